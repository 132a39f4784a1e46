"""TOML key positions (config.toml_key_lines / find_key_line) and Section errors."""

import json
import tomllib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.config import (
    Section,
    find_key_line,
    load_toml,
    split_dotted_key,
    toml_key_lines,
)
from radiopose.errors import InputError

DOC = """\
# a comment with key = 1
name = "x"   # [fake] table in a comment
text = \"\"\"
fake = 1
[fake]
\"\"\"

[area]
x_min_m = 0.0
"quoted.key" = 1
'literal key' = 2
sub.deep = 3
arr = [
  1, # y = 2
  "]",
]
inline = { a = 1, b = [1, 2] }
tail = '''
[[nope]]
'''
after = true

[[figure]]
kind = "a"

[[figure]]
kind = "b"
[figure.where]
k = 1

[ "spaced name" . inner ]
c = 1
"""


@pytest.mark.parametrize(
    ("key", "line"),
    [
        ("name", 2),
        ("text", 3),
        ("area", 8),
        ("area.x_min_m", 9),
        ('area."quoted.key"', 10),
        ("area.'literal key'", 11),
        ("area.sub", 12),
        ("area.sub.deep", 12),
        ("area.arr", 13),
        ("area.inline", 17),
        ("area.inline.a", 17),  # inside an inline table: its parent key's line
        ("area.tail", 18),
        ("area.after", 21),
        ("area.missing", 8),  # a missing key: its table's header
        ("figure", 23),
        ("figure[0].kind", 24),
        ("figure[1]", 26),
        ("figure[1].kind", 27),
        ("figure[1].where.k", 29),
        ('"spaced name".inner.c', 32),
        ("fake", None),  # only inside a multi-line string
        ("nope", None),
        ("y", None),
    ],
)
def test_find_key_line(key, line):
    tomllib.loads(DOC)  # the sample is valid TOML
    assert find_key_line(key, DOC) == line


def test_crlf_and_key_paths():
    text = DOC.replace("\n", "\r\n")
    assert find_key_line("figure[1].where.k", text) == 29
    assert split_dotted_key('figure[1]."a.b".c') == ("figure", 1, "a.b", "c")
    assert split_dotted_key("a..b") == ()
    assert find_key_line(("area", "x_min_m"), toml_key_lines(DOC)) == 9


def test_scanner_never_raises_on_bad_text():
    for text in ["[", "a = ", 'a = "', "a = [1, ", "[[a]", "= 1", 'a = """', "\x00", "a.=1"]:
        assert isinstance(toml_key_lines(text), dict)


# --------------------------------------------------------------- property test
_VALUES = [
    "1",
    "-0.5",
    "inf",
    "nan",
    "true",
    "1979-05-27T07:32:00Z",
    "1979-05-27 07:32:00",
    '"s # not a comment = 1"',
    "'[lit]'",
    '"""\nfake = 1\n[fake]\n"""',
    "'''\n[[x]]\ny = 2\n'''",
    '"""ends with a quote""""',
    "[\n  1, # x = 1\n  2,\n]",
    "[ \"a]\", 'b[', [1, [2]] ]",
    "{ a = 1, b = { c = [1, 2] } }",
]
_names = st.text(alphabet="ab_-.# =[]'\"\\x", min_size=1, max_size=5)


def _render_key(name: str, style: int) -> str:
    bare = all(c.isalnum() or c in "_-" for c in name) and name.isascii()
    if bare and style == 0:
        return name
    if "'" not in name and style == 1:
        return f"'{name}'"
    return json.dumps(name)


@st.composite
def documents(draw):
    """(text, {key path: line}) of a random document in varied TOML syntax."""
    lines: list[str] = []
    want: dict[tuple, int] = {}

    def filler():
        for _ in range(draw(st.integers(0, 2))):
            lines.append(draw(st.sampled_from(["", "# x = 1", "   ", "# [t]"])))

    def keys(prefix: tuple):
        names = draw(st.lists(_names, max_size=4, unique=True))
        used_heads: set[str] = set()
        for name in names:
            if name in used_heads:
                continue
            sub = draw(st.one_of(st.none(), _names))  # a dotted key: name.sub
            filler()
            if sub is not None:
                key = f"{_render_key(name, draw(st.integers(0, 2)))} . {_render_key(sub, 0)}"
                path = (*prefix, name, sub)
            else:
                key = _render_key(name, draw(st.integers(0, 2)))
                path = (*prefix, name)
            used_heads.add(name)
            want[path] = len(lines) + 1
            value = draw(st.sampled_from(_VALUES))
            lines.extend(f"{key} = {value}".split("\n"))

    keys(())
    tables = draw(st.lists(_names, max_size=3, unique=True))
    arrays: dict[str, int] = {}
    for name in tables:
        array = draw(st.booleans())
        for _ in range(draw(st.integers(1, 2)) if array else 1):
            filler()
            head = _render_key(name, draw(st.integers(0, 2)))
            lines.append(f"[[{head}]]" if array else f"[ {head} ]")
            if array:
                i = arrays.get(name, 0)
                arrays[name] = i + 1
                path = (name, i)
            else:
                path = (name,)
            want[path] = len(lines)
            keys(path)
    return "\n".join(lines) + "\n", want


