"""Helpers shared by the pattern-file importers: reading text, checked numbers.

Every importer reports a bad value as a one-line :class:`~radiopose.errors.InputError`
naming the file, line and column; the checks that do that live here once.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

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


@contextmanager
def _in_file(path: Path) -> Iterator[None]:
    """Give ``path`` to an :class:`InputError` raised without a file: the
    :class:`Pattern` checks (e.g. a directivity beyond the pattern CSV's
    ±200 dBi, which a gain and an attenuation each in range can reach) name
    the pattern and the angle, not the file it was imported from."""
    try:
        yield
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(exc.reason, path=path, column=exc.column) from None


def _normalised(pattern: Pattern, normalise: bool) -> Pattern:
    return pattern.normalised() if normalise else pattern


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


MIN_CIRCLE_ANGLES = 3
"""Fewest distinct angles around a circle an imported pattern is built from: the
azimuths of a sphere, each MSI cut, the MIT LL capture angles. The periodic cubic
spline of :func:`~radiopose.patterns.enrol.fill_periodic` needs 3; with 2 it draws a
line between them and with 1 a constant, not a measured pattern."""

MIN_SPHERE_POLAR_ANGLES = 3
"""Fewest polar angles of an imported sphere: both poles and one between them (a pole
is one direction whatever its azimuth, so poles alone carry no azimuth pattern)."""


def _require_angles(
    angles_deg: ArrayLike,
    minimum: int,
    what: str,
    needs: str,
    path: Path,
    line: int | None = None,
    column: str | None = None,
) -> None:
    """Check that ``angles_deg`` holds at least ``minimum`` distinct values.

    The one check of :data:`MIN_CIRCLE_ANGLES` and :data:`MIN_SPHERE_POLAR_ANGLES`
    for every importer.

    Raises
    ------
    InputError
        ``"{what}: N distinct angle(s) (a, b deg), {needs}"`` at ``path``, ``line``,
        ``column``.
    """
    distinct = np.unique(np.asarray(angles_deg, dtype=np.float64))
    if distinct.size >= minimum:
        return
    listed = ", ".join(f"{a:g}" for a in distinct)
    plural = "" if distinct.size == 1 else "s"
    raise InputError(
        f"{what}: {distinct.size} distinct angle{plural} ({listed} deg), {needs}",
        path=path,
        line=line,
        column=column,
    )
