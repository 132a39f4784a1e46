"""The radiation pattern value object and its CSV form.

A :class:`Pattern` is a directivity grid in dBi, ``(n_azimuth, n_polar)``,
travelling with its axis vectors:

* ``azimuth_deg`` — ``n_azimuth`` values at a constant step ``360 / n_azimuth``
  starting at ``azimuth_deg[0]`` in ``[0, step)``; lookups are periodic;
* ``polar_deg`` — either one value (a *slice*: the same row is used for every
  polar angle) or values at a constant step covering ``[0, 180]`` exactly.

Lookups (:meth:`Pattern.lookup_dbi`) interpolate bilinearly in dB (or take the
nearest grid point), periodic in azimuth and clamped in polar angle.
"""

from __future__ import annotations

import hashlib
import math
import numbers
import os
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from radiopose.errors import InputError, unreadable
from radiopose.tables import Column, read_table, write_table
from radiopose.units import FloatArray, db_to_linear, linear_to_db, wrap_deg

_STEP_TOL = 1e-6

MIN_GRID_STEP_DEG = 0.1
"""Finest azimuth or polar step of any pattern grid radiopose builds or reads, degrees.

At most ``MAX_AZIMUTHS`` × ``MAX_POLAR_ANGLES`` = 3600 × 1801 grid points
(about 50 MB as float64): enrolment and importer grids are checked against it
from the numbers *before* anything is allocated (``docs/patterns.md``).
"""

MAX_AZIMUTHS = 3600
"""Most grid azimuths (``360 / MIN_GRID_STEP_DEG``)."""

MAX_POLAR_ANGLES = 1801
"""Most grid polar angles (``180 / MIN_GRID_STEP_DEG + 1``)."""


def grid_steps(span_deg: float, step_deg: float) -> int | None:
    """Steps of ``step_deg`` in ``span_deg`` if it divides it (``None`` if not), unchecked size.

    Span first, like :func:`radiopose.site.grid_steps` (which also reports an
    inexact fit instead of ``None``).

    Computed from the numbers only (nothing is allocated), so a huge count is
    returned as is for the caller to reject against :data:`MIN_GRID_STEP_DEG`.
    """
    if not (np.isfinite(step_deg) and step_deg > 0):
        return None
    k = span_deg / step_deg
    if not np.isfinite(k) or k > 1e15:
        return None
    n = round(k)
    if n < 1 or abs(n * step_deg - span_deg) > 1e-6:
        return None
    return n


def too_fine(step_deg: ArrayLike) -> Any:
    """True where ``step_deg`` is finer than :data:`MIN_GRID_STEP_DEG` (beyond float noise)."""
    return np.asarray(step_deg) < MIN_GRID_STEP_DEG - 1e-9


