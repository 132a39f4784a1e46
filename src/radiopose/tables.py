"""CSV tables of the interchange contract: validated reading, atomic writing.

Every table radiopose reads goes through :func:`read_table`, which checks the
header, parses each required column, rejects NaN/inf and out-of-range values and
raises :class:`~radiopose.errors.InputError` naming file, line and column
(the header is line 1, the first data row line 2). Extra columns are ignored.

Every table radiopose writes goes through :func:`write_table`, which writes a
temporary file beside the target and renames it into place, so a failure never
leaves a half-written output.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import math
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO, Any, Literal

import numpy as np
from numpy.typing import NDArray

from radiopose.errors import InputError, unreadable


@dataclass(frozen=True)
class Column:
    """A required column of a contract table.

    Parameters
    ----------
    name
        Exact header name.
    kind
        ``"float"`` (finite float64), ``"int"`` (int64) or ``"str"`` (non-empty text).
    low, high
        Optional inclusive lower / upper bound for numbers.
    high_open
        If true the upper bound is exclusive (e.g. azimuth ``< 360``).
    """

    name: str
    kind: Literal["float", "int", "str"] = "float"
    low: float | None = None
    high: float | None = None
    high_open: bool = False

    def describe_range(self) -> str:
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        return f"[{lo}, {hi}{')' if self.high_open else ']'}"


@dataclass(frozen=True)
class Table:
    """Parsed columns, each an array of one value per data row.

    ``lines`` holds the 1-based file line of each row, for error messages
    raised by later, cross-row checks.
    """

    path: str
    columns: Mapping[str, NDArray]
    lines: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.lines.shape[0])

    def __getitem__(self, name: str) -> NDArray:
        return self.columns[name]

    def error(self, row: int, column: str | None, message: str) -> InputError:
        """An :class:`InputError` for data row index ``row`` (0-based)."""
        return InputError(message, path=self.path, line=int(self.lines[row]), column=column)


def _open_text(path: Path) -> io.TextIOWrapper:
    try:
        return open(path, newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise unreadable(path, exc, "a CSV file") from None


# Plain ASCII decimal numbers only: Python's float()/int() would also take
# "1_000", full-width or other Unicode digits, which no CSV writer means.
_FLOAT_SYNTAX = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(nan|inf|infinity)", re.I)
_INT_SYNTAX = re.compile(r"[+-]?\d+")


def _undecodable_at(path: Path) -> tuple[int | None, str | None]:
    """Line (1-based) and header column of the first byte that is not UTF-8."""
    try:
        data = path.read_bytes()
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        start = data.rfind(b"\n", 0, exc.start) + 1
        field = data.count(b",", start, exc.start)
        header = data.split(b"\n", 1)[0].decode("utf-8", "replace").lstrip("\ufeff").split(",")
        column = header[field].strip() if line > 1 and field < len(header) else None
        return line, column
    except OSError:
        pass
    return None, None


def _parse_number(text: str, col: Column, path: Path, line: int) -> float | int:
    s = text.strip()
    if s == "":
        raise InputError("empty value", path=path, line=line, column=col.name)
    try:
        syntax = _INT_SYNTAX if col.kind == "int" else _FLOAT_SYNTAX
        if not s.isascii() or syntax.fullmatch(s) is None:
            raise ValueError(s)
        value: float | int = int(s) if col.kind == "int" else float(s)
    except ValueError:
        kind = "an integer" if col.kind == "int" else "a number"
        raise InputError(f"not {kind}: {s[:40]!r}", path=path, line=line, column=col.name) from None
    if col.kind == "float" and not math.isfinite(value):
        raise InputError(f"not a finite number: {s!r}", path=path, line=line, column=col.name)
    below = col.low is not None and value < col.low
    above = col.high is not None and (value >= col.high if col.high_open else value > col.high)
    if below or above:
        raise InputError(
            f"value {s} out of range {col.describe_range()}", path=path, line=line, column=col.name
        )
    return value


def _shown(header: list[str]) -> str:
    """A header for a one-line message: comma-joined, at most 200 characters, and
    any non-printable character escaped (a binary file's NULs and newlines would
    otherwise reach the terminal raw, or split the line)."""
    text = ", ".join(header)
    return (text if text.isprintable() else repr(text)[1:-1])[:200]


def read_table(
    path: str | os.PathLike[str], columns: Sequence[Column], optional: Sequence[Column] = ()
) -> Table:
    """Read and validate a contract CSV table.

    The file is read once, front to back, so a pipe (``<(...)``, ``/dev/stdin``)
    is read like a file.

    Parameters
    ----------
    path
        The CSV file (UTF-8, header row, comma separated).
    columns
        The required columns; others in the file are ignored.
    optional
        Columns read, and validated like the required ones, when the header has
        every one of them (a group given together or not at all); the table
        then holds them (``name in table.columns``).

    Raises
    ------
    InputError
        Missing file or column, unparsable/NaN/inf/out-of-range value, ragged row.
    """
    p = Path(path)
    with _open_text(p) as fh:
        try:
            reader = csv.reader(fh)
            read_to = 0  # the last line of the last whole record: a bad one starts after it
            header = next(reader, None)
            if header is None:
                raise InputError("empty file, expected a header row", path=p, line=1)
            header = [h.strip() for h in header]
            if optional and all(c.name in header for c in optional):
                columns = [*columns, *optional]
            index: dict[str, int] = {}
            for col in columns:
                if col.name not in header:
                    raise InputError(
                        f"missing required column (header has: {_shown(header)})",
                        path=p,
                        line=1,
                        column=col.name,
                    )
                index[col.name] = header.index(col.name)
            dupes = {h for h in header if header.count(h) > 1 and h in index}
            if dupes:
                name = sorted(dupes)[0]
                raise InputError("column appears more than once", path=p, line=1, column=name)
            values: dict[str, list] = {c.name: [] for c in columns}
            lines: list[int] = []
            width = len(header)
            read_to = reader.line_num
            for row in reader:
                # a record's first line (a quoted field may run over several)
                line, read_to = read_to + 1, reader.line_num
                if not row or all(not f.strip() for f in row):
                    continue  # blank lines are not rows
                if len(row) != width:
                    short = len(row) < width
                    runs = (
                        f" (a quoted field runs from line {line} to {read_to}: a quote not closed?)"
                        if read_to > line
                        else ""
                    )
                    raise InputError(
                        f"row has {len(row)} fields, header has {width}"
                        + ("" if short else f" (extra after '{header[-1].strip()}')")
                        + runs,
                        path=p,
                        line=line,
                        column=header[len(row)].strip() if short else None,
                    )
                for col in columns:
                    raw = row[index[col.name]]
                    if col.kind == "str":
                        s = raw.strip()
                        if not s:
                            raise InputError("empty value", path=p, line=line, column=col.name)
                        values[col.name].append(s)
                    else:
                        values[col.name].append(_parse_number(raw, col, p, line))
                lines.append(line)
        except UnicodeDecodeError as exc:
            bad_line, column = _undecodable_at(p)
            raise InputError(
                f"not UTF-8 text ({exc.reason})", path=p, line=bad_line, column=column
            ) from None
        except csv.Error as exc:
            # the record's first line, not the reader's (an unclosed quote reads to
            # the end of the file)
            hint = " (a quote opened here is not closed)" if "end of data" in str(exc) else ""
            raise InputError(f"malformed CSV: {exc}{hint}", path=p, line=read_to + 1) from None
    arrays: dict[str, NDArray] = {}
    for col in columns:
        if col.kind == "float":
            arrays[col.name] = np.asarray(values[col.name], dtype=np.float64)
        elif col.kind == "int":
            arrays[col.name] = np.asarray(values[col.name], dtype=np.int64)
        else:
            arrays[col.name] = np.asarray(values[col.name], dtype=object)
    return Table(str(p), arrays, np.asarray(lines, dtype=np.int64))


def format_float(value: float, decimals: int = 6) -> str:
    """Deterministic text for a float: fixed decimals with trailing zeros stripped."""
    s = f"{value:.{decimals}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike[str], mode: str = "w") -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; rename it over ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.
    Parent directories are created. A symbolic link is written through (the
    file it names is replaced, the link stays); an existing path that is not a
    regular file (``/dev/null``, a FIFO) is opened and written directly, since
    renaming over it would replace the device node or pipe with a file.
    """
    target = Path(path)
    check_output_paths(files=[target])
    try:
        special = not stat.S_ISREG(os.stat(target).st_mode)  # through any link
    except OSError:  # missing (or a dangling link): a new file
        special = False
    if special:
        # opened by the name given, not the link's target: /dev/stdout names
        # /proc/self/fd/1, whose target text for a pipe ("pipe:[N]") is no path
        kw: dict[str, Any] = {"newline": "", "encoding": "utf-8"} if "b" not in mode else {}
        with open(target, mode, **kw) as fh:
            yield fh
        return
    if target.is_symlink():
        target = Path(os.path.realpath(target))
        check_output_paths(files=[target])
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:  # name the file asked for, not the temporary one
        raise type(exc)(exc.errno, f"cannot write ({exc.strerror})", str(target)) from None
    try:
        kwargs: dict[str, Any] = {"newline": "", "encoding": "utf-8"} if "b" not in mode else {}
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def reject_repeated_rows(table: Table, key: Sequence[str], message: str) -> None:
    """Raise at the first data row whose ``key`` columns repeat an earlier row.

    ``message`` is formatted with the key values; the error names the row's
    line, the first key column, and the line of the earlier row.
    """
    seen: dict[tuple, int] = {}
    cols = [table[name] for name in key]
    for row, values in enumerate(zip(*cols, strict=True)):
        k = tuple(str(v).lower() if isinstance(v, str) else v for v in values)
        if k in seen:
            raise table.error(
                row,
                key[-1] if len(key) > 1 else key[0],
                message.format(*values) + f" (first on line {int(table.lines[seen[k]])})",
            )
        seen[k] = row