@settings(max_examples=150, deadline=None)
@given(documents())
def test_key_lines_property(doc):
    text, want = doc
    try:
        tomllib.loads(text)
    except tomllib.TOMLDecodeError:  # e.g. a table name that clashes with a root key
        return
    got = toml_key_lines(text)
    for path, line in want.items():
        assert got.get(path) == line, (path, text)


# --------------------------------------------------------------- Section errors
def test_section_errors_name_line_and_key(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('top = 1\n\n[t]\na = "x"\nb = 2\nbad = 3\n[u]\nsub = 5\n')
    root = Section(load_toml(p), p)
    t = root.section("t")
    with pytest.raises(InputError) as exc:
        t.number("a")
    assert (exc.value.line, exc.value.column) == (4, "t.a")
    assert str(exc.value) == f"{p}:4, column 't.a': expected a number, got str 'x'"
    with pytest.raises(InputError, match=r"missing key 't\.zz'") as exc:
        t.number("zz", required=True)
    assert exc.value.line == 3  # the table header
    t.integer("b")
    with pytest.raises(InputError, match="unknown key") as exc:
        t.finish()
    assert (exc.value.line, exc.value.column) == (6, "t.bad")
    u = root.section("u")
    with pytest.raises(InputError, match="expected a table") as exc:
        u.section("sub")
    assert (exc.value.line, exc.value.column) == (8, "u.sub")
    with pytest.raises(InputError, match=r"missing table \[nope\]") as exc:
        root.section("nope")
    assert exc.value.line is None


@pytest.mark.parametrize(
    ("value", "needle"),
    [
        ("1" + "0" * 400, "expected a finite number"),  # an int beyond the float range
        ("nan", "expected a finite number"),
        ("-inf", "expected a finite number"),
        ("[1, 1" + "0" * 400 + "]", "item 1 is not a finite number"),
        ("[true]", "item 0 is not a finite number"),
    ],
)
def test_section_numbers_never_overflow(tmp_path, value, needle):
    p = tmp_path / "c.toml"
    p.write_text(f"[t]\nx = {value}\n")
    t = Section(load_toml(p), p).section("t")
    read = t.numbers if value.startswith("[") else t.number
    with pytest.raises(InputError, match=needle) as exc:
        read("x", high=10.0)
    assert (exc.value.line, exc.value.column) == (2, "t.x")


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("x = " + "1" * 5000, "a number is too long"),  # tomllib: ValueError, not a decode error
        ("x = " + "[" * 5000 + "]" * 5000, "nested too deeply"),  # RecursionError
        ("x = " + "{a=" * 3000 + "1" + "}" * 3000, "nested too deeply"),
    ],
    ids=["long-int", "deep-array", "deep-table"],
)
def test_load_toml_pathological(tmp_path, text, needle):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(InputError, match=needle):
        load_toml(p)


def test_load_toml_takes_a_bom_and_names_the_line_of_a_bad_byte(tmp_path):
    """A UTF-8 byte order mark (Notepad's) is ignored, as in the CSV files; a
    byte that is not UTF-8 is named with its line (it had none)."""
    p = tmp_path / "c.toml"
    p.write_bytes(b"\xef\xbb\xbfa = 1\n[t]\nx = 2\n")
    doc = load_toml(p)
    assert doc == {"a": 1, "t": {"x": 2}} and doc.key_lines[("t", "x")] == 3
    p.write_bytes(b"a = 1\n# caf\xe9\nb = 2\n")
    with pytest.raises(InputError, match=r"not UTF-8 text \(byte 0xe9\)") as exc:
        load_toml(p)
    assert exc.value.line == 2 and "c.toml:2:" in str(exc.value)