def finite_number(value: object, what: str, column: str | None = None) -> float:
    """``value`` as a float if it is a finite real number (not a bool, not text).

    Raises
    ------
    InputError
        ``"{what} VALUE is not a number"`` or ``"… is not a finite number"``.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(f"{what} {value!r:.40} is not a number", column=column)
    x = float(value)
    if not math.isfinite(x):
        raise InputError(f"{what} {x:g} is not a finite number", column=column)
    return x


def grid_count(step_deg: object, span_deg: float, what: str, column: str | None = None) -> int:
    """Steps of ``step_deg`` in ``span_deg`` (360 azimuth, 180 polar), checked from the
    numbers before any grid is allocated.

    Raises
    ------
    InputError
        ``step_deg`` is not a finite number, is finer than :data:`MIN_GRID_STEP_DEG`
        (at most :data:`MAX_AZIMUTHS` azimuths, :data:`MAX_POLAR_ANGLES` polar
        angles) or does not divide ``span_deg`` (within 1e-6°).
    """
    step = finite_number(step_deg, what, column)
    if step > 0 and too_fine(step):
        most = MAX_AZIMUTHS if span_deg == 360.0 else MAX_POLAR_ANGLES - 1
        raise InputError(
            f"{what} {step:g} deg is finer than the {MIN_GRID_STEP_DEG:g} deg limit "
            f"(at most {most} steps over {span_deg:g} deg)",
            column=column,
        )
    n = grid_steps(span_deg, step)
    if n is None:
        raise InputError(f"{what} {step:g} deg does not divide {span_deg:g}", column=column)
    return n


def _first_bad(ok: np.ndarray) -> tuple[int, ...]:
    """Index of the first False of a boolean array (C order)."""
    return tuple(int(i) for i in np.unravel_index(int(np.argmin(ok)), ok.shape))


def _angles(value: ArrayLike, what: str) -> FloatArray:
    """Angles as float64 (no copy if already), InputError if not numbers or not finite.

    One :func:`numpy.isfinite` reduction on the (unbroadcast) array: the lookup's
    hot-path cost for good input.
    """
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"pattern lookup: {what} {value!r:.60} is not an array of numbers"
        ) from None
    if not np.isfinite(a).all():
        at = _first_bad(np.isfinite(a))
        where = f"[{', '.join(map(str, at))}]" if at else ""
        raise InputError(
            f"pattern lookup: {what}{where} is {a[at]:g}, not a finite angle in degrees"
        )
    return a


MAX_ABS_DIRECTIVITY_DBI = 200.0
"""Largest ``|directivity_dbi|`` of a pattern CSV, dBi (:func:`read_pattern_csv` rejects more)."""

PATTERN_COLUMNS = (
    Column("azimuth_deg", low=0.0, high=360.0, high_open=True),
    Column("polar_deg", low=0.0, high=180.0),
    Column("directivity_dbi", low=-MAX_ABS_DIRECTIVITY_DBI, high=MAX_ABS_DIRECTIVITY_DBI),
)


@dataclass(frozen=True, eq=False)
class Pattern:
    """A directivity pattern on a regular (azimuth, polar) grid.

    Parameters
    ----------
    name
        Pattern name (``patterns/<name>.csv`` in a site).
    azimuth_deg
        ``(n_azimuth,)`` pattern azimuths, constant step, ``n_azimuth·step = 360``.
    polar_deg
        ``(n_polar,)`` polar angles: one value (slice) or a constant step
        covering ``[0, 180]``.
    directivity_dbi
        ``(n_azimuth, n_polar)`` directivity in dBi.

    Raises
    ------
    InputError
        Axes or grid that are not numbers, more than :data:`MAX_AZIMUTHS` ×
        :data:`MAX_POLAR_ANGLES` points, a shape that does not match the axes,
        a non-finite directivity, irregular axes, or a slice's polar angle
        outside ``[0, 180]`` (one line naming the pattern).
    """

    name: str
    azimuth_deg: FloatArray
    polar_deg: FloatArray
    directivity_dbi: FloatArray
    _digest: str = field(default="", repr=False, compare=False)

    def __post_init__(self) -> None:
        what = f"pattern {self.name!r:.60}"
        arrays = []
        for label, value in (
            ("azimuth_deg", self.azimuth_deg),
            ("polar_deg", self.polar_deg),
            ("directivity_dbi", self.directivity_dbi),
        ):
            try:
                arrays.append(np.array(value, dtype=np.float64))
            except (TypeError, ValueError):
                raise InputError(f"{what}: {label} is not an array of numbers") from None
        az, po, d = arrays[0].reshape(-1), arrays[1].reshape(-1), arrays[2]
        if az.size > MAX_AZIMUTHS or po.size > MAX_POLAR_ANGLES:
            raise InputError(
                f"{what}: {az.size} azimuths × {po.size} polar angles, more than the "
                f"{MAX_AZIMUTHS} × {MAX_POLAR_ANGLES} of the {MIN_GRID_STEP_DEG:g} deg grid limit"
            )
        if d.ndim == 1 and po.size == 1:
            d = d.reshape(-1, 1)
        if az.size < 1 or po.size < 1 or d.shape != (az.size, po.size):
            raise InputError(
                f"{what}: directivity shape {d.shape} does not match axes ({az.size}, {po.size})"
            )
        if not np.all(np.isfinite(d)):
            i, j = _first_bad(np.isfinite(d))
            raise InputError(
                f"{what}: directivity has NaN/inf ({d[i, j]:g} dBi at azimuth "
                f"{az[i]:g}, polar {po[j]:g} deg)"
            )
        if np.abs(d).max() > MAX_ABS_DIRECTIVITY_DBI:
            i, j = _first_bad(np.abs(d) <= MAX_ABS_DIRECTIVITY_DBI)
            raise InputError(
                f"{what}: directivity {d[i, j]:g} dBi at azimuth {az[i]:g}, polar "
                f"{po[j]:g} deg is out of [-{MAX_ABS_DIRECTIVITY_DBI:g}, "
                f"{MAX_ABS_DIRECTIVITY_DBI:g}] dBi (the pattern CSV's range)"
            )
        step = 360.0 / az.size
        regular = np.allclose(np.diff(az), step, atol=_STEP_TOL)
        if not (0 <= az[0] < step - _STEP_TOL) or not regular:
            raise InputError(f"{what}: azimuths must be a constant step covering [0, 360)")
        if po.size == 1 and not 0.0 <= po[0] <= 180.0:
            raise InputError(f"{what}: slice polar angle {po[0]:g} deg is not in [0, 180]")
        if po.size > 1:
            if po[0] != 0.0 or abs(po[-1] - 180.0) > _STEP_TOL:
                raise InputError(f"{what}: polar angles must cover [0, 180]")
            if not np.allclose(np.diff(po), 180.0 / (po.size - 1), atol=_STEP_TOL):
                raise InputError(f"{what}: polar angles need a constant step")
        for arr in (az, po, d):
            arr.setflags(write=False)
        object.__setattr__(self, "azimuth_deg", az)
        object.__setattr__(self, "polar_deg", po)
        object.__setattr__(self, "directivity_dbi", d)
        h = hashlib.sha256()
        for arr in (az, po, d):
            h.update(np.ascontiguousarray(arr).tobytes())
        object.__setattr__(self, "_digest", h.hexdigest())

    # ------------------------------------------------------------------ properties
    @property
    def is_slice(self) -> bool:
        """True if the pattern has a single polar angle (used for every polar angle)."""
        return self.polar_deg.size == 1

    @property
    def azimuth_step_deg(self) -> float:
        """Azimuth grid step in degrees."""
        return 360.0 / self.azimuth_deg.size

    @property
    def polar_step_deg(self) -> float:
        """Polar grid step in degrees (``0`` for a slice)."""
        return 0.0 if self.is_slice else 180.0 / (self.polar_deg.size - 1)

    @property
    def digest(self) -> str:
        """SHA-256 of the grid (content key for caches)."""
        return self._digest

    @property
    def range_dbi(self) -> tuple[float, float]:
        """(min, max) directivity in dBi."""
        return float(self.directivity_dbi.min()), float(self.directivity_dbi.max())

    def slice_dbi(self, polar_deg: float = 90.0) -> FloatArray:
        """Directivity ``(n_azimuth,)`` at one polar angle (interpolated), dBi."""
        theta = np.full(self.azimuth_deg.shape, finite_number(polar_deg, "slice polar angle"))
        return self.lookup_dbi(self.azimuth_deg, theta)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pattern):
            return NotImplemented
        return self.name == other.name and self._digest == other._digest

    def __hash__(self) -> int:
        return hash((self.name, self._digest))

    # ------------------------------------------------------------------ lookups
    def lookup_dbi(
        self,
        azimuth_deg: ArrayLike,
        polar_deg: ArrayLike | None = None,
        method: Literal["bilinear", "nearest"] = "bilinear",
    ) -> FloatArray:
        """Directivity in dBi at pattern angles (arrays broadcast together).

        Parameters
        ----------
        azimuth_deg
            Pattern azimuths in degrees, any real value (periodic).
        polar_deg
            Polar angles in degrees, clamped to ``[0, 180]``; ignored for a
            slice (may be ``None`` then).
        method
            ``"bilinear"`` (linear in each axis, in dB) or ``"nearest"``.

        Raises
        ------
        InputError
            An angle that is NaN or infinite (naming the array and index), arrays
            that do not broadcast, or an unknown method. Finite angles cost one
            :func:`numpy.isfinite` reduction per array.
        """
        if method not in ("bilinear", "nearest"):
            raise InputError(f"unknown lookup method {method!r:.40} (bilinear|nearest)")
        phi = _angles(azimuth_deg, "azimuth")
        theta = phi * 0.0 + 90.0 if polar_deg is None else _angles(polar_deg, "polar angle")
        try:
            phi, theta = np.broadcast_arrays(phi, theta)
        except ValueError:
            raise InputError(
                f"pattern lookup: azimuth shape {phi.shape} and polar shape {theta.shape} "
                "do not broadcast"
            ) from None
        n_az = self.azimuth_deg.size
        u = wrap_deg(phi - self.azimuth_deg[0]) / self.azimuth_step_deg
        if self.is_slice:
            w = np.zeros_like(u)
        else:
            w = np.clip(theta, 0.0, 180.0) / self.polar_step_deg
        d = self.directivity_dbi
        if method == "nearest":
            i = np.rint(u).astype(np.int64) % n_az
            j = np.rint(w).astype(np.int64)
            return d[i, j]
        i0 = np.floor(u).astype(np.int64)
        fu = u - i0
        i0 %= n_az
        i1 = (i0 + 1) % n_az
        j0 = np.minimum(np.floor(w).astype(np.int64), d.shape[1] - 1)
        fw = w - j0
        j1 = np.minimum(j0 + 1, d.shape[1] - 1)
        top = d[i0, j0] * (1 - fu) + d[i1, j0] * fu
        bot = d[i0, j1] * (1 - fu) + d[i1, j1] * fu
        return top * (1 - fw) + bot * fw

    # ------------------------------------------------------------------ derived
    def resampled(self, azimuth_step_deg: float) -> Pattern:
        """The pattern resampled (bilinearly) onto azimuths ``0, step, …``.

        Raises
        ------
        InputError
            ``azimuth_step_deg`` is not a number, finer than
            :data:`MIN_GRID_STEP_DEG` or does not divide 360.
        """
        n = grid_count(azimuth_step_deg, 360.0, "pattern azimuth step")
        az = np.arange(n, dtype=np.float64) * (360.0 / n)
        phi, theta = np.meshgrid(az, self.polar_deg, indexing="ij")
        return Pattern(self.name, az, self.polar_deg, self.lookup_dbi(phi, theta))

    def renamed(self, name: str) -> Pattern:
        """The same grid under another name."""
        return Pattern(name, self.azimuth_deg, self.polar_deg, self.directivity_dbi)

    def normalised(self) -> Pattern:
        """The pattern rescaled to a directivity (mean radiation intensity = 0 dBi).

        Full sphere: divides by ``∫ U sinθ dθ dφ / 4π`` (trapezoid in θ);
        slice: by the mean of the linear slice.
        """
        lin = db_to_linear(self.directivity_dbi)
        return Pattern(
            self.name,
            self.azimuth_deg,
            self.polar_deg,
            linear_to_db(lin / mean_intensity(self, lin)),
        )


def mean_intensity(pattern: Pattern, linear: FloatArray | None = None) -> float:
    """Mean of a linear intensity grid over the sphere (``sinθ``-weighted) or the slice.

    ``P_rad / 4π`` for a full-sphere grid; the arithmetic mean for a slice.
    """
    lin = db_to_linear(pattern.directivity_dbi) if linear is None else linear
    if pattern.is_slice:
        return float(lin.mean())
    theta = np.deg2rad(pattern.polar_deg)
    ring = lin.mean(axis=0)  # mean over azimuth for each polar angle
    integral = np.trapezoid(ring * np.sin(theta), theta)  # ∫ ring sinθ dθ
    return float(integral / 2.0)  # (2π ∫ ring sinθ dθ) / 4π


# ---------------------------------------------------------------------- sample grids
GRID_TOL_DEG = 1e-5
"""A sampled angle this close to a grid angle is that grid angle (printing noise)."""

_MAX_STEP_CANDIDATES = 8
_MISSING_PENALTY = 0.2


class GridError(InputError, ValueError):
    """Samples that do not form a complete regular grid (raised by :func:`pattern_from_samples`).

    ``row`` is the 0-based index of the sample the problem is reported at,
    ``axis`` (``"azimuth"`` or ``"polar"``) the angle that breaks the grid, and
    ``other_row`` the earlier sample a duplicate repeats. Loaders turn it into an
    :class:`~radiopose.errors.InputError` with their own file line and column;
    called from Python it is one itself (``column`` ``"AXIS_deg[ROW]"``), and
    still a :class:`ValueError` as it always was.
    """

    def __init__(self, row: int, axis: str, message: str, other_row: int | None = None) -> None:
        super().__init__(message, column=f"{axis}_deg[{row}]")
        self.row = row
        self.axis = axis
        self.message = message
        self.other_row = other_row


@dataclass(frozen=True)
class _AxisFit:
    step: float
    first: float  # the first grid angle
    n: int  # grid angles
    index: np.ndarray  # grid index of each fitted value, -1 if off the grid


def _step_candidates(u: FloatArray, span: float, periodic: bool) -> list[float]:
    gaps = np.diff(u)
    if periodic:
        gaps = np.append(gaps, span - u[-1] + u[0])
    gaps = gaps[gaps > GRID_TOL_DEG]
    keys, counts = np.unique(np.round(gaps, 4), return_counts=True)
    ordered = keys[np.argsort(-counts, kind="stable")][:_MAX_STEP_CANDIDATES]
    fallback = u.size if periodic else max(u.size - 1, 1)
    steps: list[float] = []
    for n in [round(span / max(g, 1e-4)) for g in ordered] + [fallback]:
        if n >= 1 and span / n not in steps:
            steps.append(span / n)
    return steps


def _fit_step(u: FloatArray, step: float, span: float, periodic: bool) -> _AxisFit:
    n = round(span / step) + (0 if periodic else 1)
    if periodic:
        residue = np.mod(u, step)
        key = np.round(residue, 4)
        key = np.where(key >= round(step, 4), 0.0, key)
        keys, counts = np.unique(key, return_counts=True)
        first = float(residue[np.nonzero(key == keys[np.argmax(counts)])[0][0]])
        if first > step - GRID_TOL_DEG:  # a hair below a multiple of the step: from ~0
            first -= step
    else:
        first = 0.0
    k = np.round((u - first) / step)
    on = np.abs(u - first - k * step) <= GRID_TOL_DEG
    if periodic:
        index = np.where(on, np.mod(k, n), -1)
    else:
        index = np.where(on & (k >= 0) & (k < n), k, -1)
    return _AxisFit(step, first, n, index.astype(np.int64))


def _fit_axis(u: FloatArray, span: float, periodic: bool) -> _AxisFit:
    """The constant-step grid that best explains the sorted distinct angles ``u``.

    Candidate steps are the most common spacings (and ``span / count``), each
    rounded to divide ``span``; a candidate scores one point per angle on its
    grid and loses :data:`_MISSING_PENALTY` per grid angle nobody sampled (ties:
    the coarser grid), so a deleted row reads as a missing point and a
    mistyped value as an angle off the grid.
    """
    best: tuple[float, float] | None = None
    fit: _AxisFit | None = None
    for step in _step_candidates(u, span, periodic):
        cand = _fit_step(u, step, span, periodic)
        on = np.unique(cand.index[cand.index >= 0]).size
        score = (on - _MISSING_PENALTY * (cand.n - on), step)
        if best is None or score > best:
            best, fit = score, cand
    assert fit is not None
    return fit


def _axis_text(fit: _AxisFit, axis: str) -> str:
    s = "" if fit.n == 1 else "s"
    if axis == "azimuth":
        return f"{fit.n} azimuth{s} every {fit.step:g} deg from {fit.first:g}"
    return f"{fit.n} polar angle{s} every {fit.step:g} deg over [0, 180]"


def pattern_from_samples(
    name: str, azimuth_deg: FloatArray, polar_deg: FloatArray, directivity_dbi: FloatArray
) -> Pattern:
    """A :class:`Pattern` from one sample per grid point, in any order.

    Azimuths must lie on a constant-step grid covering ``[0, 360)`` and polar
    angles be one value (a slice) or a constant-step grid covering
    ``[0, 180]``, each within :data:`GRID_TOL_DEG`; every grid point must be
    present exactly once.

    Raises
    ------
    GridError
        At the first duplicate (the later sample), the first sample off the grid
        (in sample order), or a missing grid point (reported at the sample
        after which it belongs, in the samples' own azimuth- or polar-major
        order), saying which angle and which grid.
    InputError
        No samples, arrays of different lengths, or a value that is not a
        finite number (naming the array and index).
    """
    az, po, values = _sample_arrays(azimuth_deg, polar_deg, directivity_dbi)
    # exact repeats first: the clearest message
    repeat = first_repeat(az, po)
    if repeat is not None:
        r, first = repeat
        raise GridError(
            r,
            "azimuth",
            f"duplicate grid point azimuth {float(az[r]):g}, polar {float(po[r]):g} deg",
            first,
        )
    az_u, az_inv = np.unique(az, return_inverse=True)
    po_u, po_inv = np.unique(po, return_inverse=True)
    az_inv, po_inv = az_inv.reshape(-1), po_inv.reshape(-1)
    slice_ = po_u.size == 1
    if not slice_:
        _check_mixed_slice(po, po_u, po_inv)
    a_fit = _fit_axis(az_u, 360.0, periodic=True)
    _check_fit_size(a_fit, az_u, az_inv, "azimuth")
    p_fit = (
        _AxisFit(0.0, float(po_u[0]), 1, np.zeros(1, np.int64))
        if slice_
        else _fit_axis(po_u, 180.0, periodic=False)
    )
    if not slice_:
        _check_fit_size(p_fit, po_u, po_inv, "polar")
    ai = a_fit.index[az_inv]
    pi = p_fit.index[po_inv]
    for idx, vals, fit, axis in ((ai, az, a_fit, "azimuth"), (pi, po, p_fit, "polar")):
        off = np.nonzero(idx < 0)[0]
        if off.size:
            r = int(off[0])
            raise GridError(
                r,
                axis,
                f"{axis} {vals[r]:g} deg is not on a constant-step grid covering "
                f"{'[0, 360)' if axis == 'azimuth' else '[0, 180]'} "
                f"(closest fit: {_axis_text(fit, axis)})",
            )
    n_a, n_p = a_fit.n, p_fit.n
    flat = ai * n_p + pi
    repeat = first_repeat(flat)
    if repeat is not None:
        r, first = repeat
        raise GridError(
            r,
            "azimuth",
            f"duplicate grid point azimuth {az[r]:g}, polar {po[r]:g} deg: the same "
            f"as azimuth {az[first]:g}, polar {po[first]:g} within "
            f"{GRID_TOL_DEG:g} deg",
            first,
        )
    grid_a = a_fit.first + np.arange(n_a, dtype=np.float64) * a_fit.step
    grid_p = p_fit.first + np.arange(n_p, dtype=np.float64) * p_fit.step
    if flat.size != n_a * n_p:
        _raise_missing(flat, ai, pi, n_a, n_p, grid_a, grid_p, a_fit, p_fit, slice_)
    flat_grid = np.empty(n_a * n_p)
    flat_grid[flat] = values
    grid = flat_grid.reshape(n_a, n_p)
    axis_a = np.empty(n_a)
    axis_a[ai] = az
    axis_p = np.empty(n_p)
    axis_p[pi] = po
    try:  # the file's own angles where they pass Pattern's checks
        return Pattern(name, axis_a, axis_p, grid)
    except InputError:  # within GRID_TOL_DEG but not Pattern's tolerance: exact angles
        grid_a = max(a_fit.first, 0.0) + np.arange(n_a, dtype=np.float64) * a_fit.step
        return Pattern(name, grid_a, grid_p if not slice_ else axis_p, grid)


def first_repeat(*keys: np.ndarray) -> tuple[int, int] | None:
    """``(row, first_row)`` of the earliest sample whose keys all equal (``==``) those of
    an earlier sample, and that earlier sample's first row; ``None`` if every sample
    is distinct.

    The answer of walking the samples with a ``dict`` of seen keys, from one stable
    sort (keys, then row) instead of a Python object per sample.
    """
    rows = np.arange(keys[0].size)
    order = np.lexsort((rows, *keys[::-1]))  # first key primary, ties by row
    same = np.ones(order.size, bool)  # same keys as the sample sorted before it
    same[0] = False
    for k in keys:
        ks = k[order]
        same[1:] &= ks[1:] == ks[:-1]
    if not same.any():
        return None
    # sorted position of each group's first sample (its lowest row)
    start = np.maximum.accumulate(np.where(same, 0, np.arange(order.size)))
    repeats = np.nonzero(same)[0]
    at = repeats[np.argmin(order[repeats])]
    return int(order[at]), int(order[start[at]])


def _sample_arrays(
    azimuth_deg: ArrayLike, polar_deg: ArrayLike, directivity_dbi: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The three sample arrays of :func:`pattern_from_samples`, checked: 1-D, equal
    non-zero lengths, finite values."""
    names = ("azimuth_deg", "polar_deg", "directivity_dbi")
    arrays = []
    for label, value in zip(names, (azimuth_deg, polar_deg, directivity_dbi), strict=True):
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"pattern samples: {label} is not an array of numbers") from None
        if a.ndim != 1:
            raise InputError(f"pattern samples: {label} has shape {a.shape}, expected (n,)")
        arrays.append(a)
    sizes = [a.size for a in arrays]
    if len(set(sizes)) != 1:
        raise InputError(
            "pattern samples: azimuth_deg, polar_deg and directivity_dbi have "
            f"{', '.join(map(str, sizes))} values, expected one each per sample"
        )
    if sizes[0] == 0:
        raise InputError("pattern samples: no samples")
    for label, a in zip(names, arrays, strict=True):
        ok = np.isfinite(a)
        if not ok.all():
            r = int(np.argmin(ok))
            raise InputError(f"pattern samples: {label}[{r}] is {a[r]:g}, not a finite number")
    return arrays[0], arrays[1], arrays[2]


