"""Errors that reach the user as one line.

Every problem with user input is raised as :class:`InputError` (or a subclass)
whose message is a single line naming *where* (file, line, column or key) and
*what*. The CLI prints ``radiopose: <message>`` on stderr and exits with status 2;
no traceback reaches the user.
"""

from __future__ import annotations

from os import PathLike


class RadioposeError(Exception):
    """Base class of all radiopose errors that are reported as one line."""


class MethodError(RadioposeError):
    """A tracking method outside the package (a plugin, ``docs/methods.md``)
    failed or gave an estimate the contract does not allow (a non-finite
    value, no orientation where it estimates one); the message names the
    method, the transmitter and the packet."""


class InputError(RadioposeError):
    """Bad user input (file contents, arguments, configuration).

    Parameters
    ----------
    message
        What is wrong, one line.
    path
        The file concerned, if any.
    line
        1-based line number in the file (the header is line 1), if known.
    column
        Column name or configuration key, if known.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        column: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.column = column
        self.reason = " ".join(str(message).split())
        where = ""
        if self.path is not None:
            where = self.path
            if line is not None:
                where += f":{line}"
        if column is not None:
            where += (", " if where else "") + f"column '{column}'"
        super().__init__(f"{where}: {self.reason}" if where else self.reason)


def unreadable(path: str | PathLike[str], exc: OSError, expected: str = "a file") -> InputError:
    """The one-line :class:`InputError` for a file that cannot be opened or read.

    Parameters
    ----------
    path
        The file.
    exc
        The error of opening or reading it.
    expected
        What the file should have been, for the directory case (``"a CSV file"``).
    """
    if isinstance(exc, FileNotFoundError):
        return InputError("file not found", path=path)
    if isinstance(exc, IsADirectoryError):
        return InputError(f"is a directory, expected {expected}", path=path)
    return InputError(f"cannot read: {exc.strerror}", path=path)


def os_error_line(exc: OSError) -> str:
    """One line for an :class:`OSError` of a path the user gave (a directory where
    a file is expected, no permission, a full disk): ``FILENAME: REASON``, or the
    reason alone when the error names no file. The command line's and the
    research scripts' last resort (:func:`radiopose.cli.main`,
    :func:`radiopose.scripting.run_script`)."""
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or str(exc)}"


def check_setting_types(config: object, what: str) -> None:
    """Check that each field of the dataclass ``config`` holds a value of its
    annotated type, so that a configuration built in Python fails at
    construction, as a ``tracker.toml`` does when read: ``int`` an integer
    (not a bool), ``float`` a finite real number, ``float | None`` that or
    ``None``, ``bool`` a bool, ``str`` text, ``tuple[float, ...]`` a tuple of
    finite real numbers, ``tuple[float, float]`` a pair of them. Other
    annotations (nested configurations, ``Literal``) are the class's own checks.

    Raises
    ------
    InputError
        ``"{what} setting NAME = VALUE must be …"`` for the first field that is not.
    """
    import dataclasses
    import math
    import numbers

    def real(v: object) -> bool:
        return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)

    checks = {
        "int": (lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool),
                "an integer"),
        "float": (real, "a finite number"),
        "float | None": (lambda v: v is None or real(v), "a finite number or None"),
        # numpy's bool is not a bool subclass: accepted by its type's name
        "bool": (lambda v: isinstance(v, bool) or type(v).__name__ == "bool_", "true or false"),
        "str": (lambda v: isinstance(v, str), "text"),
        "tuple[float, ...]": (
            lambda v: isinstance(v, tuple) and all(real(x) for x in v),
            "a tuple of finite numbers",
        ),
        "tuple[float, float]": (
            lambda v: isinstance(v, tuple) and len(v) == 2 and all(real(x) for x in v),
            "a pair of finite numbers (low, high)",
        ),
    }  # fmt: skip
    for f in dataclasses.fields(config):  # type: ignore[arg-type]
        check = checks.get(str(f.type))
        if check is None:
            continue
        value = getattr(config, f.name)
        ok, expected = check
        if not ok(value):
            raise InputError(f"{what} setting {f.name} = {value!r} must be {expected}")
