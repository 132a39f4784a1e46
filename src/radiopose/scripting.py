"""Command-line plumbing of the research scripts (``scripts/*.py``).

The scripts parse their options with :mod:`argparse`. Bad input must reach the
user as one line naming what is wrong, with exit status 2, no traceback and
nothing half-written, and be found before the long work starts (the
``radiopose`` command's rule, :func:`radiopose.cli.main`). This module gives them:

* ``type=`` helpers for counts and numbers (:func:`positive_int`,
  :func:`non_negative_int`, :func:`finite_float`, :func:`positive_float`,
  :func:`non_negative_float`): a bad value is the parser's own usage error,
  ``usage: …`` and ``script.py: error: argument --seeds: must be an integer
  >= 1, got '0'`` on stderr, exit status 2;
* :func:`check_output`: an ``--out`` file or directory that could not be
  written, refused as the parser's usage error before any work;
* :func:`usage_errors`: a configuration built from the options and refused by
  its own checks (:class:`~radiopose.errors.InputError`), turned into the
  parser's usage error;
* :func:`run_script`: the scripts' entry point
  (``raise SystemExit(run_script(main))``), which turns what is still found
  during the work — a :class:`~radiopose.errors.RadioposeError`, an
  :class:`OSError` of a path given — into ``script.py: <one line>`` on stderr
  and exit status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from radiopose.errors import InputError, RadioposeError, os_error_line
from radiopose.tables import check_output_paths

__all__ = [
    "check_output",
    "finite_float",
    "non_negative_float",
    "non_negative_int",
    "positive_float",
    "positive_int",
    "run_script",
    "usage_errors",
]


def _integer(text: str) -> int:
    """``text`` as an integer; not an integer (``'1.5'``, ``'x'``) is a type error."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def _number(text: str) -> float:
    """``text`` as a finite float; not a number, NaN or ±inf is a type error."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (a count of seeds, packets, runs, receivers, jobs).

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not an integer, or is below 1.
    """
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0 (a simulation seed; a count where 0 means none).

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not an integer, or is negative.
    """
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite number (not NaN, not ±inf).

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not a number, or is NaN or infinite.
    """
    return _number(text)


def positive_float(text: str) -> float:
    """A finite number > 0 (a noise σ, a duration, a step).

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not a finite number, or is not above 0.
    """
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0 (a window where 0 means per packet; an error where 0 means none).

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not a finite number, or is negative.
    """
    value = _number(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def check_output(
    parser: argparse.ArgumentParser,
    option: str,
    *,
    files: Sequence[str | os.PathLike[str]] = (),
    dirs: Sequence[str | os.PathLike[str]] = (),
) -> None:
    """Refuse, before any work, outputs that could not be written: each of
    ``files`` an existing directory, each of ``dirs`` an existing file, a parent
    of either a file (:func:`radiopose.tables.check_output_paths`), or an
    existing path (or, for a new one, its nearest existing parent) not
    writable. The refusal is the parser's usage error naming ``option`` and the
    path (``--out /tmp/x: is a directory, expected a file path``; exit status 2).
    Nothing is created."""
    try:
        check_output_paths(files=files, dirs=dirs)
    except OSError as exc:
        parser.error(f"{option} {exc.filename}: {exc.strerror}")
    for path in map(Path, [*files, *dirs]):
        existing = next((p for p in (path, *path.parents) if p.exists()), None)
        if existing is not None and not os.access(existing, os.W_OK):
            where = "" if existing == path else f" (in {existing})"
            parser.error(f"{option} {path}: permission denied{where}")


@contextmanager
def usage_errors(parser: argparse.ArgumentParser, prefix: str = "") -> Iterator[None]:
    """Within the block, an :class:`~radiopose.errors.InputError` (a configuration
    built from the options refusing a value) is the parser's usage error:
    ``prefix`` and the error's one line, exit status 2. For checks made before
    the work starts::

        with usage_errors(ap):
            replace(ScenarioConfig(), noise_db=args.sigma).validate()
    """
    try:
        yield
    except InputError as exc:
        parser.error(f"{prefix} {exc}" if prefix else str(exc))


def _script_name(main: Callable[..., object]) -> str:
    """The file name of the script that defines ``main`` (``accuracy_table.py``)."""
    code = getattr(main, "__code__", None)
    path = code.co_filename if code is not None else (sys.argv[0] or "script")
    return Path(path).name


def run_script(
    main: Callable[[list[str] | None], int | None], argv: list[str] | None = None
) -> int:
    """Run a script's ``main(argv)`` and return its exit status.

    ``None`` from ``main`` is status 0. A
    :class:`~radiopose.errors.RadioposeError` (bad input found during the
    work) becomes ``<script name>: <message>`` on stderr and status 2; an
    :class:`OSError` (a path that cannot be read or written)
    ``<script name>: <filename>: <reason>`` and status 2; a
    :class:`KeyboardInterrupt` ``<script name>: interrupted`` and status 130.
    :class:`SystemExit` (the parser's usage errors, status 2) and anything else
    propagate: a bug shows its traceback.
    """
    name = _script_name(main)
    try:
        code = main(argv)
    except RadioposeError as exc:
        print(f"{name}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{name}: {os_error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    return 0 if code is None else code
