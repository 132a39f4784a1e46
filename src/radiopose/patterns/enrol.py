"""Pattern enrolment: positioner RSS measurements -> directivity pattern (dBi).

A device is turned on a positioner in front of a fixed receiver in the far
field; each received packet gives one row ``(motor_azimuth_deg,
motor_elevation_deg, rss_dbm)`` (``docs/patterns.md``, contract "Enrolment
measurements"). :func:`enrol` turns those rows into a :class:`Pattern`:

1. **Pattern angles** — ``phi = (360 − motor_azimuth) mod 360``,
   ``theta = motor_elevation`` (the contract's positioner convention).
2. **Average per direction** — the packets of one direction are averaged as
   powers: ``P̄ = mean(10^(rss_dbm/10))`` mW (never the mean of dBm).
3. **Bin onto the output grid** — each direction goes to the nearest grid
   azimuth (step ``azimuth_step_deg``, default 1°) and polar row; directions
   sharing a bin are averaged in mW (one vote per direction).
4. **Fill empty azimuths** of each measured polar row by *periodic*
   interpolation through the filled bins — by default a periodic cubic spline
   (``scipy.interpolate.CubicSpline(bc_type="periodic")``) in the **dB**
   domain, which cannot go negative and follows a lobe's shape between sparse
   samples (e.g. 8 azimuths 45° apart). ``interpolation="linear"`` gives
   piecewise-linear periodic interpolation; ``interpolation_domain="linear"``
   interpolates mW instead (clipped at 1e-3 × the smallest measured power).
   A gap between consecutive measured azimuths (circularly) wider than
   :data:`MAX_FILL_GAP_DEG` is an error (:class:`CoverageGapError`), as is, on
   a full sphere, such a gap between measured elevations or from a pole: the
   fill would invent most of the pattern.
5. **Fill empty polar rows** (full sphere only) per azimuth, linearly in dB
   between the nearest measured rows, held constant beyond the first/last
   measured row. The pole rows (θ = 0°, 180°: one physical direction each)
   are then replaced by their mW mean.
6. **Smooth** each polar row with a centred circular boxcar of ±``smooth_deg``
   (default ±5°) in the **linear** (mW) domain. A circular boxcar preserves
   the row's mean power, so smoothing does not change ``P_rad``.
   ``smoothing_domain="db"`` exists for comparison only (see below).
7. **Directivity** — ``D = U / (P_rad / 4π)``: for a full sphere the mean
   of ``U`` is ``sinθ``-weighted (trapezoid in θ, see
   :func:`~radiopose.patterns.pattern.mean_intensity`); for a single slice it
   is the slice mean. Stored in dBi.

Why linear smoothing: averaging dB values is a geometric mean, which pulls
narrow peaks down; the lost power is put back by the directivity
normalisation as a uniform *upward* shift, which lifts (fills) the troughs.
Averaging mW keeps the row's power, so the troughs stay where they were up to
the window's own blur (``tests/test_patterns_enrol.py`` measures both).
"""

from __future__ import annotations

import numbers
import os
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from radiopose.errors import InputError, check_setting_types
from radiopose.patterns.pattern import (
    MAX_POLAR_ANGLES,
    MIN_GRID_STEP_DEG,
    Pattern,
    finite_number,
    grid_count,
    mean_intensity,
    too_fine,
    unwritable,
)
from radiopose.tables import Column, Table, read_table, write_table
from radiopose.units import (
    FloatArray,
    dbm_to_mw,
    linear_to_db,
    mw_to_dbm,
    wrap_deg,
)

MEASUREMENT_COLUMNS = (
    Column("motor_azimuth_deg", low=0.0, high=360.0),
    Column("motor_elevation_deg", low=0.0, high=180.0),
    Column("rss_dbm", low=-200.0, high=60.0),
)
"""Required columns of an enrolment CSV and their valid ranges (360° = 0°)."""

_ANGLE_DECIMALS = 6  # directions equal to 1e-6 deg are the same direction

