"""Validated access to TOML configuration (site.toml, experiment files).

:func:`load_toml` parses a file and turns syntax errors into one-line
:class:`~radiopose.errors.InputError` s naming file, line and column.
:class:`Section` reads typed, range-checked values and rejects unknown keys, so
a typo is an error naming the dotted key rather than a silently ignored setting.

Python's :mod:`tomllib` keeps no positions, so :func:`toml_key_lines` scans the
(already parsed, hence valid) text once for the line of every key and table
header; :func:`load_toml` attaches that index to the document it returns and
:class:`Section` errors name ``file:line`` and the dotted key. A key that is
not in the file (a missing key) falls back to the line of its table header; a
key of a table that is not in the file has no line.
"""

from __future__ import annotations

import bisect
import difflib
import math
import os
import re
import tomllib
from collections.abc import Iterable, Mapping
from typing import Any, NoReturn

from radiopose.errors import InputError

KeyPath = tuple[str | int, ...]
"""A key as a path: table names, key names and array-of-tables indices,
``("figure", 1, "kind")`` for ``figure[1].kind``."""


class TomlDocument(dict[str, Any]):
    """A parsed TOML document (a plain ``dict``) that remembers where its keys are.

    Attributes
    ----------
    key_lines
        ``{key path: 1-based line}`` (see :func:`toml_key_lines`).
    """

    key_lines: dict[KeyPath, int]

    def __init__(self, data: Mapping[str, Any], key_lines: dict[KeyPath, int]) -> None:
        super().__init__(data)
        self.key_lines = key_lines


def load_toml(path: str | os.PathLike[str]) -> TomlDocument:
    """Parse a TOML file; errors become one-line :class:`InputError` s.

    Returns the document as a ``dict`` (a :class:`TomlDocument`, which also
    carries the line of every key for later error messages). A leading UTF-8
    byte order mark (which some Windows editors write) is ignored, as in the
    CSV files.
    """
    raw = b""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
        text = raw.decode("utf-8-sig")
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        line = int(m.group(1)) if m else None
        reason = re.sub(r"\s*\(at line \d+, column \d+\)", "", msg)
        if m:
            reason += f" (column {m.group(2)})"
        raise InputError(f"invalid TOML: {reason}", path=path, line=line) from None
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise InputError(
            f"invalid TOML: not UTF-8 text (byte 0x{raw[exc.start]:02x})", path=path, line=line
        ) from None
    except RecursionError:
        raise InputError("invalid TOML: arrays or tables nested too deeply", path=path) from None
    except ValueError:  # tomllib lets int("<over 4300 digits>") through
        m = re.search(r"[0-9_]{1000,}", text)
        line = text.count("\n", 0, m.start()) + 1 if m else None
        raise InputError("invalid TOML: a number is too long", path=path, line=line) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=path) from None
    return TomlDocument(data, toml_key_lines(text))


# ----------------------------------------------------------------------------- key positions
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_KEY_SEGMENT = re.compile(
    r"""\s*(?:"((?:[^"\\]|\\.)*)"|'([^']*)'|([^.\[\]"'\s]+))\s*((?:\[\s*\d+\s*\])*)\s*"""
)


class _ScanError(Exception):
    """The scanner met text it does not understand: keep what was indexed."""


def split_dotted_key(key: str) -> KeyPath:
    """``'figure[1]."a.b".c'`` → ``("figure", 1, "a.b", "c")``.

    Bare segments, ``"basic"`` and ``'literal'`` quoted segments and ``[i]``
    array indices. Text that does not parse gives ``()``.
    """
    out: list[str | int] = []
    i = 0
    while i < len(key):
        m = _KEY_SEGMENT.match(key, i)
        if not m or m.end() == i:
            return ()
        basic, literal, bare, indices = m.groups()
        if basic is not None:
            try:
                out.append(tomllib.loads(f'k = "{basic}"')["k"])
            except tomllib.TOMLDecodeError:
                out.append(basic)
        else:
            out.append(literal if literal is not None else bare)
        out.extend(int(x) for x in re.findall(r"\d+", indices))
        i = m.end()
        if i < len(key):
            if key[i] != ".":
                return ()
            i += 1
            if i == len(key):
                return ()
    return tuple(out)


