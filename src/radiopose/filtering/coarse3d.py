"""Offline: the most likely path of a whole-file coarse HMM in 3-D, as one more
refinement start (docs/pose3d.md, "A coarse-path start, 2026-11-28").

Beyond the paper (issue 18). The 3-D batch refinement
(:func:`radiopose.filtering.refine3d.refine_smoothed`) keeps the refined track
of the lowest objective among its starts, and every start so far is a particle
filter's track (forward, reversed, restarted): when none of them enters the
truth's mode the refinement cannot reach it. The 2-D filter's search failures
were fixed by a start that does not depend on any particle filter: the Viterbi
path of a coarse HMM over the whole file (docs/filter.md, "Coarse-grid HMM").
This is its 3-D analogue:

* the grid is the 3-D filter's own acquisition grid
  (:class:`~radiopose.filtering.particle3d.CoarseGrid`: positions × heights,
  azimuths × pitches × rolls; its expected RSS is already built);
* the packets are read in windows of ``window_s``: per window and receiver
  the median RSS of its ``n`` readings, scored at every grid pose as
  ``Σ w (y − E − b)² / 2`` with ``w = n / ((π/2) σ² + σ_g² n)`` (the median's
  variance plus the grid's coarseness ``σ_g``, as in 2-D), at a device
  offset ``b``; windows with fewer than three receivers are not read;
* height, pitch and roll are minimised per (x, y, azimuth) cell (a compiled
  kernel, :func:`_profile`): the HMM's state is (x, y, azimuth), whose walk
  is the 2-D one (a Gaussian random walk of ``walk_m`` and ``walk_deg`` per
  window, azimuth wrapping);
* the offset ``b`` is the one of :data:`OFFSETS_DB` whose forward-algorithm
  evidence plus the offset prior is largest (:func:`offset_evidence`; with
  ``paths`` > 1 also the next local maxima);
* the most likely path is :func:`viterbi_nd` (optionally with pitch and roll
  as walking states, ``tilt_walk_deg``: measured, not better);
* the path becomes a start of one pose per packet: x, y and azimuth
  interpolated linearly in time between the read windows' mean times (held
  beyond the first and last), height, pitch and roll those that minimised
  the packet's window at its cell (the nearest read window's).

Offline only: the path needs the whole track; the causal filter and the live
server never compute it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from radiopose.errors import InputError
from radiopose.filtering.coarse_track import _forward_window, _kernel, evidence_peaks, nearest
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import CoarseGrid

MIN_RECEIVERS = 3
"""A window heard by fewer receivers is not read (its pose is not fixed)."""
OFFSETS_DB = tuple(float(v) for v in range(-6, 7))
"""The device power offsets (dB) whose evidence is compared (the 3-D offset
bank's span, ±6 dB, in 1 dB steps)."""


def _axes(grid: CoarseGrid) -> tuple[list[FloatArray], tuple[int, ...]]:
    """The grid's axes ``[pitch, roll, azimuth, x, y, z]`` (sorted values) and
    the shape of its table rows in that order (``CoarseGrid.build``'s layout:
    row ``o · n_p + p``, ``o`` over (pitch, roll, azimuth), ``p`` over
    (x, y, z), each the last fastest)."""
    o, p = grid.orientations_deg, grid.positions_m
    axes = [np.unique(o[:, 1]), np.unique(o[:, 2]), np.unique(o[:, 0]),
            np.unique(p[:, 0]), np.unique(p[:, 1]), np.unique(p[:, 2])]  # fmt: skip
    shape = tuple(a.size for a in axes)
    if math.prod(shape[:3]) != o.shape[0] or math.prod(shape[3:]) != p.shape[0]:
        raise InputError("3-D coarse path: the acquisition grid is not a full product grid")
    return axes, shape


def window_index(times_s: FloatArray, window_s: float) -> np.ndarray:
    """Each packet's window, ``⌊(t − t₀) / window_s⌋`` (``times_s`` in seconds,
    non-decreasing)."""
    if not (window_s > 0):
        raise InputError(f"3-D coarse path: window_s = {window_s!r} must be positive")
    t = np.asarray(times_s, dtype=float)
    return np.floor((t - t[0]) / window_s).astype(np.int64)


def _medians(
    heard: Sequence[HeardRss], members: np.ndarray
) -> tuple[np.ndarray, FloatArray, FloatArray]:
    """The receivers heard by the packets ``members`` and, per receiver, the
    median RSS (dBm) and the number of readings."""
    rx = np.concatenate([np.asarray(heard[i].receiver_index, dtype=np.int64) for i in members])
    rss = np.concatenate([np.asarray(heard[i].rss_dbm, dtype=float) for i in members])
    ids = np.unique(rx)
    med = np.array([float(np.median(rss[rx == r])) for r in ids])
    n = np.array([float(np.count_nonzero(rx == r)) for r in ids])
    return ids, med, n


@dataclass(frozen=True)
class CoarseWindow:
    """One read window: the walk steps before it (0: the first), its receivers,
    their median RSS (dBm) and weights (1/dB²), and its packets' mean time (s)."""

    steps: int
    receivers: np.ndarray
    median_dbm: FloatArray
    weight: FloatArray
    time_s: float


def read_windows(
    times_s: FloatArray, heard: Sequence[HeardRss], sigma_db: float, grid_sigma_db: float,
    window_s: float,
) -> list[CoarseWindow]:  # fmt: skip
    """The track's windows heard by at least :data:`MIN_RECEIVERS` receivers."""
    win = window_index(times_s, window_s)
    out: list[CoarseWindow] = []
    last = 0
    for members in np.split(np.arange(win.size), np.flatnonzero(np.diff(win)) + 1):
        members = members[[heard[i].n_heard > 0 for i in members]]
        if members.size == 0:
            continue
        ids, med, n = _medians(heard, members)
        if ids.size < MIN_RECEIVERS:
            continue
        w_idx = int(win[members[0]])
        w = n / ((math.pi / 2) * sigma_db**2 + grid_sigma_db**2 * n)
        steps = w_idx - last if out else 0
        out.append(CoarseWindow(steps, ids, med, w, float(np.mean(times_s[members]))))
        last = w_idx
    return out


@numba.njit(cache=True)
def _profile(table, receivers, median, weight, offsets, shape, out):  # pragma: no cover
    """``out[x, y, azimuth, tilt, j]``: a window's cost ``Σ w (y − E − b_j)² /
    2`` at offset ``offsets[j]``, minimised over height, per (x, y, azimuth)
    cell and tilt ``pitch · n_roll + roll`` — or minimised over the tilts too
    when ``out`` has one tilt slot. ``table`` rows run ``CoarseGrid.build``'s
    layout: ``((pitch · n_roll + roll) · n_az + azimuth) · n_p + (x · ny + y) ·
    nz + z``."""
    n_pitch, n_roll, n_az, nx, ny, nz = shape
    m = offsets.size
    k = receivers.size
    n_p = nx * ny * nz
    keep = out.shape[3] > 1
    w_sum = 0.0
    for r in range(k):
        w_sum += weight[r]
    half_b2w = np.empty(m)
    for j in range(m):
        half_b2w[j] = 0.5 * offsets[j] * offsets[j] * w_sum
    out[:] = np.inf
    for ip in range(n_pitch):
        for ir in range(n_roll):
            for ia in range(n_az):
                base = ((ip * n_roll + ir) * n_az + ia) * n_p
                for ix in range(nx):
                    for iy in range(ny):
                        cell = out[ix, iy, ia, (ip * n_roll + ir) if keep else 0]
                        for iz in range(nz):
                            row = base + (ix * ny + iy) * nz + iz
                            a = 0.0
                            b = 0.0
                            for r in range(k):
                                e = median[r] - table[row, receivers[r]]
                                we = weight[r] * e
                                a += we * e
                                b += we
                            a *= 0.5
                            for j in range(m):
                                c = a - offsets[j] * b + half_b2w[j]
                                if c < cell[j]:
                                    cell[j] = c


@numba.njit(cache=True)
def _max_axis(src, dst, arg, log_kernel, wrap):  # pragma: no cover - compiled
    """``dst`` = the max-walk of ``src`` (log scores, ``(pre, n, post)``) along
    its middle axis: ``dst[p, i, q] = max_d src[p, i − d, q] + log_kernel[d]``
    (``d`` centred; wrapping when ``wrap``, else off-grid terms left out), the
    arg-max shift in ``arg``."""
    pre, n, post = src.shape
    h = (log_kernel.size - 1) // 2
    for p in range(pre):
        for i in range(n):
            for q in range(post):
                best = -np.inf
                bd = 0
                for d in range(log_kernel.size):
                    ii = i - (d - h)
                    if wrap:
                        ii = ii % n
                    elif ii < 0 or ii >= n:
                        continue
                    v = src[p, ii, q] + log_kernel[d]
                    if v > best:
                        best = v
                        bd = d - h
                dst[p, i, q] = best
                arg[p, i, q] = bd


_CHUNK = 64
"""Windows per chunk of the Viterbi's back-pointers (memory stays bounded)."""


def viterbi_nd(
    steps: Sequence[int],
    cost: Callable[[int], FloatArray],
    shape: tuple[int, ...],
    log_kernels: Sequence[FloatArray],
    wraps: Sequence[bool],
) -> list[tuple[int, ...]]:
    """The most likely path (one cell per window) of an HMM on a grid of
    ``shape`` whose motion is a separable random walk: per elapsed window one
    move along each axis ``k`` with log probabilities ``log_kernels[k]``
    (centred; the axis wraps when ``wraps[k]``). ``steps[q]`` is the number of
    walk steps before window ``q`` (0 at the first: a flat start), ``cost(q)``
    its negative log likelihood per cell. A first pass keeps the scores at
    every :data:`_CHUNK`-th window; the back-pointers are recomputed one chunk
    at a time, last first."""
    nd = len(shape)
    if not (len(log_kernels) == len(wraps) == nd):
        raise InputError("viterbi_nd: one kernel and one wrap flag per axis")
    views = [(math.prod(shape[:k]), shape[k], math.prod(shape[k + 1 :])) for k in range(nd)]
    buf = np.empty(shape)
    scratch = np.zeros((nd, *shape), dtype=np.int8)  # the back-pointers a pass drops

    def advance(delta: FloatArray, q: int, keep: bool) -> list[np.ndarray]:
        backs: list[np.ndarray] = []
        if steps[q] == 0:
            delta[:] = -cost(q)
            return backs
        for _ in range(steps[q]):
            arg = np.zeros((nd, *shape), dtype=np.int8) if keep else scratch
            for k in reversed(range(nd)):  # last axis first
                _max_axis(delta.reshape(views[k]), buf.reshape(views[k]),
                          arg[k].reshape(views[k]), log_kernels[k], wraps[k])  # fmt: skip
                delta[:] = buf
            if keep:
                backs.append(arg)
        delta -= cost(q)
        top = float(np.max(delta))
        if math.isfinite(top):
            delta -= top  # bounded scores; the arg-max path is unchanged
        return backs

    n = len(steps)
    chunks = [list(range(i, min(i + _CHUNK, n))) for i in range(0, n, _CHUNK)]
    delta = np.empty(shape)
    starts: list[FloatArray] = []
    for chunk in chunks[:-1]:
        starts.append(delta.copy())
        for q in chunk:
            advance(delta, q, keep=False)
    starts.append(delta)
    out: list[tuple[int, ...]] = []
    cell: list[int] = []
    for c, (chunk, start) in enumerate(zip(reversed(chunks), reversed(starts), strict=True)):
        delta = start.copy()
        backs = [advance(delta, q, keep=True) for q in chunk]
        if c == 0:  # the end: its best cell
            cell = [int(v) for v in np.unravel_index(int(np.argmax(delta)), shape)]
        for back in reversed(backs):
            out.append(tuple(cell))
            for arg in reversed(back):  # the steps, last first
                for k in range(nd):  # axis 0 was walked last
                    cell[k] -= int(arg[k][tuple(cell)])
                    if wraps[k]:
                        cell[k] %= shape[k]
    out.reverse()
    return out


class CoarseScorer:
    """A window's cost over the (x, y, azimuth, pitch, roll) cells at given
    offsets, height minimised (:func:`_profile`)."""

    def __init__(self, grid: CoarseGrid) -> None:
        self.axes, self.shape = _axes(grid)
        self.table = np.ascontiguousarray(grid.table_dbm)
        n_pitch, n_roll, n_az, nx, ny, _ = self.shape
        self.cells = (nx, ny, n_az, n_pitch, n_roll)

    def cost(self, window: CoarseWindow, offsets_db: FloatArray, tilts: bool = True) -> FloatArray:
        """``(nx, ny, n_az, n_pitch, n_roll, m)``: the window's cost per cell and
        offset (nats), height minimised; without ``tilts`` ``(nx, ny, n_az, m)``,
        pitch and roll minimised too."""
        n_tilts = self.cells[3] * self.cells[4] if tilts else 1
        out = np.empty((*self.cells[:3], n_tilts, offsets_db.size))
        _profile(self.table, window.receivers, window.median_dbm, window.weight,
                 np.asarray(offsets_db, dtype=float), self.shape, out)  # fmt: skip
        if tilts:
            return out.reshape(*self.cells, offsets_db.size)
        return out[:, :, :, 0, :]

    def best_rows(
        self, window: CoarseWindow, offset_db: float, cell: tuple[int, ...]
    ) -> tuple[int, int, int]:
        """The (pitch, roll, height) indices minimising the window's cost at
        ``cell``: ``(x, y, azimuth)`` indices (over every pitch and roll) or
        ``(x, y, azimuth, pitch, roll)`` (over the heights), at ``offset_db``."""
        n_pitch, n_roll, n_az, nx, ny, nz = self.shape
        ix, iy, ia = cell[:3]
        ip, ir, iz = np.meshgrid(
            np.arange(n_pitch) if len(cell) == 3 else np.array([cell[3]]),
            np.arange(n_roll) if len(cell) == 3 else np.array([cell[4]]),
            np.arange(nz),
            indexing="ij",
        )
        rows = ((ip * n_roll + ir) * n_az + ia) * (nx * ny * nz) + (ix * ny + iy) * nz + iz
        e = (window.median_dbm - offset_db)[None, :] - self.table[
            rows.ravel()[:, None], window.receivers[None, :]
        ]
        k = int(np.argmin((e * e) @ window.weight))
        return int(ip.ravel()[k]), int(ir.ravel()[k]), int(iz.ravel()[k])


def offset_evidence(
    grid: CoarseGrid,
    times_s: FloatArray,
    heard: Sequence[HeardRss],
    sigma_db: float,
    offsets_db: Sequence[float] = OFFSETS_DB,
    window_s: float = 0.1,
    walk_m: float = 0.35,
    walk_deg: float = 9.0,
    grid_sigma_db: float = 1.5,
) -> FloatArray:
    """The coarse HMM's log evidence (nats) per offset of ``offsets_db`` (dB):
    the forward algorithm over the track's windows on (x, y, azimuth), each
    window's cost minimised over height, pitch and roll per cell (module
    docstring). ``-inf`` everywhere when no window is read."""
    _check(sigma_db, walk_m, walk_deg, grid_sigma_db)
    offs = np.asarray(offsets_db, dtype=float)
    wins = read_windows(np.asarray(times_s, float), heard, sigma_db, grid_sigma_db, window_s)
    if not wins:
        return np.full(offs.size, -np.inf)
    return _evidence(CoarseScorer(grid), wins, offs, walk_m, walk_deg)


def _evidence(
    sc: CoarseScorer, wins: list[CoarseWindow], offs: FloatArray, walk_m: float, walk_deg: float
) -> FloatArray:
    """:func:`offset_evidence` over windows already read (not empty)."""
    kx, ka = _walks(sc, walk_m, walk_deg)
    flat = sc.cells[:3]
    alpha = np.empty((offs.size, *flat))
    ll = np.zeros(offs.size)
    zero = np.zeros(math.prod(flat))
    at_zero = np.zeros(1)
    for win in wins:
        cost = sc.cost(win, offs, tilts=False)
        for j in range(offs.size):
            c = np.ascontiguousarray(cost[..., j]).ravel()
            _forward_window(alpha[j : j + 1], win.steps, c, zero, 0.0, at_zero, kx, ka,
                            ll[j : j + 1])  # fmt: skip
    return ll


def _check(sigma_db: float, walk_m: float, walk_deg: float, grid_sigma_db: float) -> None:
    if not (sigma_db > 0 and grid_sigma_db >= 0 and walk_m > 0 and walk_deg > 0):
        raise InputError(
            "3-D coarse path: sigma_db, walk_m and walk_deg must be positive, grid_sigma_db >= 0"
        )


def _walks(sc: CoarseScorer, walk_m: float, walk_deg: float) -> tuple[FloatArray, FloatArray]:
    """The walk's kernels in x/y and azimuth cells (probabilities)."""
    xs, ys = sc.axes[3], sc.axes[4]
    steps = [float(np.min(np.diff(v))) for v in (xs, ys) if v.size > 1]
    step_m = min(steps) if steps else 1.0
    return _kernel(walk_m / step_m), _kernel(walk_deg / (360.0 / sc.cells[2]))


def _tilt_kernel(values_deg: FloatArray, walk_deg: float) -> FloatArray:
    """The tilt walk's kernel in cells of an axis of (roughly even) values, degrees."""
    if values_deg.size < 2:
        return np.ones(1)
    return _kernel(walk_deg / float(np.mean(np.diff(values_deg))))


def coarse_paths3d(
    grid: CoarseGrid,
    times_s: FloatArray,
    heard: Sequence[HeardRss],
    sigma_db: float,
    offset_db: float | None = None,
    window_s: float = 0.1,
    walk_m: float = 0.35,
    walk_deg: float = 9.0,
    grid_sigma_db: float = 1.5,
    offsets_db: Sequence[float] = OFFSETS_DB,
    offset_prior_sd_db: float = 6.0,
    tilt_walk_deg: float | None = None,
    paths: int = 1,
) -> list[tuple[FloatArray, FloatArray, float]]:
    """The coarse HMM's most likely path as a start for the packets of one track
    (see the module docstring).

    ``times_s`` (s, non-decreasing) and ``heard`` are the track's packets,
    ``sigma_db`` the per-reading σ (dB). The path is taken at ``offset_db``
    (dB) when given; otherwise at the offset of ``offsets_db`` whose log
    evidence (:func:`offset_evidence`) plus ``log N(b; 0,
    offset_prior_sd_db²)`` is largest, and with ``paths`` > 1 also at the
    next local maxima of that score over the offsets
    (:func:`radiopose.filtering.coarse_track.evidence_peaks`), up to ``paths``
    paths, the best first. With ``tilt_walk_deg`` (°) pitch and
    roll are states of the path too, walking by that standard deviation per
    window (the roll wrapping when the grid's rolls span the circle); without
    it they are minimised per window and cell. Returns ``(positions m (n,
    3), orientations ° (n, 3): azimuth, pitch, roll, the offset dB)`` per
    path, one row per packet; none when no window is heard by three
    receivers."""
    _check(sigma_db, walk_m, walk_deg, grid_sigma_db)
    if tilt_walk_deg is not None and not (tilt_walk_deg > 0):
        raise InputError(f"3-D coarse path: tilt_walk_deg = {tilt_walk_deg!r} must be positive")
    if paths < 1:
        raise InputError(f"3-D coarse path: paths = {paths!r} must be at least 1")
    t = np.asarray(times_s, dtype=float)
    if t.size == 0:
        return []
    wins = read_windows(t, heard, sigma_db, grid_sigma_db, window_s)
    if not wins:
        return []
    sc = CoarseScorer(grid)
    if offset_db is not None:
        chosen = [float(offset_db)]
    else:
        offs = np.asarray(offsets_db, dtype=float)
        ll = _evidence(sc, wins, offs, walk_m, walk_deg)
        score = ll - 0.5 * (offs / offset_prior_sd_db) ** 2
        chosen = [float(offs[i]) for i in evidence_peaks(score)[:paths]]
    return [_path(sc, wins, t, b, walk_m, walk_deg, tilt_walk_deg) for b in chosen]


def coarse_path3d(
    grid: CoarseGrid,
    times_s: FloatArray,
    heard: Sequence[HeardRss],
    sigma_db: float,
    offset_db: float | None = None,
    **kw: Any,
) -> tuple[FloatArray, FloatArray, float] | None:
    """:func:`coarse_paths3d`'s best path (``None`` when there is none)."""
    got = coarse_paths3d(grid, times_s, heard, sigma_db, offset_db, **kw)
    return got[0] if got else None


def window_path(
    sc: CoarseScorer, wins: list[CoarseWindow], offset_db: float, walk_m: float, walk_deg: float,
    tilt_walk_deg: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The Viterbi path at ``offset_db``: per read window its cell ``(x, y,
    azimuth, pitch, roll)`` indices ``(windows, 5)`` and its best height index."""
    kx, ka = _walks(sc, walk_m, walk_deg)
    b = np.array([offset_db])
    axes = sc.axes
    steps = [w.steps for w in wins]
    if tilt_walk_deg is None:
        path3 = viterbi_nd(
            steps, lambda q: sc.cost(wins[q], b, tilts=False)[..., 0], sc.cells[:3],
            [np.log(kx), np.log(kx), np.log(ka)], [False, False, True],
        )  # fmt: skip
        best = [sc.best_rows(w, offset_db, c) for w, c in zip(wins, path3, strict=True)]
        cells = np.array([(*c, ip, ir) for c, (ip, ir, _) in zip(path3, best, strict=True)])
        return cells.astype(np.int64), np.array([iz for _, _, iz in best], dtype=np.int64)
    rolls = axes[1]
    span = rolls[-1] - rolls[0] + (np.mean(np.diff(rolls)) if rolls.size > 1 else 0.0)
    roll_wraps = bool(rolls.size > 1 and span >= 359.0)
    path = viterbi_nd(
        steps, lambda q: sc.cost(wins[q], b)[..., 0], sc.cells,
        [np.log(kx), np.log(kx), np.log(ka), np.log(_tilt_kernel(axes[0], tilt_walk_deg)),
         np.log(_tilt_kernel(rolls, tilt_walk_deg))],
        [False, False, True, False, roll_wraps],
    )  # fmt: skip
    cells = np.array(path, dtype=np.int64)  # (windows, 5): ix, iy, iaz, ipitch, iroll
    iz = np.array([sc.best_rows(w, offset_db, c)[2] for w, c in zip(wins, path, strict=True)])
    return cells, iz


def _path(
    sc: CoarseScorer, wins: list[CoarseWindow], t: FloatArray, offset_db: float, walk_m: float,
    walk_deg: float, tilt_walk_deg: float | None,
) -> tuple[FloatArray, FloatArray, float]:  # fmt: skip
    """The Viterbi path at ``offset_db`` as poses at the packets' times ``t``:
    x, y and azimuth interpolated between the windows' mean times, height,
    pitch and roll those of the nearest window."""
    cells, iz = window_path(sc, wins, offset_db, walk_m, walk_deg, tilt_walk_deg)
    axes = sc.axes
    tw = np.array([w.time_s for w in wins])
    az_unwrapped = np.rad2deg(np.unwrap(np.deg2rad(axes[2][cells[:, 2]])))
    x = np.interp(t, tw, axes[3][cells[:, 0]])
    y = np.interp(t, tw, axes[4][cells[:, 1]])
    az = np.interp(t, tw, az_unwrapped) % 360.0
    near = nearest(tw, t)
    pos = np.column_stack([x, y, axes[5][iz[near]]])
    ori = np.column_stack([az, axes[0][cells[near, 3]], axes[1][cells[near, 4]]])
    return pos, ori, offset_db


__all__ = [
    "MIN_RECEIVERS",
    "OFFSETS_DB",
    "CoarseScorer",
    "CoarseWindow",
    "coarse_path3d",
    "coarse_paths3d",
    "nearest",
    "offset_evidence",
    "read_windows",
    "viterbi_nd",
    "window_index",
    "window_path",
]