MAX_FILL_GAP_DEG = 90.0
"""Widest gap the fill may bridge, degrees: between consecutive measured azimuths
of a polar row (circularly; a pole row of a sphere is one direction and exempt),
and on a full sphere between consecutive measured elevations or from a pole to
the nearest one. Wider is a :class:`CoverageGapError`. The shipped real patterns
(MIT LL, 8 azimuths) leave 45°, as do the sparsest enrolments of the tests; 90°
is four positioner stops, the fewest that describe a front, back and sides.
A gap is refused only beyond :data:`FILL_GAP_SLACK_DEG` more than this."""

FILL_GAP_SLACK_DEG = 1.0
"""Tolerance on :data:`MAX_FILL_GAP_DEG`, degrees: a gap is refused only when it is
wider than ``MAX_FILL_GAP_DEG + FILL_GAP_SLACK_DEG`` (91°). Angles read back from
a positioner's encoder are a little off the plan: the four-stop plan logged as
motor azimuths 0, 90.2, 180, 270 (a 90.2° gap) or 350, 80, 170, 260.5 (90.5°) is
still four stops 90° apart and is filled; a missing stop leaves 135° or more."""

RADIAN_HINT_MAX = 6.3
"""Motor azimuths all in ``[0, RADIAN_HINT_MAX]`` (just above 2π) under a
:class:`CoverageGapError` were likely given in radians: the error says so."""

MAX_SIMULATED_PACKETS = 10_000_000
"""Most packets :func:`simulate_positioner_measurements` makes (checked before allocating)."""


@dataclass(frozen=True)
class EnrolConfig:
    """Settings of :func:`enrol`.

    Invalid settings raise :class:`~radiopose.errors.InputError` whose
    ``column`` is the attribute name (the CLI names its option instead); a
    setting of the wrong type (``smooth_deg="5"``, ``azimuth_step_deg=True``)
    is named in the message by :func:`~radiopose.errors.check_setting_types`.
    Steps finer than :data:`~radiopose.patterns.pattern.MIN_GRID_STEP_DEG`
    (0.1°) are rejected: at most 3600 azimuths × 1801 polar angles.

    Attributes
    ----------
    smooth_deg
        Half-width of the centred circular smoothing window along azimuth,
        degrees (the window is ``[phi − smooth_deg, phi + smooth_deg]``);
        ``0`` disables smoothing.
    azimuth_step_deg
        Output azimuth grid step, degrees; must divide 360.
    polar_step_deg
        Output polar step for a full-sphere measurement, degrees (must divide
        180); ``None`` takes the smallest spacing of the measured elevations.
        Ignored for a single-elevation (slice) measurement.
    interpolation
        ``"spline"`` (periodic cubic spline) or ``"linear"`` (periodic
        piecewise linear), used to fill azimuths without samples.
    interpolation_domain
        ``"db"`` (default) or ``"linear"``: the domain the fill interpolates in.
    smoothing_domain
        ``"linear"`` (default, the method) or ``"db"`` (for comparison only:
        it fills troughs).
    """

    smooth_deg: float = 5.0
    azimuth_step_deg: float = 1.0
    polar_step_deg: float | None = None
    interpolation: Literal["spline", "linear"] = "spline"
    interpolation_domain: Literal["db", "linear"] = "db"
    smoothing_domain: Literal["linear", "db"] = "linear"

    def __post_init__(self) -> None:
        check_setting_types(self, "enrolment")
        if not (np.isfinite(self.smooth_deg) and 0.0 <= self.smooth_deg < 180.0):
            raise InputError(
                f"smoothing half-width {self.smooth_deg} deg not in [0, 180)", column="smooth_deg"
            )
        _grid_count(self.azimuth_step_deg, 360.0, "azimuth step", "azimuth_step_deg")
        if self.polar_step_deg is not None:
            _grid_count(self.polar_step_deg, 180.0, "polar step", "polar_step_deg")
        if self.interpolation not in ("spline", "linear"):
            raise InputError(
                f"unknown interpolation {self.interpolation!r:.40} (spline|linear)",
                column="interpolation",
            )
        if self.interpolation_domain not in ("db", "linear"):
            raise InputError(
                f"unknown interpolation domain {self.interpolation_domain!r:.40} (db|linear)",
                column="interpolation_domain",
            )
        if self.smoothing_domain not in ("linear", "db"):
            raise InputError(
                f"unknown smoothing domain {self.smoothing_domain!r:.40} (linear|db)",
                column="smoothing_domain",
            )