def _check_mixed_slice(po: FloatArray, po_u: FloatArray, po_inv: np.ndarray) -> None:
    """More than half the samples at one polar angle: a slice with stray polar angles.

    A complete sphere has the same number of samples at every polar angle (at
    most half of them at one, with two rows), so this never rejects a valid
    grid; it reports the first stray sample rather than a grid fit around it.
    """
    counts = np.bincount(po_inv, minlength=po_u.size)
    k = int(np.argmax(counts))
    if 2 * int(counts[k]) <= po.size:
        return
    r = int(np.nonzero(po_inv != k)[0][0])
    raise GridError(
        r,
        "polar",
        f"polar {po[r]:g} deg in a slice at polar {po_u[k]:g} deg ({int(counts[k])} of "
        f"{po.size} rows): a slice has one polar angle, a sphere covers [0, 180] at a "
        "constant step",
    )


def _check_fit_size(fit: _AxisFit, u: FloatArray, inv: np.ndarray, axis: str) -> None:
    """Reject a fitted grid finer than :data:`MIN_GRID_STEP_DEG` before it is allocated.

    Reported at the first sample of the larger angle of the lowest too-close pair.
    """
    if not too_fine(fit.step):
        return
    gaps = np.diff(u)
    gaps = np.where(gaps > GRID_TOL_DEG, gaps, np.inf)
    idx, pair = 0, f"{u[0]:g} deg"
    gap = fit.step
    if gaps.size and np.isfinite(gaps.min()):
        fine = np.nonzero(too_fine(gaps))[0]
        j = int(fine[0]) if fine.size else int(np.argmin(gaps))
        idx, gap, pair = j + 1, float(gaps[j]), f"{u[j]:g} and {u[j + 1]:g} deg"
    r = int(np.nonzero(inv == idx)[0][0])
    plural = "azimuths" if axis == "azimuth" else "polar angles"
    raise GridError(
        r,
        axis,
        f"{plural} {pair} imply a grid step of {gap:g} deg ({fit.n} {plural}), "
        f"finer than the {MIN_GRID_STEP_DEG:g} deg limit",
    )


