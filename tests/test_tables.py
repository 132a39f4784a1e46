"""The validated CSV reader and the atomic writer (the base of every loader)."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.tables import Column, format_float, read_table, write_table

COLS = (
    Column("x_m"),
    Column("name", "str"),
    Column("azimuth_deg", low=0, high=360, high_open=True),
)


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "t.csv"
    p.write_text(text, encoding="utf-8")
    return p


def test_reads_and_ignores_extra_columns(tmp_path):
    p = write(tmp_path, "extra,name,x_m,azimuth_deg\n1,a,1.5,0\n\n2,b,-2,359.9\n")
    t = read_table(p, COLS)
    assert len(t) == 2
    assert t["x_m"].tolist() == [1.5, -2.0]
    assert t["name"].tolist() == ["a", "b"]
    assert t.lines.tolist() == [2, 4]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("name,azimuth_deg\na,1\n", "t.csv:1, column 'x_m': missing required column"),
        # a binary header is shown escaped, on one line (helper-63: raw NULs reached the terminal)
        ("\x00\x00\x1b[2J\r\x00,b\na,1\n", r"(header has: \x00\x00\x1b[2J"),
        ("x_m,name,azimuth_deg\nabc,a,1\n", "t.csv:2, column 'x_m': not a number"),
        ("x_m,name,azimuth_deg\n1_000,a,1\n", "t.csv:2, column 'x_m': not a number: '1_000'"),
        ("x_m,name,azimuth_deg\n\u0661,a,1\n", "t.csv:2, column 'x_m': not a number"),
        ("x_m,name,azimuth_deg\n1,a,0x1\n", "t.csv:2, column 'azimuth_deg': not a number"),
        ("x_m,name,azimuth_deg\nnan,a,1\n", "t.csv:2, column 'x_m': not a finite number"),
        ("x_m,name,azimuth_deg\ninf,a,1\n", "t.csv:2, column 'x_m': not a finite number"),
        ("x_m,name,azimuth_deg\n1,a,1\n1,b,360\n", "t.csv:3, column 'azimuth_deg': value 360"),
        ("x_m,name,azimuth_deg\n1,a,-0.5\n", "column 'azimuth_deg': value -0.5 out of range"),
        ("x_m,name,azimuth_deg\n1,,1\n", "t.csv:2, column 'name': empty value"),
        (
            "x_m,name,azimuth_deg\n1,a\n",
            "t.csv:2, column 'azimuth_deg': row has 2 fields, header has 3",
        ),
        ("", "empty file"),
        ("x_m,x_m,name,azimuth_deg\n1,1,a,1\n", "column appears more than once"),
    ],
)
def test_errors_name_file_line_column(tmp_path, text, needle):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as exc:
        read_table(p, COLS)
    assert needle in str(exc.value)
    assert "\n" not in str(exc.value)


def test_missing_file_and_binary(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_table(tmp_path / "nope.csv", COLS)
    p = tmp_path / "b.csv"
    p.write_bytes(b"x_m,name,azimuth_deg\n\xff\xfe\x00,a,1\n")
    with pytest.raises(InputError, match="not UTF-8"):
        read_table(p, COLS)
    p.write_bytes(b"x_m,name,azimuth_deg\n1,a,1\n2,b\xe9,2\n")  # Latin-1 on line 3
    with pytest.raises(InputError, match=r"b\.csv:3, column 'name': not UTF-8"):
        read_table(p, COLS)


def test_write_is_atomic(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(ValueError):
        write_table(target, {"a": [1.0, 2.0], "b": [1.0]})
    assert target.read_text() == "old\n"
    assert list(tmp_path.iterdir()) == [target]


def test_float_format_is_deterministic():
    assert format_float(1.0) == "1"
    assert format_float(-0.0000001) == "0"
    assert format_float(2.5) == "2.5"
    assert format_float(1 / 3, 3) == "0.333"


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(alphabet=st.characters(codec="utf-8"), max_size=200))
def test_fuzz_never_crashes(tmp_path, text):
    p = write(tmp_path, "x_m,name,azimuth_deg\n" + text)
    try:
        t = read_table(p, COLS)
    except InputError as exc:
        assert "\n" not in str(exc)
    else:
        assert np.all(np.isfinite(t["x_m"]))
        assert np.all((t["azimuth_deg"] >= 0) & (t["azimuth_deg"] < 360))


@settings(max_examples=100, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.tuples(
            st.floats(-1e6, 1e6), st.text("abc_", min_size=1, max_size=5), st.floats(0, 359.999)
        ),
        max_size=20,
    )
)
def test_round_trip(tmp_path, rows):
    p = tmp_path / "rt.csv"
    write_table(
        p,
        {
            "x_m": np.array([r[0] for r in rows], float),
            "name": [r[1] for r in rows],
            "azimuth_deg": np.array([r[2] for r in rows], float),
        },
        decimals={"x_m": 9},
    )
    t = read_table(p, COLS)
    assert t["name"].tolist() == [r[1] for r in rows]
    assert np.allclose(t["x_m"], [r[0] for r in rows], atol=1e-6)


def test_staged_echo_names_the_target_not_the_stage(tmp_path):
    from radiopose.tables import staged_directory, staged_echo

    lines: list[str] = []
    out = tmp_path / "out"
    with staged_directory(out) as stage:
        say = staged_echo(lines.append, stage, out)
        (stage / "a.txt").write_text("x")
        say(f"wrote {stage / 'a.txt'}")
    assert lines == [f"wrote {out / 'a.txt'}"]
    assert (out / "a.txt").read_text() == "x"


def test_a_staged_directory_that_cannot_be_made_names_the_target():
    """Where the staging directory cannot be made (/proc takes no new entry,
    even from root), the error names the output directory, not the staging one
    (helper-63: "/proc/.xx.lt32p8h4.staging: No such file or directory")."""
    from pathlib import Path

    from radiopose.tables import staged_directory

    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc here (not Linux)")
    with pytest.raises(InputError) as err, staged_directory("/proc/radiopose-out"):
        pass
    assert str(err.value).startswith("cannot write the output directory /proc/radiopose-out: ")
    assert ".staging" not in str(err.value)


def test_atomic_writer_writes_through_links_and_special_files(tmp_path):
    """A symbolic link's file is replaced (the link stays); a FIFO or a device is
    written, never replaced by a regular file (``-o /dev/null`` once did that)."""
    import os
    import threading

    from radiopose.tables import atomic_writer

    target = tmp_path / "target.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    with atomic_writer(link) as fh:
        fh.write("new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()))
    reader.start()
    with atomic_writer(fifo) as fh:
        fh.write("through the pipe\n")
    reader.join(10)
    assert got == ["through the pipe\n"] and fifo.exists() and not fifo.is_file()
    with atomic_writer("/dev/null") as fh:
        fh.write("discarded\n")
    assert Path("/dev/null").is_char_device()


def test_atomic_writer_writes_to_stdout_when_it_is_a_pipe(tmp_path):
    """``-o /dev/stdout`` into a pipe: /dev/stdout links to /proc/self/fd/1, whose
    link text for a pipe ("pipe:[N]") is no path; the name given is opened (it
    once tried to make a temporary file in /proc/N/fd and failed after the work)."""
    import subprocess
    import sys

    code = (
        "from radiopose.tables import atomic_writer\n"
        "with atomic_writer('/dev/stdout') as fh:\n"
        "    fh.write('a,b\\n1,2\\n')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "a,b\n1,2\n"


def test_an_output_may_not_overwrite_an_input(tmp_path):
    from radiopose.tables import check_outputs_not_inputs

    packets = tmp_path / "packets.csv"
    packets.write_text("x\n")
    site = tmp_path / "site"
    (site / "patterns").mkdir(parents=True)
    (site / "patterns" / "rx1.csv").write_text("x\n")
    alias = tmp_path / "alias.csv"
    alias.symlink_to(packets)
    for out, words in (
        (packets, "the input"),
        (alias, "the input"),
        (site / "patterns" / "rx1.csv", "a file of the input directory"),
    ):
        with pytest.raises(InputError, match=words):
            check_outputs_not_inputs([out], [packets, site])
    # new files, even inside the site directory, and options not given are fine
    check_outputs_not_inputs([tmp_path / "est.csv", site / "new.csv", None], [packets, site])


def test_replace_outputs_removes_only_what_its_manifest_lists(tmp_path):
    """The helper behind ``spoof`` and ``evaluate`` removing an earlier run's outputs:
    without a manifest nothing goes; with one, only listed files this run did not
    write, while each is a regular file inside the directory reached through no
    link. Entries naming anything else (``..``, absolute, ``./x`` for a file this
    run wrote, a linked subdirectory) are ignored."""
    import json

    from radiopose.tables import outputs_manifest, replace_outputs

    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)
    for name in ("a.csv", "b.csv", "figures/a.png", "figures/b.png", "mine.csv"):
        (out / name).write_text("x\n")
    (tmp_path / "outside.csv").write_text("mine\n")
    # no manifest: nothing removed; the manifest lists what was written
    assert replace_outputs(out, "test", [out / "a.csv"]) == []
    manifest = out / outputs_manifest("test")
    assert json.loads(manifest.read_text())["files"] == ["a.csv"]
    assert all((out / n).exists() for n in ("b.csv", "figures/b.png", "mine.csv"))
    replace_outputs(out, "test", [out / n for n in ("a.csv", "b.csv", "figures/a.png")])
    removed = replace_outputs(out, "test", [out / "a.csv", out / "figures/b.png"])
    assert removed == [out / "b.csv", out / "figures/a.png"]
    assert sorted(p.name for p in out.rglob("*") if p.is_file()) == [
        manifest.name, "a.csv", "b.png", "mine.csv"
    ]  # fmt: skip
    # entries that are not the run's files: nothing followed or removed
    pictures = tmp_path / "pictures"
    pictures.mkdir()
    (pictures / "b.png").write_text("mine\n")
    (out / "figures" / "b.png").unlink()
    (out / "figures").rmdir()
    (out / "figures").symlink_to(pictures)
    (out / "link.csv").symlink_to(tmp_path / "outside.csv")
    entries = ["../outside.csv", str(tmp_path / "outside.csv"), "./a.csv", "a//a.csv", "."]
    entries += ["figures/b.png", "link.csv", "missing.csv", manifest.name]
    manifest.write_text(json.dumps({"files": entries}))
    assert replace_outputs(out, "test", [out / "a.csv"]) == []
    assert (tmp_path / "outside.csv").read_text() == "mine\n" and (out / "link.csv").is_symlink()
    assert (pictures / "b.png").read_text() == "mine\n" and (out / "a.csv").exists()
    # a manifest that is not one: nothing removed, rewritten
    manifest.write_text("not json")
    assert replace_outputs(out, "test", [out / "a.csv"]) == []
    with pytest.raises(ValueError):  # a written file must be inside the directory
        replace_outputs(out, "test", [tmp_path / "outside.csv"])


def test_an_unclosed_quote_is_named_at_its_records_first_line(tmp_path):
    """An unclosed quote makes the CSV reader run to the end of the file: the
    error names the line where the record starts (it named the file's last
    line), and says what probably happened; blank lines are counted."""
    rows = ["a,b,c", "1,2,3", "", "3,4,5", '5,"6,7', *[f"{i},{i},{i}" for i in range(7, 40)]]
    p = tmp_path / "t.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError) as err:
        read_table(p, [Column("a"), Column("b"), Column("c")])
    assert err.value.line == 5
    assert "a quoted field runs from line 5 to 38: a quote not closed?" in str(err.value)
    rows[4] = '5,"6",7'  # closed: read on
    p.write_text("\n".join(rows) + "\n")
    assert list(read_table(p, [Column("a"), Column("b"), Column("c")]).lines[:3]) == [2, 4, 5]