class MeasurementError(InputError, ValueError):
    """Bad :class:`Measurements` arrays (an :class:`InputError`; also a
    :class:`ValueError`, which the constructor raised before)."""


@dataclass(frozen=True, eq=False)
class Measurements:
    """Positioner measurements, one entry per received packet.

    Attributes
    ----------
    motor_azimuth_deg, motor_elevation_deg
        ``(n,)`` positioner angles, degrees (azimuth in ``[0, 360]``,
        elevation = pattern polar angle in ``[0, 180]``).
    rss_dbm
        ``(n,)`` received signal strength, dBm, in ``[-200, 60]``.

    Values outside the ranges of the enrolment CSV (:data:`MEASUREMENT_COLUMNS`)
    or not finite raise :class:`MeasurementError` (an :class:`InputError`)
    naming the array and index.
    """

    motor_azimuth_deg: FloatArray
    motor_elevation_deg: FloatArray
    rss_dbm: FloatArray

    def __post_init__(self) -> None:
        arrays = []
        for col in MEASUREMENT_COLUMNS:
            try:
                arrays.append(np.array(getattr(self, col.name), dtype=np.float64).reshape(-1))
            except (TypeError, ValueError):
                raise MeasurementError(
                    f"measurement {col.name} is not an array of numbers", column=col.name
                ) from None
        if len({a.size for a in arrays}) != 1:
            names = [c.name for c in MEASUREMENT_COLUMNS]
            sizes = ", ".join(f"{n} {a.size}" for n, a in zip(names, arrays, strict=True))
            raise MeasurementError(f"measurement arrays differ in length ({sizes})")
        for col, a in zip(MEASUREMENT_COLUMNS, arrays, strict=True):
            # the enrolment CSV's ranges (read_measurements_csv), one reduction each
            assert col.low is not None and col.high is not None
            ok = (a >= col.low) & (a <= col.high)  # False for NaN
            if not ok.all():
                r = int(np.argmin(ok))
                what = "out of range" if np.isfinite(a[r]) else "not a finite number, expected"
                raise MeasurementError(
                    f"measurement {col.name}[{r}] = {a[r]:g} is {what} {col.describe_range()}",
                    column=col.name,
                )
            a.setflags(write=False)
            object.__setattr__(self, col.name, a)

    def __len__(self) -> int:
        return int(self.rss_dbm.size)


# ---------------------------------------------------------------------- CSV io
def read_measurements_csv(path: str | os.PathLike[str]) -> Measurements:
    """Read an enrolment CSV (``motor_azimuth_deg, motor_elevation_deg, rss_dbm``).

    Raises
    ------
    InputError
        Missing column, unparsable/NaN/inf/out-of-range value (naming file,
        line and column), or no data rows.
    """
    return _measurements(_read_measurement_table(path))


def _read_measurement_table(path: str | os.PathLike[str]) -> Table:
    table = read_table(path, MEASUREMENT_COLUMNS)
    if len(table) == 0:
        raise InputError("no measurement rows", path=path, line=2)
    return table


def _measurements(table: Table) -> Measurements:
    return Measurements(table["motor_azimuth_deg"], table["motor_elevation_deg"], table["rss_dbm"])


def write_measurements_csv(measurements: Measurements, path: str | os.PathLike[str]) -> None:
    """Write measurements as an enrolment CSV (atomically).

    Raises
    ------
    InputError
        ``path`` is a directory or cannot be written (one line naming it).
    """
    try:
        write_table(
            path,
            {
                "motor_azimuth_deg": measurements.motor_azimuth_deg,
                "motor_elevation_deg": measurements.motor_elevation_deg,
                "rss_dbm": measurements.rss_dbm,
            },
        )
    except OSError as exc:
        raise unwritable(path, exc) from None


# ---------------------------------------------------------------------- kernels
class PolarStepError(InputError):
    """Measured elevations closer than the grid limit (raised by :func:`enrol`).

    ``elevation_deg`` is the larger of the two closest measured elevations
    (pattern polar angles); :func:`enrol_csv` reports it at its first row.
    """

    def __init__(self, message: str, elevation_deg: float) -> None:
        super().__init__(message, column="motor_elevation_deg")
        self.elevation_deg = elevation_deg


