"""The ``radiopose`` command line: parsing and printing only.

Each area registers its commands from its own module (``cli/<area>.py``) on the
one :data:`app`; the work itself lives in the library. :func:`main` turns every
:class:`~radiopose.errors.RadioposeError` into ``radiopose: <one line>`` on
stderr with exit status 2 — no traceback reaches the user.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any

import typer

from radiopose.errors import RadioposeError, os_error_line

app = typer.Typer(
    name="radiopose",
    help="Passive position and orientation estimation of wireless devices from RSS.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


@app.callback()
def _root() -> None:
    """Passive position and orientation estimation of wireless devices from RSS."""


def fail(message: str) -> typer.Exit:
    """Print a one-line error on stderr and return the exit to raise."""
    print(f"radiopose: {message}", file=sys.stderr)
    return typer.Exit(2)


def count_progress(label: str, *, elapsed: bool = True, description: bool = False) -> Any:
    """A transient rich progress bar over a count of runs or packets:
    ``label``, bar, done/total, [elapsed,] remaining[, the task's description]."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns: list[Any] = [TextColumn(label), BarColumn(), MofNCompleteColumn()]
    if elapsed:
        columns.append(TimeElapsedColumn())
    columns.append(TimeRemainingColumn())
    if description:
        columns.append(TextColumn("{task.description}"))
    return Progress(*columns, transient=True)


@contextmanager
def method_progress(
    label: str, show: bool
) -> Iterator[tuple[Callable[[str, int, int], None] | None, Callable[[str], None]]]:
    """A transient bar over packets (:func:`count_progress`) while the block runs,
    when ``show``, for several methods in turn: it names the one it is on. Yields
    ``(progress, echo)``: the ``progress(method, done, total)`` callback
    :func:`radiopose.evaluate.run_methods` takes, and a print that does not break
    the bar; ``(None, print)`` when not shown."""
    if not show:
        yield None, print
        return
    with count_progress(label, elapsed=False, description=True) as bar:
        task = bar.add_task("", total=None)

        def progress(method: str, done: int, total: int) -> None:
            bar.update(task, completed=done, total=total, description=method)

        yield progress, partial(bar.console.print, markup=False, highlight=False)


@contextmanager
def packet_progress(
    label: str, show: bool
) -> Iterator[tuple[Callable[[int, int], None] | None, Callable[[str], None]]]:
    """:func:`method_progress` for one method: yields the ``progress(done,
    total)`` callback :func:`radiopose.tracker.locate` takes (or ``None``) and
    the print."""
    with method_progress(label, show) as (progress, echo):
        yield (None if progress is None else partial(progress, "")), echo


def _register() -> None:
    # Imported for their side effect of adding commands to ``app``.
    import importlib

    for name in (
        "core",
        "patterns",
        "capture",
        "pipeline",
        "server",
        "evaluate",
        "security",
        "realdata",
    ):
        try:
            importlib.import_module(f"radiopose.cli.{name}")
        except ModuleNotFoundError as exc:  # an area not written yet
            if exc.name != f"radiopose.cli.{name}":
                raise


def _usage_message(exc: Exception, message: str) -> str:
    """A click usage error's ``message`` on one line; a bad value in the project's
    form, ``--receivers: 'x' is not a valid integer``, instead of click's
    ``Invalid value for '--receivers': …`` around the pydantic wording that recent
    typer passes on (``Input should be a valid integer, unable to parse string as
    an integer``, ``Value error, 'zz' is not one of …``)."""
    if (
        not isinstance(exc, typer.BadParameter)
        or exc.param is None
        or not message.startswith("Invalid value for ")
    ):  # a missing option, an unknown one, …
        return " ".join(message.split())
    param = exc.param
    opts = [o for o in param.opts if o.startswith("-")]
    name = max(opts, key=len) if opts else str(param.name)  # an argument: its name
    reason = str(exc.message)
    errors = getattr(exc.__cause__, "errors", None)  # typer's pydantic coercion
    if callable(errors) and errors():
        first = errors()[0]
        given = first.get("input")
        kind = first.get("type")
        if kind == "int_parsing":
            reason = f"{given!r} is not a valid integer"
        elif kind == "float_parsing":
            reason = f"{given!r} is not a valid number"
        elif kind == "value_error" and "error" in first.get("ctx", {}):
            reason = str(first["ctx"]["error"])
    reason = reason.removeprefix("Value error, ").rstrip(".")
    return f"{name}: {' '.join(reason.split())}"


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit status."""
    _register()
    try:
        # prog_name: the errors and usage lines say "radiopose simulate", also when run
        # as `python -m radiopose` or in process (click took it from sys.argv[0])
        app(args=argv, prog_name="radiopose", standalone_mode=False)
    except RadioposeError as exc:
        print(f"radiopose: {exc}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except OSError as exc:
        # A path the user gave cannot be read or written: one line, no trace.
        print(f"radiopose: {os_error_line(exc)}", file=sys.stderr)
        return 2
    except typer.Abort:
        print("radiopose: aborted", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("radiopose: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        # Usage errors of the (vendored) click layer: show their one-line message.
        fmt = getattr(exc, "format_message", None)
        code = getattr(exc, "exit_code", None)
        if callable(fmt) and isinstance(code, int):
            ctx = getattr(exc, "ctx", None)
            where = ctx.command_path if ctx is not None else "radiopose"
            print(f"{where}: {_usage_message(exc, str(fmt()))}", file=sys.stderr)
            return code
        # Anything else is a bug (or memory ran out): still one line for the
        # user; RADIOPOSE_TRACEBACK=1 shows the traceback for a report.
        if os.environ.get("RADIOPOSE_TRACEBACK"):
            raise
        if isinstance(exc, MemoryError):
            print("radiopose: out of memory (reduce the grid or the trace)", file=sys.stderr)
            return 3
        what = " ".join(str(exc).split()) or "no message"
        print(
            f"radiopose: internal error, {type(exc).__name__}: {what} "
            "(please report it; RADIOPOSE_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
