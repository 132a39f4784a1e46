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
