"""The most likely orientation path along a fixed position track (offline, 3-D).

Beyond the paper; docs/pose3d.md, "An orientation path, 2026-11-28". The batch
refinement (:mod:`radiopose.filtering.refine3d`) is a local solve: a track that
is right in position but turned into a wrong mode over part of its length
(pitch slid toward the gimbal or flat, azimuth and roll compensating) stays
there, because every start the filters give it is wrong over the same part.
This module searches the orientation **globally** for a given position track:
a Viterbi path over a fine grid of (azimuth, pitch, roll) per time window,

* **windows** of :data:`WINDOW_S` seconds from the first packet; in each, every
  heard receiver's mean RSS ``ȳ_r`` over its ``n_r`` readings, and the track's
  mean position ``p``;
* **data cost** of an orientation ``o`` in a window:
  ``½ Σ_r w_r (ȳ_r − E_r(p, o) − b)²`` with ``w_r = n_r / (σ² + σ_g² n_r)``,
  ``E`` the 3-D filter's own expected RSS (height model, full-sphere pattern;
  :meth:`~radiopose.filtering.particle3d.FilterModel3d.expected`), ``b`` the
  device offset, ``σ`` the reading noise and ``σ_g`` = :data:`GRID_SD_DB` the
  grid's own error (the window's mean position and the grid's steps);
* **grid**: azimuth every :data:`STEP_DEG` degrees around the circle, pitch and
  roll every :data:`STEP_DEG` over the filter's tilt support (pitch kept
  1° off ±90°; roll around the circle when its arc is the whole circle);
* **transitions** between consecutive windows: a Gaussian step per axis
  (:data:`STEP_SD_DEG`: azimuth, pitch, roll), at most :data:`MAX_STEP_CELLS`
  cells — separable, so each window costs three one-axis min-plus passes.

The path (the grid orientations of the windows, placed at each window's mean
packet time and interpolated linearly to the packets, angles unwrapped) is a
**start** for the refinement, not an estimate:
:func:`~radiopose.filtering.refine3d.refine_smoothed` refines it from the kept
track's positions and keeps it only when its objective is lower by
the mode choice's switch margin. Cost: ≈ 1.3 CPU s for a 4 s file at 6
receivers (40 windows × 26,000 orientations; the expected RSS is the compiled
kernel's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from radiopose.errors import InputError
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.refine3d import checked_track
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import FilterModel3d

WINDOW_S = 0.1
"""Window length, seconds (the coarse HMM's, :mod:`radiopose.filtering.coarse3d`)."""
STEP_DEG = 5.0
"""Grid step of azimuth, pitch and roll, degrees."""
GRID_SD_DB = 0.7
"""The grid's own error in a window's expected RSS, dB (``σ_g``)."""
STEP_SD_DEG = (8.0, 5.0, 5.0)
"""Standard deviation of a window-to-window step: azimuth, pitch, roll, degrees
(a hand-held phone: heading wobble and turns up to ≈ 80 °/s, tilt rates up to
≈ 50 °/s; docs/pose3d.md, "Refinement prior")."""
MAX_STEP_CELLS = 3
"""Largest window-to-window step per axis, grid cells."""
_PITCH_MARGIN_DEG = 1.0


def orientation_path(
    model: FilterModel3d,
    times_s: Sequence[float] | FloatArray,
    heard: Sequence[HeardRss],
    position_m: FloatArray,
    offset_db: float,
    sigma_db: float,
) -> FloatArray:
    """The most likely orientation per packet along ``position_m`` (see the module docstring).

    Parameters
    ----------
    model
        The 3-D filter's device model (its ``expected``, ``tilt_rad``, ``z_box_m``).
    times_s
        ``(n,)`` packet times, seconds, non-decreasing.
    heard
        ``n`` packets' readings (site receiver indices, RSS dBm).
    position_m
        ``(n, 3)`` the track's positions, metres (held fixed).
    offset_db
        The device's power offset, dB.
    sigma_db
        Reading noise σ, dB.

    Returns
    -------
    ``(n, 3)`` azimuth [0, 360), pitch, roll (−180, 180] in degrees.

    Raises
    ------
    InputError
        Arrays of different lengths, an empty track, times going backwards,
        non-finite positions, offset or σ.
    """
    t, pos, _ = checked_track("orientation_path", times_s, position_m, None, heard)
    if not (math.isfinite(offset_db) and math.isfinite(sigma_db) and sigma_db > 0):
        raise InputError("orientation_path: the offset must be finite and σ positive")

    p_lo, p_hi, r_c, r_w = (math.degrees(float(v)) for v in model.tilt_rad)
    p_lo = max(p_lo, -90.0 + _PITCH_MARGIN_DEG)
    p_hi = min(p_hi, 90.0 - _PITCH_MARGIN_DEG)
    roll_circle = r_w >= 180.0
    azimuths = np.arange(0.0, 360.0, STEP_DEG)
    pitches = _axis(p_lo, p_hi)
    rolls = np.arange(-180.0, 180.0, STEP_DEG) if roll_circle else _axis(r_c - r_w, r_c + r_w)
    grid_az, grid_pitch, grid_roll = np.meshgrid(azimuths, pitches, rolls, indexing="ij")
    shape = grid_az.shape
    S = np.zeros((grid_az.size, K.N_COLUMNS))
    S[:, K.AZIMUTH_RAD] = np.deg2rad(grid_az.ravel())
    S[:, K.PITCH_RAD] = np.deg2rad(grid_pitch.ravel())
    S[:, K.ROLL_RAD] = np.deg2rad(grid_roll.ravel())
    z_lo, z_hi = (float(v) for v in model.z_box_m)

    window = np.floor((t - t[0]) / WINDOW_S + 1e-9).astype(np.int64)
    n_win = int(window[-1]) + 1
    steps = [_step_costs(sd) for sd in STEP_SD_DEG]
    wraps = (True, False, roll_circle)
    value: FloatArray | None = None
    back: list[tuple[np.ndarray, ...] | None] = []
    bounds = np.searchsorted(window, np.arange(n_win + 1))
    for w in range(n_win):
        data = _window_cost(model, S, heard, pos, bounds[w], bounds[w + 1], offset_db,
                            sigma_db, z_lo, z_hi, shape)  # fmt: skip
        if value is None:
            value, arg = data, None
        else:
            shifts = []
            for axis in range(3):
                value, a = _min_plus(value, axis, steps[axis], wraps[axis])
                shifts.append(a)
            value = value + data
            arg = tuple(shifts)
        back.append(arg)
    assert value is not None
    cell = np.array(np.unravel_index(int(np.argmin(value)), shape))
    path = np.empty((n_win, 3), dtype=np.int64)
    path[-1] = cell
    for w in range(n_win - 1, 0, -1):
        came = back[w]
        assert came is not None
        for axis in (2, 1, 0):  # undo the passes in reverse order
            cell[axis] -= came[axis][tuple(cell)]
            if wraps[axis]:
                cell[axis] %= shape[axis]
        path[w - 1] = cell
    # each window's orientation at its packets' mean time (its centre when empty)
    counts = np.bincount(window, minlength=n_win)
    centres = t[0] + (np.arange(n_win) + 0.5) * WINDOW_S
    filled = counts > 0
    centres[filled] = np.bincount(window, weights=t, minlength=n_win)[filled] / counts[filled]
    az = np.rad2deg(np.unwrap(np.deg2rad(azimuths[path[:, 0]])))
    pitch = pitches[path[:, 1]]
    roll = rolls[path[:, 2]]
    if roll_circle:
        roll = np.rad2deg(np.unwrap(np.deg2rad(roll)))
    out = np.column_stack([np.interp(t, centres, az), np.interp(t, centres, pitch),
                           np.interp(t, centres, roll)])  # fmt: skip
    out[:, 0] %= 360.0
    out[:, 2] = 180.0 - (180.0 - out[:, 2]) % 360.0  # (−180, 180]
    return out


def _axis(lo: float, hi: float) -> FloatArray:
    """Grid values from ``lo`` to ``hi`` degrees every :data:`STEP_DEG` (one value
    when the support is a point); ``hi`` included when it falls on the grid."""
    if hi <= lo:
        return np.array([lo])
    count = math.floor((hi - lo) / STEP_DEG + 1e-9) + 1
    return np.asarray(lo + STEP_DEG * np.arange(count), dtype=np.float64)


def _step_costs(sd_deg: float) -> FloatArray:
    """``½ (k · step / sd)²`` for shifts ``k = −MAX_STEP_CELLS … MAX_STEP_CELLS``."""
    k = np.arange(-MAX_STEP_CELLS, MAX_STEP_CELLS + 1)
    return np.asarray(0.5 * (k * STEP_DEG / sd_deg) ** 2, dtype=np.float64)


def _window_cost(
    model: FilterModel3d,
    S: FloatArray,
    heard: Sequence[HeardRss],
    pos: FloatArray,
    i0: int,
    i1: int,
    offset_db: float,
    sigma_db: float,
    z_lo: float,
    z_hi: float,
    shape: tuple[int, ...],
) -> FloatArray:
    """The data cost of every grid orientation in the window of packets ``i0 … i1 − 1``
    (zero for an empty window or one without readings)."""
    if i1 <= i0:
        return np.zeros(shape)
    packets = range(i0, i1)
    rx = np.concatenate([np.asarray(heard[i].receiver_index, dtype=np.int64) for i in packets])
    y = np.concatenate([np.asarray(heard[i].rss_dbm, dtype=float) for i in packets])
    if rx.size == 0:
        return np.zeros(shape)
    rxs, inv, counts = np.unique(rx, return_inverse=True, return_counts=True)
    mean = np.bincount(inv, weights=y) / counts
    weight = counts / (sigma_db**2 + GRID_SD_DB**2 * counts)
    p = pos[i0:i1].mean(axis=0)
    S[:, K.X_M], S[:, K.Y_M] = p[0], p[1]
    S[:, K.Z_M] = min(max(p[2], z_lo), z_hi)
    resid = mean - model.expected(S, rxs) - offset_db
    return np.asarray(0.5 * (resid * resid) @ weight, dtype=np.float64).reshape(shape)


def _min_plus(
    value: FloatArray, axis: int, step_cost: FloatArray, wrap: bool
) -> tuple[FloatArray, np.ndarray]:
    """``min_k value[i − k] + step_cost[k]`` along ``axis`` (cyclic when ``wrap``) and
    the minimising shift ``k`` per cell (int8)."""
    best = np.full(value.shape, np.inf)
    arg = np.zeros(value.shape, dtype=np.int8)
    size = value.shape[axis]
    for j, k in enumerate(range(-MAX_STEP_CELLS, MAX_STEP_CELLS + 1)):
        if wrap:
            shifted = np.roll(value, k, axis=axis)
        else:
            if abs(k) >= size:
                continue
            shifted = np.full(value.shape, np.inf)
            dst = [slice(None)] * value.ndim
            src = [slice(None)] * value.ndim
            dst[axis] = slice(max(k, 0), size + min(k, 0))
            src[axis] = slice(max(-k, 0), size - max(k, 0))
            shifted[tuple(dst)] = value[tuple(src)]
        cand = shifted + step_cost[j]
        better = cand < best
        best[better] = cand[better]
        arg[better] = k
    return best, arg