def _raise_missing(
    flat: np.ndarray,
    ai: np.ndarray,
    pi: np.ndarray,
    n_a: int,
    n_p: int,
    grid_a: FloatArray,
    grid_p: FloatArray,
    a_fit: _AxisFit,
    p_fit: _AxisFit,
    slice_: bool,
) -> None:
    polar_major = n_p > 1 and flat.size > 1
    key_p = pi * n_a + ai
    polar_major = polar_major and bool(np.all(np.diff(key_p) > 0))
    polar_major = polar_major and not bool(np.all(np.diff(flat) > 0))
    keys = key_p if polar_major else flat
    have = np.zeros(n_a * n_p, bool)
    have[keys] = True
    missing = int(np.nonzero(~have)[0][0])
    if polar_major:
        m_a, m_p = missing % n_a, missing // n_a
    else:
        m_a, m_p = missing // n_p, missing % n_p
    before = np.nonzero(keys < missing)[0]
    if before.size:
        r, where = int(before[np.argmax(keys[before])]), "after"
    else:
        r, where = int(np.argmin(keys)), "before"
    # the angle that breaks the sequence: within a present azimuth (azimuth-major)
    # the polar angle is missing, else the whole azimuth is
    if slice_:
        axis = "azimuth"
    elif polar_major:
        axis = "azimuth" if np.any(pi == m_p) else "polar"
    else:
        axis = "polar" if np.any(ai == m_a) else "azimuth"
    polar = "slice" if slice_ else _axis_text(p_fit, "polar")
    raise GridError(
        r,
        axis,
        f"missing grid point azimuth {grid_a[m_a]:g}, polar {grid_p[m_p]:g} deg, "
        f"expected {where} this row (grid: {_axis_text(a_fit, 'azimuth')} × {polar}; "
        "every grid point must be present once)",
    )