def check_output_paths(
    files: Sequence[str | os.PathLike[str]] = (), dirs: Sequence[str | os.PathLike[str]] = ()
) -> None:
    """Refuse, before anything is written, outputs that could not be written.

    ``files`` must not be existing directories, ``dirs`` not existing files, and
    no existing parent of either may be a file. Raises :class:`OSError` with
    the offending path (the CLI prints it as one line).
    """
    for kind, paths in (("file", files), ("dir", dirs)):
        for p in map(Path, paths):
            if kind == "file" and p.is_dir():
                raise IsADirectoryError(
                    errno.EISDIR, "is a directory, expected a file path", str(p)
                )
            if kind == "dir" and p.exists() and not p.is_dir():
                raise NotADirectoryError(errno.ENOTDIR, "is a file, expected a directory", str(p))
            for parent in p.parents:
                if parent.exists():
                    if not parent.is_dir():
                        raise NotADirectoryError(
                            errno.ENOTDIR, "cannot create: a parent is not a directory", str(p)
                        )
                    break


def check_output_dir(
    out: str | os.PathLike[str], files: Sequence[str] = (), subdirs: Sequence[str] = ()
) -> None:
    """Refuse, before any work, an output directory that could not be written: ``out``
    or one of its ``subdirs`` an existing file, a parent of it a file, or one of the
    ``files`` (names in ``out``) an existing directory. The directories are checked
    first, so the error names the path given. Nothing is created
    (:func:`check_output_paths`)."""
    root = Path(out)
    check_output_paths(dirs=[root, *(root / d for d in subdirs)])
    check_output_paths(files=[root / name for name in files])