def toml_key_lines(text: str) -> dict[KeyPath, int]:
    """The 1-based line of every key and table header of a TOML document.

    Keys are paths (:data:`KeyPath`): ``[a.b]`` → ``("a", "b")``; ``c = 1``
    below it → ``("a", "b", "c")``; dotted and quoted keys are split
    (``"x.y".z = 1`` → ``("x.y", "z")``); the ``i``-th ``[[t]]`` → ``("t", i)``
    (and ``("t",)`` at its first header). A table only implied by a header or a
    dotted key (``[a.b]`` implies ``a``) gets the line of its first mention.
    Keys inside inline tables are not indexed (they share the line of their
    parent key). Values, strings (multi-line too), arrays and comments are
    skipped, so text inside them is never taken for a key.

    Meant for text that :mod:`tomllib` accepted; on anything it does not
    understand it stops and returns what it has indexed so far (it never raises).
    """
    s = text
    n = len(s)
    newlines = [m.start() for m in re.finditer("\n", s)]
    out: dict[KeyPath, int] = {}
    aot: dict[KeyPath, int] = {}  # array-of-tables path → elements so far

    def line_at(i: int) -> int:
        return bisect.bisect_left(newlines, i) + 1

    def skip_ws(i: int) -> int:
        while i < n and s[i] in " \t":
            i += 1
        return i

    def end_of_line(i: int) -> int:
        j = s.find("\n", i)
        return n if j < 0 else j

    def skip_string(i: int) -> int:
        """Index just after the string starting at ``s[i]`` (a quote)."""
        q = s[i]
        if s.startswith(q * 3, i):  # multi-line: up to two extra quotes before the closer
            j = i + 3
            while j < n:
                if q == '"' and s[j] == "\\":
                    j += 2
                elif s.startswith(q * 3, j):
                    run = 3
                    while run < 5 and j + run < n and s[j + run] == q:
                        run += 1
                    return j + run
                else:
                    j += 1
            raise _ScanError
        j = i + 1
        while j < n and s[j] != "\n":
            if q == '"' and s[j] == "\\":
                j += 2
                continue
            if s[j] == q:
                return j + 1
            j += 1
        raise _ScanError

    def skip_value(i: int) -> int:
        i = skip_ws(i)
        if i >= n:
            raise _ScanError
        if s[i] in "\"'":
            return skip_string(i)
        if s[i] in "[{":
            depth = 0
            while i < n:
                c = s[i]
                if c in "[{":
                    depth += 1
                    i += 1
                elif c in "]}":
                    depth -= 1
                    i += 1
                    if depth == 0:
                        return i
                elif c in "\"'":
                    i = skip_string(i)
                elif c == "#":
                    i = end_of_line(i)
                else:
                    i += 1
            raise _ScanError
        return end_of_line(i)  # a number, boolean or date: nothing special up to the newline

    def parse_key(i: int) -> tuple[list[str], int]:
        parts: list[str] = []
        while True:
            i = skip_ws(i)
            if i >= n:
                raise _ScanError
            if s[i] == '"':
                j = skip_string(i)
                try:
                    parts.append(tomllib.loads(f"k = {s[i:j]}")["k"])
                except tomllib.TOMLDecodeError:
                    parts.append(s[i + 1 : j - 1])
                i = j
            elif s[i] == "'":
                j = skip_string(i)
                parts.append(s[i + 1 : j - 1])
                i = j
            else:
                m = _BARE_KEY.match(s, i)
                if not m:
                    raise _ScanError
                parts.append(m.group())
                i = m.end()
            i = skip_ws(i)
            if i < n and s[i] == ".":
                i += 1
                continue
            return parts, i

    def resolve(parts: list[str]) -> KeyPath:
        """Header names → path, entering the last element of arrays of tables."""
        path: KeyPath = ()
        for p in parts:
            path = (*path, p)
            if path in aot:
                path = (*path, aot[path] - 1)
        return path

    def mention(path: KeyPath, line: int, start: int) -> None:
        for k in range(max(start, 1), len(path)):
            out.setdefault(path[:k], line)
        out[path] = line

    table: KeyPath = ()
    i = 0
    try:
        while i < n:
            c = s[i]
            if c in " \t\r\n":
                i += 1
            elif c == "#":
                i = end_of_line(i)
            elif c == "[":
                line = line_at(i)
                array = s.startswith("[[", i)
                parts, i = parse_key(i + (2 if array else 1))
                close = "]]" if array else "]"
                if not s.startswith(close, i):
                    raise _ScanError
                i += len(close)
                if array:
                    base = (*resolve(parts[:-1]), parts[-1])
                    aot[base] = aot.get(base, 0) + 1
                    out.setdefault(base, line)
                    table = (*base, aot[base] - 1)
                else:
                    table = resolve(parts)
                mention(table, line, 1)
                i = end_of_line(i)
            else:
                line = line_at(i)
                parts, i = parse_key(i)
                if i >= n or s[i] != "=":
                    raise _ScanError
                mention((*table, *parts), line, len(table) + 1)
                i = end_of_line(skip_value(i + 1))
    except (_ScanError, IndexError):
        pass
    return out