class CoverageGapError(InputError):
    """The measurements leave a gap wider than :data:`MAX_FILL_GAP_DEG` for the
    fill (raised by :func:`enrol`; :func:`enrol_csv` names the file). ``column``
    is ``motor_azimuth_deg`` or ``motor_elevation_deg``.

    ``radians``: every motor azimuth lies in ``[0, RADIAN_HINT_MAX]``; the message
    then ends with a hint naming ``column`` as in degrees. :meth:`at` reports the
    error at a file and, for an importer, its own column (MIT LL: ``Angle``), so
    the hint names the column of the file being read.
    """

    def __init__(
        self,
        message: str,
        *,
        column: str,
        path: str | os.PathLike[str] | None = None,
        radians: bool = False,
    ) -> None:
        self.gap_reason = message
        self.radians = radians
        hint = (
            f"; every motor azimuth lies in [0, {RADIAN_HINT_MAX:g}]: radians? "
            f"{column} is in degrees"
            if radians
            else ""
        )
        super().__init__(message + hint, path=path, column=column)

    def at(self, path: str | os.PathLike[str], column: str | None = None) -> CoverageGapError:
        """This error reported at ``path`` and ``column`` (default: its own column)."""
        return CoverageGapError(
            self.gap_reason, column=column or self.column or "", path=path, radians=self.radians
        )


def largest_circular_gap(azimuth_deg: ArrayLike) -> tuple[float, float]:
    """``(gap, start)`` degrees: the widest gap between consecutive distinct azimuths
    around the circle (from ``start`` up to ``start + gap``, wrapping at 360);
    one azimuth leaves a 360° gap from itself."""
    x = np.unique(wrap_deg(azimuth_deg))
    gaps = np.diff(np.append(x, x[0] + 360.0))
    k = int(np.argmax(gaps))
    return float(gaps[k]), float(x[k])


def _too_wide(gap_deg: float) -> bool:
    """Whether the fill may not bridge ``gap_deg`` (see :data:`FILL_GAP_SLACK_DEG`)."""
    return gap_deg > MAX_FILL_GAP_DEG + FILL_GAP_SLACK_DEG


def _check_coverage(
    d_phi: FloatArray,
    d_theta: FloatArray,
    j_po: np.ndarray,
    po_grid: FloatArray,
    motor_azimuth_deg: FloatArray,
) -> None:
    """Raise :class:`CoverageGapError` if the fill would bridge more than
    :data:`MAX_FILL_GAP_DEG` + :data:`FILL_GAP_SLACK_DEG` (the measured directions
    ``d_phi, d_theta``, degrees, binned to polar rows ``j_po`` of ``po_grid``)."""
    n_po = po_grid.size
    worst: tuple[float, float, float] | None = None  # (gap, start phi, polar angle)
    most_azimuths = 0  # distinct azimuths of the fullest ring (off the poles)
    for j in np.unique(j_po):
        if n_po > 1 and j in (0, n_po - 1):  # a pole row is one direction
            continue
        ring = d_phi[j_po == j]
        most_azimuths = max(most_azimuths, np.unique(ring).size)
        gap, start = largest_circular_gap(ring)
        if worst is None or gap > worst[0]:
            worst = (gap, start, float(po_grid[j]))
    if worst is not None and _too_wide(worst[0]):
        gap, start, theta = worst
        lo = float(wrap_deg(360.0 - (start + gap)))  # the motor turns the other way
        where = f" at elevation {theta:g}°" if n_po > 1 else ""
        hint = ""
        if n_po > 1 and most_azimuths <= 2:  # principal-plane cuts, not a sphere
            hint = (
                "; every elevation off the poles has at most 2 motor azimuths (a cut "
                "through the poles: the fill would invent half of every ring): measure at "
                f"least 4, at most {MAX_FILL_GAP_DEG:g}° apart (e.g. add the orthogonal cut)"
            )
        if gap >= 360.0:  # one azimuth
            span = f"every motor azimuth but {_deg(lo)}°"
        elif lo + gap > 360.0:
            span = f"motor azimuths {_deg(lo)}–{_deg(lo + gap - 360.0)}° through 0°"
        else:
            span = f"motor azimuths {_deg(lo)}–{_deg(lo + gap)}°"
        raise CoverageGapError(
            f"measurements leave {span}{where} "
            f"(a {_deg(gap)}° gap) unmeasured; at most {MAX_FILL_GAP_DEG:g}° can be "
            f"filled{hint}",
            column="motor_azimuth_deg",
            radians=float(np.max(motor_azimuth_deg)) <= RADIAN_HINT_MAX,
        )
    if n_po > 1:
        edges = np.concatenate([[0.0], np.unique(d_theta), [180.0]])
        gaps = np.diff(edges)
        k = int(np.argmax(gaps))
        if _too_wide(float(gaps[k])):
            raise CoverageGapError(
                f"measurements leave motor elevations {_deg(edges[k])}–{_deg(edges[k + 1])}° "
                f"(a {_deg(gaps[k])}° gap) unmeasured; at most {MAX_FILL_GAP_DEG:g}° can be "
                "filled",
                column="motor_elevation_deg",
            )