def outputs_manifest(command: str) -> str:
    """The name of the file in which ``radiopose <command>`` lists, in its output
    directory, the files it wrote there (see :func:`replace_outputs`)."""
    return f".radiopose-{command}-outputs.json"


def _listed_outputs(manifest: Path) -> list[str]:
    """The relative paths a manifest lists; none if it is missing, not a regular file
    or not a manifest (a directory from before manifests, or the user's own)."""
    try:
        if not stat.S_ISREG(os.lstat(manifest).st_mode):
            return []
        doc = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return []
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return []
    return files


def _owned_file(root: Path, real_root: Path, rel: str) -> Path | None:
    """``root / rel`` if it is a regular file inside ``root`` reached through no
    symbolic link below ``root`` (``rel`` relative, canonical, without ``..``); else None."""
    pure = PurePosixPath(rel)
    if pure.as_posix() != rel or pure.is_absolute() or ".." in pure.parts or "\\" in rel:
        return None  # not as written ("./x", "a//b"), outside, or not a POSIX path
    path = root
    for part in pure.parts[:-1]:
        path = path / part
        if path.is_symlink() or not path.is_dir():
            return None
    path = path / pure.name
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None
        inside = path.resolve().relative_to(real_root) == Path(*pure.parts)
    except (OSError, ValueError):
        return None
    return path if inside else None