def find_key_line(key: str | KeyPath, lines: Mapping[KeyPath, int] | str | None) -> int | None:
    """Line of a key in a TOML document, or of the nearest table above it.

    Parameters
    ----------
    key
        A dotted key (``"area.step_m"``, ``'figure[1].kind'``) or a :data:`KeyPath`.
    lines
        The document's text, or its :func:`toml_key_lines` index.

    Returns
    -------
    The 1-based line of ``key``; if it is not in the document, the line of its
    closest enclosing table that is (its header); otherwise ``None``.
    """
    if lines is None:
        return None
    if isinstance(lines, str):
        lines = toml_key_lines(lines)
    path = split_dotted_key(key) if isinstance(key, str) else tuple(key)
    for k in range(len(path), 0, -1):
        if path[:k] in lines:
            return lines[path[:k]]
    return None


# ----------------------------------------------------------------------------- typed reading
def _fmt(x: float | None, default: str) -> str:
    return default if x is None else f"{x:g}"


def _short_int(v: int) -> str:
    s = str(v)
    return s if len(s) <= 24 else f"{s[:12]}… ({len(s)} digits)"


def _finite_float(x: Any) -> float | None:
    """``float(x)`` for a finite int/float (not bool), else ``None`` (huge ints too)."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        return None
    try:
        v = float(x)
    except OverflowError:  # an integer beyond the float range
        return None
    return v if math.isfinite(v) else None


class Section:
    """Typed reader over one TOML table; tracks which keys were used.

    Errors name the file, the line (when the data came from :func:`load_toml`,
    or ``lines`` is given) and the dotted key.

    Parameters
    ----------
    data
        The table.
    path
        The file, for error messages.
    prefix
        Dotted name of the table (``"area"``), for error messages.
    lines
        Key positions of the document (:func:`toml_key_lines`); by default
        taken from ``data`` if it is a :class:`TomlDocument`.
    parts
        The table's key path; by default parsed from ``prefix``.
    """

    def __init__(
        self,
        data: Mapping[str, Any],
        path: str | os.PathLike[str],
        prefix: str = "",
        *,
        lines: Mapping[KeyPath, int] | None = None,
        parts: KeyPath | None = None,
    ):
        self.path = str(path)
        self.prefix = prefix
        self.lines = lines if lines is not None else getattr(data, "key_lines", None)
        self.parts: KeyPath = parts if parts is not None else split_dotted_key(prefix)
        if not isinstance(data, Mapping):
            raise InputError(
                f"expected a table, got {type(data).__name__}",
                path=path,
                line=find_key_line(self.parts, self.lines),
                column=prefix or None,
            )
        self.data = data
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def line(self, name: str | None = None) -> int | None:
        """Line of key ``name`` (of the table itself if ``None``), else its table's."""
        path = self.parts if name is None else (*self.parts, name)
        return find_key_line(path, self.lines)

    def error(self, name: str, message: str) -> InputError:
        """An :class:`InputError` at key ``name``: ``file:line, column '<key>': message``."""
        return InputError(message, path=self.path, line=self.line(name), column=self.key(name))

    def table_error(self, message: str) -> InputError:
        """An :class:`InputError` about the table as a whole (its header line)."""
        return InputError(message, path=self.path, line=self.line(), column=self.prefix or None)

    def has(self, name: str) -> bool:
        return name in self.data

    def section(self, name: str, required: bool = True) -> Section:
        self.used.add(name)
        parts = (*self.parts, name)
        if name not in self.data:
            if required:
                raise InputError(
                    f"missing table [{self.key(name)}]", path=self.path, line=self.line()
                )
            return Section({}, self.path, self.key(name), lines=self.lines, parts=parts)
        return Section(self.data[name], self.path, self.key(name), lines=self.lines, parts=parts)

    def _get(self, name: str, default: Any) -> Any:
        self.used.add(name)
        if name not in self.data:
            if default is _REQUIRED:
                raise InputError(
                    f"missing key '{self.key(name)}'", path=self.path, line=self.line()
                )
            return default
        return self.data[name]

    def number(
        self,
        name: str,
        default: Any = None,
        *,
        low: float | None = None,
        high: float | None = None,
        positive: bool = False,
        required: bool = False,
    ) -> float:
        v = self._get(name, _REQUIRED if required else default)
        if v is default and not required and name not in self.data:
            return v
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.error(name, f"expected a number, got {type(v).__name__} {v!r:.40}")
        x = _finite_float(v)
        if x is None:
            raise self.error(name, f"expected a finite number, got {v!r:.40}")
        if positive and x <= 0:
            raise self.error(name, f"must be > 0, got {x:g}")
        if (low is not None and x < low) or (high is not None and x > high):
            raise self.error(
                name, f"value {x:g} out of range [{_fmt(low, '-inf')}, {_fmt(high, 'inf')}]"
            )
        return x

    def integer(
        self,
        name: str,
        default: Any = None,
        *,
        low: int | None = None,
        high: int | None = None,
        required: bool = False,
    ) -> int:
        v = self._get(name, _REQUIRED if required else default)
        if v is default and not required and name not in self.data:
            return v
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(name, f"expected an integer, got {v!r:.40}")
        if (low is not None and v < low) or (high is not None and v > high):
            raise self.error(name, f"value {_short_int(v)} out of range [{low}, {high}]")
        return int(v)

    def string(
        self,
        name: str,
        default: Any = None,
        *,
        choices: tuple[str, ...] | None = None,
        required: bool = False,
    ) -> str:
        v = self._get(name, _REQUIRED if required else default)
        if v is default and not required and name not in self.data:
            return v
        if not isinstance(v, str) or not v.strip():
            raise self.error(name, f"expected a non-empty string, got {v!r:.40}")
        if choices is not None and v not in choices:
            raise self.error(name, f"expected one of {', '.join(choices)}, got {v!r:.40}")
        return v

    def numbers(
        self,
        name: str,
        default: Any = None,
        *,
        low: float | None = None,
        high: float | None = None,
        nonempty: bool = True,
        scalar: bool = True,
    ) -> tuple[float, ...]:
        """A list of finite numbers in ``[low, high]``; ``scalar=False`` rejects a bare
        number; ``nonempty=False`` accepts ``[]``. A value of another kind is an error
        that says which of these are accepted."""
        v = self._get(name, default)
        if v is default and name not in self.data:
            return v
        expected = "a non-empty list of numbers" if nonempty else "a list of numbers ([] allowed)"
        if scalar:
            expected = f"a number or {expected}"
        if isinstance(v, int | float) and not isinstance(v, bool):
            if not scalar:
                raise self.error(name, f"expected {expected}, got a single number (write [{v!r}])")
            v = [v]
        if not isinstance(v, list):
            raise self.error(name, f"expected {expected}, got {v!r:.40}")
        if nonempty and not v:
            raise self.error(name, f"expected {expected}, got []")
        out = []
        for i, item in enumerate(v):
            x = _finite_float(item)
            if x is None:
                raise self.error(name, f"item {i} is not a finite number: {item!r:.40}")
            if (low is not None and x < low) or (high is not None and x > high):
                lo, hi = _fmt(low, "-inf"), _fmt(high, "inf")
                raise self.error(name, f"item {i} = {x:g} out of range [{lo}, {hi}]")
            out.append(x)
        return tuple(out)

    def boolean(self, name: str, default: Any = None) -> bool:
        v = self._get(name, default)
        if not isinstance(v, bool):
            raise self.error(name, f"expected true or false, got {v!r:.40}")
        return v

    def finish(
        self, allowed: Iterable[str] | None = None, elsewhere: dict[str, str] | None = None
    ) -> None:
        """Reject keys that were never read (typos).

        ``allowed``: every key this table may hold, for a reader that reads only
        the keys present (default: the keys asked for); the message suggests
        the closest ones, or lists them when there are few. ``elsewhere``: keys
        that belong in another table of the file (key → where, e.g. ``"the top
        level, above [filter]"``), named as such.
        """
        unknown = sorted(set(self.data) - self.used)
        if not unknown:
            return
        self._reject(unknown[0], set(self.used if allowed is None else allowed), elsewhere)

    def reject_unknown(
        self, allowed: Iterable[str], elsewhere: dict[str, str] | None = None
    ) -> None:
        """Reject a key outside ``allowed`` before any is read, so that a misspelt
        key is named at its own line rather than reported as a missing one."""
        unknown = sorted(set(self.data) - set(allowed))
        if unknown:
            self._reject(unknown[0], set(allowed), elsewhere)

    def _reject(self, key: str, allowed: set[str], elsewhere: dict[str, str] | None) -> NoReturn:
        if elsewhere and key in elsewhere:
            raise self.error(key, f"unknown key here: it belongs at {elsewhere[key]}")
        known = sorted(allowed - {key})
        close = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
        if close:
            hint = f"did you mean {' or '.join(repr(k) for k in close)}?"
        elif len(known) <= 12:
            hint = f"known here: {', '.join(known) or 'none'}"
        else:
            hint = f"{len(known)} keys are known here; see the docs"
        raise self.error(key, f"unknown key ({hint})")


_REQUIRED = object()