# ---------------------------------------------------------------------- CSV io
def read_pattern_csv(path: str | os.PathLike[str], name: str | None = None) -> Pattern:
    """Read a contract pattern CSV (``azimuth_deg, polar_deg, directivity_dbi``).

    Raises :class:`~radiopose.errors.InputError` naming file, line and column
    for malformed values, duplicate or missing grid points, or an irregular grid
    (see :func:`pattern_from_samples` for where each is reported).
    """
    table = read_table(path, PATTERN_COLUMNS)
    if len(table) == 0:
        raise InputError("no pattern samples", path=path, line=2)
    stem = os.path.splitext(os.path.basename(os.fspath(path)))[0]
    try:
        return pattern_from_samples(
            name or stem, table["azimuth_deg"], table["polar_deg"], table["directivity_dbi"]
        )
    except GridError as exc:
        msg = exc.message
        if exc.other_row is not None:
            msg += f" (first at line {int(table.lines[exc.other_row])})"
        raise table.error(exc.row, f"{exc.axis}_deg", msg) from None


def unwritable(path: str | os.PathLike[str], exc: OSError) -> InputError:
    """The one-line :class:`InputError` for a CSV file that cannot be written.

    A directory at ``path`` is reported as :func:`radiopose.errors.unreadable`
    does (``"is a directory, expected a CSV file"``); anything else by its
    reason (``"cannot create: a parent is not a directory"``, ``"cannot write
    (No space left on device)"``).
    """
    if isinstance(exc, IsADirectoryError):
        return unreadable(path, exc, "a CSV file")
    reason = exc.strerror or str(exc)
    if not reason.startswith("cannot"):
        reason = f"cannot write: {reason}"
    return InputError(reason, path=path)


def write_pattern_csv(pattern: Pattern, path: str | os.PathLike[str]) -> None:
    """Write a pattern as a contract CSV (atomically), azimuth-major order.

    Raises
    ------
    InputError
        ``path`` is a directory or cannot be written (one line naming it).
    """
    phi, theta = np.meshgrid(pattern.azimuth_deg, pattern.polar_deg, indexing="ij")
    try:
        write_table(
            path,
            {
                "azimuth_deg": phi.ravel(),
                "polar_deg": theta.ravel(),
                "directivity_dbi": pattern.directivity_dbi.ravel(),
            },
        )
    except OSError as exc:
        raise unwritable(path, exc) from None
