"""Validated access to TOML configuration (site.toml, experiment files).

:func:`load_toml` parses a file and turns syntax errors into one-line
:class:`~radiopose.errors.InputError` s naming file, line and column.
:class:`Section` reads typed, range-checked values and rejects unknown keys, so
a typo is an error naming the dotted key rather than a silently ignored setting.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Mapping
from typing import Any

from radiopose.errors import InputError


def load_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a TOML file; errors become one-line :class:`InputError` s."""
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
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
    except UnicodeDecodeError:
        raise InputError("invalid TOML: not UTF-8 text", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=path) from None


class Section:
    """Typed reader over one TOML table; tracks which keys were used.

    Parameters
    ----------
    data
        The table.
    path
        The file, for error messages.
    prefix
        Dotted name of the table (``"area"``), for error messages.
    """

    def __init__(self, data: Mapping[str, Any], path: str | os.PathLike[str], prefix: str = ""):
        if not isinstance(data, Mapping):
            raise InputError(f"key '{prefix}' must be a table", path=path)
        self.data = data
        self.path = str(path)
        self.prefix = prefix
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, message: str) -> InputError:
        return InputError(f"key '{self.key(name)}': {message}", path=self.path)

    def has(self, name: str) -> bool:
        return name in self.data

    def section(self, name: str, required: bool = True) -> Section:
        self.used.add(name)
        if name not in self.data:
            if required:
                raise InputError(f"missing table [{self.key(name)}]", path=self.path)
            return Section({}, self.path, self.key(name))
        return Section(self.data[name], self.path, self.key(name))

    def _get(self, name: str, default: Any) -> Any:
        self.used.add(name)
        if name not in self.data:
            if default is _REQUIRED:
                raise InputError(f"missing key '{self.key(name)}'", path=self.path)
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
            raise self.error(name, f"expected a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise self.error(name, f"expected a finite number, got {v}")
        if positive and v <= 0:
            raise self.error(name, f"must be > 0, got {v:g}")
        if (low is not None and v < low) or (high is not None and v > high):
            lo = "-inf" if low is None else f"{low:g}"
            hi = "inf" if high is None else f"{high:g}"
            raise self.error(name, f"value {v:g} out of range [{lo}, {hi}]")
        return v

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
            raise self.error(name, f"expected an integer, got {v!r}")
        if (low is not None and v < low) or (high is not None and v > high):
            raise self.error(name, f"value {v} out of range [{low}, {high}]")
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
            raise self.error(name, f"expected a non-empty string, got {v!r}")
        if choices is not None and v not in choices:
            raise self.error(name, f"expected one of {', '.join(choices)}, got {v!r}")
        return v

    def numbers(
        self,
        name: str,
        default: Any = None,
        *,
        low: float | None = None,
        high: float | None = None,
        nonempty: bool = True,
    ) -> tuple[float, ...]:
        v = self._get(name, default)
        if v is default and name not in self.data:
            return v
        if isinstance(v, int | float) and not isinstance(v, bool):
            v = [v]
        if not isinstance(v, list) or (nonempty and not v):
            raise self.error(name, "expected a non-empty list of numbers")
        out = []
        for i, x in enumerate(v):
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise self.error(name, f"item {i} is not a finite number: {x!r}")
            if (low is not None and x < low) or (high is not None and x > high):
                raise self.error(name, f"item {i} = {x:g} out of range [{low:g}, {high:g}]")
            out.append(float(x))
        return tuple(out)

    def boolean(self, name: str, default: Any = None) -> bool:
        v = self._get(name, default)
        if not isinstance(v, bool):
            raise self.error(name, f"expected true or false, got {v!r}")
        return v

    def finish(self) -> None:
        """Reject keys that were never read (typos)."""
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise InputError(f"unknown key '{self.key(unknown[0])}'", path=self.path)


_REQUIRED = object()