def _deg(value: float) -> str:
    """An angle for a message, degrees to 0.001."""
    return f"{round(float(value), 3):g}"


def _grid_count(step_deg: float, span_deg: float, what: str, field: str) -> int:
    """Grid steps in ``span_deg``, checked from the numbers before any grid exists."""
    return grid_count(step_deg, span_deg, what, field)


def motor_to_pattern_deg(
    motor_azimuth_deg: ArrayLike, motor_elevation_deg: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Positioner angles -> pattern angles: ``phi = (360 − az) mod 360``, ``theta = el``."""
    phi = wrap_deg(360.0 - np.asarray(motor_azimuth_deg, dtype=np.float64))
    return phi, np.asarray(motor_elevation_deg, dtype=np.float64).copy()


def pattern_to_motor_deg(
    azimuth_deg: ArrayLike, polar_deg: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Pattern angles -> positioner angles (inverse of :func:`motor_to_pattern_deg`)."""
    return wrap_deg(360.0 - np.asarray(azimuth_deg, dtype=np.float64)), np.asarray(
        polar_deg, dtype=np.float64
    ).copy()


def average_per_direction(
    azimuth_deg: ArrayLike, polar_deg: ArrayLike, rss_dbm: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean received power of each distinct direction, averaged in mW.

    Parameters
    ----------
    azimuth_deg, polar_deg
        ``(n,)`` pattern angles of each packet, degrees (equal to 1e-6° = same direction).
    rss_dbm
        ``(n,)`` RSS of each packet, dBm.

    Returns
    -------
    azimuth_deg, polar_deg, power_mw
        ``(m,)`` each: the distinct directions and their mean power in mW.
    """
    phi = np.round(wrap_deg(azimuth_deg), _ANGLE_DECIMALS)
    phi = np.where(phi >= 360.0, 0.0, phi)
    theta = np.round(np.asarray(polar_deg, dtype=np.float64), _ANGLE_DECIMALS)
    keys = np.stack([phi, theta], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    # P̄ = Σ P_i / n per direction, in mW
    total = np.bincount(inverse, weights=dbm_to_mw(rss_dbm), minlength=uniq.shape[0])
    count = np.bincount(inverse, minlength=uniq.shape[0])
    return uniq[:, 0], uniq[:, 1], total / count


def fill_periodic(
    azimuth_deg: ArrayLike,
    values: ArrayLike,
    grid_deg: ArrayLike,
    method: Literal["spline", "linear"] = "spline",
) -> FloatArray:
    """Periodic (360°) interpolation of samples onto a grid.

    Parameters
    ----------
    azimuth_deg
        ``(k,)`` distinct sample azimuths, degrees (any order, any spacing).
    values
        ``(k,)`` sample values (any unit; interpolated as given).
    grid_deg
        ``(m,)`` azimuths to evaluate at, degrees.
    method
        ``"spline"``: cubic spline with periodic boundary conditions through
        the samples (``k ≥ 3``; two samples fall back to linear); ``"linear"``:
        piecewise linear, periodic. One sample gives a constant.

    Returns
    -------
    ``(m,)`` interpolated values; equal to ``values`` at the sample azimuths.
    """
    x = wrap_deg(azimuth_deg)
    y = np.asarray(values, dtype=np.float64)
    order = np.argsort(x)
    x, y = x[order], y[order]
    g = np.asarray(grid_deg, dtype=np.float64)
    if x.size == 1:
        return np.full(g.shape, y[0])
    if method == "linear" or x.size == 2:
        return np.interp(wrap_deg(g), x, y, period=360.0)
    if method != "spline":
        raise ValueError(f"unknown interpolation {method!r}")
    from scipy.interpolate import CubicSpline  # ≈ 0.45 s to import: only where used

    spline = CubicSpline(np.append(x, x[0] + 360.0), np.append(y, y[0]), bc_type="periodic")
    return spline(x[0] + wrap_deg(g - x[0]))


def smooth_circular(values: ArrayLike, half_width: int) -> FloatArray:
    """Centred circular moving average along the last axis.

    ``out[i] = mean(values[i − h … i + h])`` with indices taken modulo the
    length: a boxcar of ``2h + 1`` samples that preserves the row mean.

    Parameters
    ----------
    values
        ``(..., n)`` samples on a periodic grid (already in the domain to smooth in).
    half_width
        ``h``, samples on each side; ``0`` returns a copy.
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.shape[-1]
    h = int(half_width)
    if h <= 0:
        return v.copy()
    if 2 * h + 1 >= n:
        return np.broadcast_to(v.mean(axis=-1, keepdims=True), v.shape).copy()
    acc = np.zeros_like(v)
    for k in range(-h, h + 1):
        acc += np.roll(v, k, axis=-1)
    return acc / (2 * h + 1)


def smooth_rows(
    power_mw: ArrayLike,
    azimuth_step_deg: float,
    smooth_deg: float,
    domain: Literal["linear", "db"] = "linear",
) -> FloatArray:
    """Smooth each polar row of an ``(n_azimuth, n_polar)`` power grid along azimuth.

    The window holds the grid azimuths within ``±smooth_deg`` of the centre
    (``h = floor(smooth_deg / step)`` samples each side). ``domain="linear"``
    averages mW (the method); ``"db"`` averages dB (comparison only).
    Returns mW, same shape.
    """
    h = int(np.floor(smooth_deg / azimuth_step_deg + 1e-9))
    p = np.asarray(power_mw, dtype=np.float64)
    if domain == "linear":
        return smooth_circular(p.T, h).T
    if domain == "db":
        return dbm_to_mw(smooth_circular(mw_to_dbm(p).T, h).T)
    raise ValueError(f"unknown smoothing domain {domain!r}")


def _polar_grid(theta_deg: FloatArray, config: EnrolConfig) -> FloatArray:
    if config.polar_step_deg is not None:
        n = _grid_count(config.polar_step_deg, 180.0, "polar step", "polar_step_deg")
    else:
        gaps = np.diff(theta_deg)  # distinct, sorted
        j = int(np.argmin(gaps))
        gap = float(gaps[j])
        if too_fine(gap):
            lo, hi = float(theta_deg[j]), float(theta_deg[j + 1])
            raise PolarStepError(
                f"elevations {lo:g} and {hi:g} deg imply a polar step of {gap:g} deg, finer "
                f"than the {MIN_GRID_STEP_DEG:g} deg limit (give a polar step, or fix the "
                "elevation)",
                hi,
            )
        n = min(int(np.ceil(180.0 / gap - 1e-6)), MAX_POLAR_ANGLES - 1)
    return np.arange(n + 1, dtype=np.float64) * (180.0 / n)


def enrol(
    measurements: Measurements,
    config: EnrolConfig | None = None,
    *,
    name: str = "enrolled",
) -> Pattern:
    """Enrol a directivity pattern from positioner measurements.

    Parameters
    ----------
    measurements
        Packets with positioner angles and RSS (see :class:`Measurements`).
    config
        Grid, fill and smoothing settings (:class:`EnrolConfig` defaults).
    name
        Name of the resulting pattern.

    Returns
    -------
    Pattern
        ``(360/step, 1)`` slice at the measured elevation when a single
        elevation was measured, else ``(360/step, n_polar)`` full sphere;
        directivity in dBi (mean intensity 0 dBi; see module docstring).

    Raises
    ------
    InputError
        No measurements; :class:`PolarStepError` if no polar step is set and
        two measured elevations are closer than 0.1° (the grid limit);
        :class:`CoverageGapError` if the measurements leave a gap wider than
        :data:`MAX_FILL_GAP_DEG` (+ :data:`FILL_GAP_SLACK_DEG`) for the fill.
    """
    cfg = config or EnrolConfig()
    if len(measurements) == 0:
        raise InputError("no measurements to enrol")
    phi, theta = motor_to_pattern_deg(
        measurements.motor_azimuth_deg, measurements.motor_elevation_deg
    )
    d_phi, d_theta, d_mw = average_per_direction(phi, theta, measurements.rss_dbm)

    n_az = _grid_count(cfg.azimuth_step_deg, 360.0, "azimuth step", "azimuth_step_deg")
    step = 360.0 / n_az
    az_grid = np.arange(n_az, dtype=np.float64) * step
    thetas = np.unique(d_theta)
    po_grid = thetas[:1] if thetas.size == 1 else _polar_grid(thetas, cfg)
    n_po = po_grid.size

    # bins: nearest grid azimuth / polar row; one vote per direction (mean of mW)
    i_az = np.rint(d_phi / step).astype(np.int64) % n_az
    if n_po == 1:
        j_po = np.zeros_like(i_az)
    else:
        j_po = np.rint(d_theta / (180.0 / (n_po - 1))).astype(np.int64)
    _check_coverage(d_phi, d_theta, j_po, po_grid, measurements.motor_azimuth_deg)
    flat = i_az * n_po + j_po
    total = np.bincount(flat, weights=d_mw, minlength=n_az * n_po).reshape(n_az, n_po)
    count = np.bincount(flat, minlength=n_az * n_po).reshape(n_az, n_po)
    have = count > 0
    binned = np.where(have, total / np.maximum(count, 1), np.nan)

    floor_mw = 1e-3 * float(d_mw.min())
    grid = np.full((n_az, n_po), np.nan)
    rows = np.nonzero(have.any(axis=0))[0]
    for j in rows:
        k = have[:, j]
        if cfg.interpolation_domain == "db":
            vals = fill_periodic(az_grid[k], mw_to_dbm(binned[k, j]), az_grid, cfg.interpolation)
            grid[:, j] = dbm_to_mw(vals)
        else:
            vals = fill_periodic(az_grid[k], binned[k, j], az_grid, cfg.interpolation)
            grid[:, j] = np.maximum(vals, floor_mw)
        grid[k, j] = binned[k, j]  # measured bins are kept exactly

    if n_po > 1:
        if rows.size < n_po:
            # empty polar rows: linear in dB along θ per azimuth, held at the ends
            known_db = mw_to_dbm(grid[:, rows])
            for i in range(n_az):
                grid[i, :] = dbm_to_mw(np.interp(po_grid, po_grid[rows], known_db[i]))
        for pole in (0, n_po - 1):  # a pole is one direction: its row is one value
            grid[:, pole] = grid[:, pole].mean()

    smoothed = smooth_rows(grid, step, cfg.smooth_deg, cfg.smoothing_domain)
    raw = Pattern(name, az_grid, po_grid, mw_to_dbm(smoothed))
    # D = U / (P_rad / 4π), P_rad/4π = sinθ-weighted mean (sphere) or slice mean
    mean_u = mean_intensity(raw, smoothed)
    return Pattern(name, az_grid, po_grid, linear_to_db(smoothed / mean_u))


def enrol_csv(
    path: str | os.PathLike[str], config: EnrolConfig | None = None, *, name: str | None = None
) -> Pattern:
    """Read an enrolment CSV and enrol it (pattern named after the file stem by default).

    Elevations too close for the polar grid limit are reported at the first
    row of the larger one (file, line, column ``motor_elevation_deg``); a gap
    too wide to fill (:class:`CoverageGapError`) at the file and its column.
    """
    stem = os.path.splitext(os.path.basename(os.fspath(path)))[0]
    table = _read_measurement_table(path)
    try:
        return enrol(_measurements(table), config, name=name or stem)
    except PolarStepError as exc:
        el = np.round(np.asarray(table["motor_elevation_deg"], dtype=np.float64), _ANGLE_DECIMALS)
        rows = np.nonzero(el == exc.elevation_deg)[0]
        if rows.size == 0:
            raise
        raise table.error(int(rows[0]), "motor_elevation_deg", exc.reason) from None
    except CoverageGapError as exc:
        raise exc.at(path) from None


def simulate_positioner_measurements(
    pattern: Pattern,
    rng: np.random.Generator,
    *,
    azimuth_step_deg: float = 1.0,
    elevations_deg: ArrayLike = (90.0,),
    samples_per_direction: int = 10,
    noise_db: float = 1.0,
    tx_power_dbm: float = 0.0,
    path_loss_db: float = 40.0,
) -> Measurements:
    """Simulated positioner packets of a device with a known pattern.

    The positioner visits pattern azimuths ``0, step, …`` at each elevation;
    every packet has ``rss = tx_power + D(phi, theta) − path_loss + n`` dBm,
    ``n ~ N(0, noise_db²)`` (log-normal fading), and is reported at motor
    azimuth ``(360 − phi) mod 360``.

    Parameters
    ----------
    pattern
        The true pattern (looked up bilinearly).
    rng
        Source of the noise.
    azimuth_step_deg
        Positioner azimuth step, degrees (e.g. 45 for a sparse measurement).
    elevations_deg
        Positioner elevations (= pattern polar angles), degrees.
    samples_per_direction
        Packets per direction.
    noise_db
        Standard deviation of the RSS noise, dB.
    tx_power_dbm, path_loss_db
        Link budget constants, dBm and dB.

    Returns
    -------
    Measurements
        ``n_az · n_el · samples_per_direction`` packets.
    """
    n_az = grid_count(azimuth_step_deg, 360.0, "positioner azimuth step")
    theta = _elevations(elevations_deg)
    spd = samples_per_direction
    if isinstance(spd, (bool, np.bool_)) or not isinstance(spd, numbers.Integral) or spd < 1:
        raise InputError(f"samples_per_direction {spd!r:.40} is not a positive integer")
    if n_az * theta.size * int(spd) > MAX_SIMULATED_PACKETS:
        raise InputError(
            f"{n_az} azimuths × {theta.size} elevations × {spd} samples per direction "
            f"is more than {MAX_SIMULATED_PACKETS} packets"
        )
    noise_db = finite_number(noise_db, "noise_db")
    if noise_db < 0:
        raise InputError(f"noise_db {noise_db:g} dB is negative")
    tx_power_dbm = finite_number(tx_power_dbm, "tx_power_dbm")
    path_loss_db = finite_number(path_loss_db, "path_loss_db")
    phi = np.arange(n_az) * (360.0 / n_az)
    p, t = np.meshgrid(phi, theta, indexing="ij")
    p = np.repeat(p.ravel(), samples_per_direction)
    t = np.repeat(t.ravel(), samples_per_direction)
    d_dbi = pattern.lookup_dbi(p, t)
    rss = tx_power_dbm + d_dbi - path_loss_db + rng.normal(0.0, noise_db, p.size)
    motor_az, motor_el = pattern_to_motor_deg(p, t)
    return Measurements(motor_az, motor_el, rss)


def _elevations(elevations_deg: ArrayLike) -> FloatArray:
    """Positioner elevations (pattern polar angles): at least one, each in [0, 180]."""
    try:
        theta = np.asarray(elevations_deg, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(
            f"elevations_deg {elevations_deg!r:.40} is not an array of numbers"
        ) from None
    if theta.size == 0:
        raise InputError("elevations_deg is empty: give at least one elevation")
    ok = (theta >= 0.0) & (theta <= 180.0)  # False for NaN
    if not ok.all():
        r = int(np.argmin(ok))
        raise InputError(f"elevations_deg[{r}] = {theta[r]:g} deg is not in [0, 180]")
    return theta


__all__ = [
    "FILL_GAP_SLACK_DEG",
    "MAX_FILL_GAP_DEG",
    "MAX_SIMULATED_PACKETS",
    "MEASUREMENT_COLUMNS",
    "CoverageGapError",
    "EnrolConfig",
    "MeasurementError",
    "Measurements",
    "PolarStepError",
    "average_per_direction",
    "enrol",
    "enrol_csv",
    "fill_periodic",
    "largest_circular_gap",
    "motor_to_pattern_deg",
    "pattern_to_motor_deg",
    "read_measurements_csv",
    "simulate_positioner_measurements",
    "smooth_circular",
    "smooth_rows",
    "write_measurements_csv",
]