def replace_outputs(
    directory: str | os.PathLike[str], command: str, written: Sequence[str | os.PathLike[str]]
) -> list[Path]:
    """Record the files a run of ``radiopose <command>`` wrote into ``directory`` and
    remove those of its previous run there that this run did not write.

    Call it after the run's outputs are written. The previous run's list is read
    from ``directory``'s manifest (:func:`outputs_manifest`). A file it lists and
    ``written`` does not is removed only if it is a regular file (not a symbolic
    link) inside ``directory``, reached through no symbolic link below
    ``directory``; anything else is left alone. No manifest (a directory from
    before manifests, or one the command never wrote) means nothing is removed,
    so files the command did not write are never touched. The manifest is then
    rewritten (atomically) listing ``written`` (relative to ``directory``, each
    inside it), plus any stale file that could not be removed, to retry next
    time. Returns the removed files as ``directory / relative``, in order.
    """
    root = Path(directory)
    real_root = root.resolve()
    manifest = root / outputs_manifest(command)
    wrote: set[str] = set()
    for p in map(Path, written):
        try:
            inside = p.relative_to(root)
        except ValueError:
            inside = p.resolve().relative_to(real_root)  # ValueError: not inside directory
        wrote.add(inside.as_posix())
    removed: list[Path] = []
    kept: list[str] = []
    for rel in _listed_outputs(manifest):
        if rel in wrote or rel == manifest.name:
            continue
        path = _owned_file(root, real_root, rel)
        if path is None:
            continue  # no longer the run's file: replaced by a link, moved, or gone
        try:
            path.unlink()
        except OSError:
            kept.append(rel)
            continue
        removed.append(path)
    doc = {
        "about": f"the files the last radiopose {command} run wrote into this directory; "
        "the next one removes those it does not write again",
        "files": sorted(wrote | set(kept)),
    }
    with atomic_writer(manifest) as fh:
        fh.write(json.dumps(doc, indent=1) + "\n")
    return removed


def removed_outputs_note(
    command: str, directory: str | os.PathLike[str], removed: Sequence[Path]
) -> str:
    """The stderr line naming the files :func:`replace_outputs` removed, and why."""
    them, are = ("it", "it is") if len(removed) == 1 else ("them", "they are")
    return (
        f"{command}: removed {', '.join(map(str, removed))}: the previous {command} run into "
        f"this directory wrote {them} and this one did not, so {are} not in its report; "
        f"that run's results stay in {Path(directory) / 'parts'}/, from which the "
        "earlier command, run again, resumes them"
    )


