"""Helpers shared by the pattern-file importers: reading text, checked numbers.

Every importer reports a bad value as a one-line :class:`~radiopose.errors.InputError`
naming the file, line and column; the checks that do that live here once.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from radiopose.errors import InputError, unreadable
from radiopose.patterns.pattern import Pattern

DBD_TO_DBI = 2.15
"""Gain of a half-wave dipole over isotropic, dB (``G_dBi = G_dBd + 2.15``)."""

_ROUND = 6


def _stem(path: str | os.PathLike[str]) -> str:
    return Path(path).stem


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text ({exc.reason})", path=path) from None
    except OSError as exc:
        raise unreadable(path, exc, "a file") from None


# Largest |value| of a gain, attenuation or directivity in any imported file, dB:
# real antennas span well under 100 dB; anything near 1e308 is a corrupt file.
MAX_ABS_DB = 1000.0


def _finite(
    text: str, path: Path, line: int | None, column: str, limit: float | None = None
) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"not a number: {text[:40]!r}", path=path, line=line, column=column
        ) from None
    if not math.isfinite(value):
        raise InputError(f"not a finite number: {text!r}", path=path, line=line, column=column)
    if limit is not None and abs(value) > limit:
        raise InputError(
            f"{text[:40]} is out of range [-{limit:g}, {limit:g}]",
            path=path,
            line=line,
            column=column,
        )
    return value


def _normalised(pattern: Pattern, normalise: bool) -> Pattern:
    return pattern.normalised() if normalise else pattern


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