def check_outputs_not_inputs(
    outputs: Sequence[str | os.PathLike[str] | None], inputs: Sequence[str | os.PathLike[str]]
) -> None:
    """Refuse, before any work, an output that would overwrite an input.

    An output is refused if it is (after symbolic links) one of the input files,
    or an existing file inside an input directory (a site directory holds only
    inputs). ``None`` outputs (an option not given) are skipped.

    Raises
    ------
    InputError
        Naming the output and the input it would overwrite.
    """
    files: dict[Path, Path] = {}
    dirs: list[tuple[Path, Path]] = []
    for given in map(Path, inputs):
        real = given.resolve()
        if real.is_dir():
            dirs.append((real, given))
        else:
            files[real] = given
    for out in outputs:
        if out is None:
            continue
        real = Path(out).resolve()
        if real in files:
            what = f"the input {os.fspath(files[real])!r}"
        elif real.is_file() and any(d in real.parents for d, _ in dirs):
            given = next(g for d, g in dirs if d in real.parents)
            what = f"a file of the input directory {os.fspath(given)!r}"
        else:
            continue
        raise InputError(f"the output would overwrite {what}", path=out)


@contextlib.contextmanager
def staged_directory(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Write a run's outputs into a staging directory, then move them into ``target``.

    Yields an empty directory beside ``target``. When the block succeeds, each
    entry written there replaces the entry of the same name in ``target``
    (a directory replaces the previous run's directory as a whole); entries of
    ``target`` not written by the run are left alone. When the block fails,
    nothing of the run reaches ``target``. A file where a directory is written
    (or the reverse) is refused before anything is moved.
    """
    target = Path(target)
    check_output_paths(dirs=[target])
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(
            tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".staging", dir=target.parent)
        )
    except OSError as exc:  # (named by the output, not by the staging directory's name)
        raise InputError(
            f"cannot write the output directory {target}: {exc.strerror or exc}"
        ) from None
    try:
        yield stage
        entries = sorted(stage.iterdir())
        check_output_paths(
            files=[target / e.name for e in entries if not e.is_dir()],
            dirs=[target / e.name for e in entries if e.is_dir()],
        )
        target.mkdir(exist_ok=True)
        for src in entries:
            dst = target / src.name
            old = None
            if src.is_dir() and dst.is_dir():
                old = Path(tempfile.mkdtemp(prefix=f".{src.name}.", suffix=".old", dir=target))
                os.replace(dst, old / src.name)
            os.replace(src, dst)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def staged_echo(
    echo: Callable[[str], None], stage: Path, target: str | os.PathLike[str]
) -> Callable[[str], None]:
    """``echo`` for lines written inside :func:`staged_directory`: the staging
    directory's path in a line is shown as ``target``'s, where the files end up."""
    stage_s, target_s = str(stage), str(Path(target))

    def say(line: str) -> None:
        echo(line.replace(stage_s, target_s))

    return say


def write_table(
    path: str | os.PathLike[str],
    columns: Mapping[str, Sequence | NDArray],
    *,
    decimals: Mapping[str, int] | None = None,
) -> None:
    """Write a CSV table atomically, columns in the given order.

    Floats are written with :func:`format_float` (``decimals`` per column,
    default 6) so that the same values always give the same bytes.
    """
    names = list(columns)
    n = len(columns[names[0]]) if names else 0
    for name in names:
        if len(columns[name]) != n:
            raise ValueError(f"column {name!r} has {len(columns[name])} rows, expected {n}")
    dec = dict(decimals or {})
    cols = [np.asarray(columns[name]) for name in names]
    with atomic_writer(path) as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(names)
        fmts = []
        for name, arr in zip(names, cols, strict=True):
            if arr.dtype.kind == "f":
                d = dec.get(name, 6)
                fmts.append(lambda v, d=d: format_float(float(v), d))
            else:
                fmts.append(str)
        for i in range(n):
            w.writerow([f(c[i]) for f, c in zip(fmts, cols, strict=True)])
