"""Offline: a whole-file coarse-grid HMM, its offset and its best path (a candidate track).

Beyond the paper (issue 15, search failures of the offline ``filter``;
docs/filter.md, "Coarse-grid HMM"). Every candidate track of the offline
arbiter (:mod:`radiopose.filtering.refine2d`) comes from a particle filter,
and a particle filter can lock: when no pass comes near the truth's basin the
arbiter has nothing right to choose (docs/filter.md, "Accuracy round 7", kind
1: pass 1's offset beliefs never near the device's, so no tight pass ran
there). This module searches the whole file exhaustively on a coarse grid
instead, so what it finds does not depend on what a filter happened to hold:

1. the packets are cut into windows of ``window_s`` (median RSS per heard
   receiver, :func:`radiopose.filtering.offset_profile.timed_windows`);
2. each window scores every pose of a coarse grid (``position_step_m`` ×
   ``azimuth_step_deg``, :class:`~radiopose.filtering.offset_profile.CoarseTable`)
   at each device offset ``b`` of a fixed set:
   ``c(pose, b) = Σ_r w_r (y_r − E_r(pose) − b)² / 2``, ``w_r = n_r / v``,
   ``v = (π/2) σ² + σ_g²`` (the median's variance and the grid's coarseness),
   nats;
3. between windows the pose moves by a random walk on the grid (a discretised
   Gaussian of ``step_sd_cells`` cells per window in x and y, and
   ``turn_sd_cells`` in azimuth, wrapping; applied once per elapsed window, so
   gaps widen it; a silence longer than ``reacquire_gap_s`` starts a new
   track from a flat prior);
4. per offset the forward algorithm gives the whole file's log evidence
   ``ℓ(b)`` (nats): unlike round 8's offset profile, which scores the
   windows independently, this has the motion's continuity, so one window's
   wrong (pose, offset) fit does not carry the file;
5. at the offset of the largest ``ℓ`` the Viterbi path (max-product over the
   same model) is the file's most likely coarse track, interpolated to the
   packets' times (azimuth unwrapped): a start for the arbiter's batch MAP
   refinement, which takes it from the grid's ±0.5 cell to the optimum of its
   basin (:class:`CoarseTrack`);
6. optionally (``paths`` > 1, :func:`coarse_tracks`) the Viterbi paths at the
   next local maxima of ``ℓ`` too: ``ℓ`` over the offsets is often
   multi-peaked at σ = 3 dB, and a mirror track can take the largest peak
   while the truth's path lies under the second (docs/filter.md,
   "Coarse-grid HMM: more than one path").

The forward step runs in a compiled kernel over every (offset, pose);
``Σ`` and ``max`` over the random walk are separable per axis.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np

from radiopose.errors import InputError
from radiopose.filtering.model import FilterModel
from radiopose.filtering.offset_profile import CoarseTable, Record, timed_windows
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray


@dataclass(frozen=True)
class CoarseSettings:
    """The coarse HMM's grid and model (defaults: docs/filter.md, "Coarse-grid HMM").

    Attributes
    ----------
    position_step_m, azimuth_step_deg
        The grid's steps, metres and degrees.
    window_s
        Window length, seconds.
    grid_sigma_db
        The grid's coarseness as noise added to every window reading, dB.
    step_sd_cells, turn_sd_cells
        The random walk's standard deviation per window, in grid cells of
        position (x and y) and of azimuth.
    offsets_db
        The device offsets scored, dB from the enrolled power.
    min_receivers
        Windows heard by fewer receivers carry no reading (the walk goes on).
    max_steps
        At most this many walk steps between two windows (longer gaps within a
        track are this many: the walk is nearly flat by then).
    path_position_step_m
        The Viterbi paths' grid step, metres (``None``: ``position_step_m``).
        A finer step than the evidence's (session 14) gives a path closer to
        the truth's basin at a fraction of the cost of a finer grid throughout:
        the evidence over every offset stays on the coarse grid, the path is
        found at one offset only. The walk keeps its size in metres
        (``step_sd_cells × position_step_m``).
    """

    position_step_m: float = 1.0
    azimuth_step_deg: float = 15.0
    window_s: float = 0.1
    grid_sigma_db: float = 0.5
    step_sd_cells: float = 0.35
    turn_sd_cells: float = 0.6
    offsets_db: tuple[float, ...] = tuple(float(v) for v in range(-12, 13))
    min_receivers: int = 3
    max_steps: int = 30
    path_position_step_m: float | None = None

    def __post_init__(self) -> None:
        for name in (
            "position_step_m", "azimuth_step_deg", "window_s", "grid_sigma_db",
            "step_sd_cells", "turn_sd_cells",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"coarse track setting {name} = {v!r} must be positive")
        if not self.offsets_db or not all(math.isfinite(v) for v in self.offsets_db):
            raise InputError(f"coarse track offsets {self.offsets_db!r} must be finite, not empty")
        if self.min_receivers < 1 or self.max_steps < 1:
            raise InputError("coarse track: min_receivers and max_steps must be at least 1")
        step = self.path_position_step_m
        if step is not None and not (math.isfinite(step) and step > 0):
            raise InputError(
                f"coarse track setting path_position_step_m = {step!r} must be positive"
            )


@dataclass(frozen=True, eq=False)
class CoarseTrack:
    """The whole file's coarse HMM (module docstring).

    Attributes
    ----------
    offsets_db
        ``(m,)`` the offsets scored, dB.
    log_evidence
        ``(m,)`` ``ℓ(b)``: the file's log evidence per offset, nats (the
        windows' readings; constants shared by every offset left out).
    offset_db
        The offset of this path, dB: the largest ``ℓ``'s for the first path
        (``nan`` with no window read), a further peak's for the others
        (:func:`coarse_tracks`).
    window_times_s
        ``(w,)`` each window's mean packet time, seconds.
    window_poses
        ``(w, 3)`` the Viterbi path at ``offset_db``: x (m), y (m), azimuth
        (deg) per window.
    window_track
        ``(w,)`` the track (silences longer than the gap split them) of each
        window.
    """

    offsets_db: FloatArray
    log_evidence: FloatArray
    offset_db: float
    window_times_s: FloatArray
    window_poses: FloatArray
    window_track: np.ndarray

    def poses_at(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The path at ``times_s`` (seconds, ascending): x, y linearly and the
        azimuth unwrapped between the windows of the nearest time's track, held
        beyond its ends; ``(n, 2)`` metres and ``(n,)`` degrees in ``[0, 360)``.
        Every time takes the track of its nearest window."""
        t = np.asarray(times_s, dtype=float)
        xy = np.empty((t.size, 2))
        az = np.empty(t.size)
        if self.window_times_s.size == 0:
            raise InputError("CoarseTrack.poses_at: no window was read")
        near = nearest(self.window_times_s, t)  # (ascending)
        for tr in np.unique(self.window_track):
            w = self.window_track == tr
            sel = self.window_track[near] == tr
            wt = self.window_times_s[w]
            p = self.window_poses[w]
            un = np.rad2deg(np.unwrap(np.deg2rad(p[:, 2])))
            xy[sel, 0] = np.interp(t[sel], wt, p[:, 0])
            xy[sel, 1] = np.interp(t[sel], wt, p[:, 1])
            az[sel] = np.interp(t[sel], wt, un) % 360.0
        return xy, az


def nearest(sorted_s: FloatArray, t_s: FloatArray) -> np.ndarray:
    """Per time of ``t_s``, the index of the nearest of ``sorted_s`` (seconds,
    non-decreasing, not empty; a tie goes to the earlier)."""
    ref = np.asarray(sorted_s, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if ref.size == 1:
        return np.zeros(t.size, dtype=np.int64)
    j = np.clip(np.searchsorted(ref, t), 1, ref.size - 1)
    return np.where(np.abs(t - ref[j - 1]) <= np.abs(ref[j] - t), j - 1, j).astype(np.int64)


def _kernel(sd_cells: float) -> FloatArray:
    """A discretised Gaussian of ``sd_cells`` over ±⌈3 sd⌉ cells, summing to 1."""
    half = max(math.ceil(3.0 * sd_cells), 1)
    d = np.arange(-half, half + 1, dtype=float)
    w = np.exp(-0.5 * (d / sd_cells) ** 2)
    return w / w.sum()


@numba.njit(cache=True)
def _walk_sum(src, dst, tmp, kx, ka):  # pragma: no cover - compiled
    """``dst = walk(src)`` for one offset's ``(nx, ny, na)`` probabilities: the
    separable random walk, azimuth wrapping, x and y not (mass off the grid
    is lost). ``tmp`` is scratch of the same shape. Inner loops run over
    contiguous memory."""
    nx, ny, na = src.shape
    hx = (kx.size - 1) // 2
    ha = (ka.size - 1) // 2
    row = np.empty(na + 2 * ha)
    for i in range(nx):  # azimuth, wrapping: src → tmp
        for j in range(ny):
            for a in range(na):
                row[a + ha] = src[i, j, a]
            for a in range(ha):
                row[a] = src[i, j, (a - ha) % na]
                row[na + ha + a] = src[i, j, a % na]
            for a in range(na):
                s = 0.0
                for d in range(ka.size):
                    s += ka[d] * row[a + 2 * ha - d]
                tmp[i, j, a] = s
    for i in range(nx):  # y: tmp → dst
        for j in range(ny):
            for a in range(na):
                dst[i, j, a] = 0.0
            for d in range(kx.size):
                jj = j - (d - hx)
                if 0 <= jj < ny:
                    w = kx[d]
                    for a in range(na):
                        dst[i, j, a] += w * tmp[i, jj, a]
    for i in range(nx):  # x: dst → tmp, copied back
        for j in range(ny):
            for a in range(na):
                tmp[i, j, a] = 0.0
        for d in range(kx.size):
            ii = i - (d - hx)
            if 0 <= ii < nx:
                w = kx[d]
                for j in range(ny):
                    for a in range(na):
                        tmp[i, j, a] += w * dst[ii, j, a]
    dst[:] = tmp


@numba.njit(cache=True)
def _forward_window(alpha, steps, a_cost, b_cost, w_sum, offsets, kx, ka, ll):  # pragma: no cover
    """One window of the forward algorithm for every offset, in place.

    ``alpha[j]`` (``(nx, ny, na)``) is offset ``j``'s filtered distribution
    (summing to 1), walked ``steps`` times (0: a flat prior, a track's first
    window), then weighted by ``exp(−c)`` with ``c = a_cost − b b_cost + b²
    w_sum / 2`` per pose (``inf`` where the map has no reading) and
    renormalised; ``ll[j]`` gains the log normaliser."""
    m, nx, ny, na = alpha.shape
    n = nx * ny * na
    buf = np.empty((nx, ny, na))
    tmp = np.empty((nx, ny, na))
    for j in range(m):
        cur = alpha[j]
        if steps == 0:
            cur[:] = 1.0 / n
        else:
            for _ in range(steps):
                _walk_sum(cur, buf, tmp, kx, ka)
                cur[:] = buf
        b = offsets[j]
        base = 0.5 * b * b * w_sum
        lo = np.inf
        flat = cur.reshape(n)
        for i in range(n):
            c = a_cost[i] - b * b_cost[i] + base
            if c < lo:
                lo = c
        if not math.isfinite(lo):  # no pose has a reading: the window says nothing
            continue
        s = 0.0
        for i in range(n):
            d = a_cost[i] - b * b_cost[i] + base - lo
            v = flat[i] * math.exp(-d) if d < 60.0 else 0.0
            flat[i] = v
            s += v
        if s > 0.0:
            for i in range(n):
                flat[i] /= s
            ll[j] += math.log(s) - lo
        else:  # every pose unreachable under this offset's walk: −inf evidence
            ll[j] = -np.inf
            cur[:] = 1.0 / n


@numba.njit(cache=True)
def _walk_max(src, dst, tmp, lx, la, arg):  # pragma: no cover - compiled
    """``dst = max-walk(src)`` in log space (the separable max over the walk's
    log kernel ``lx``/``la``), with the arg-max shift of each axis stored in
    ``arg[0..2]`` (x, y, azimuth), evaluated in the order azimuth, y, x."""
    nx, ny, na = src.shape
    hx = (lx.size - 1) // 2
    ha = (la.size - 1) // 2
    for i in range(nx):
        for j in range(ny):
            for a in range(na):
                best = -np.inf
                bd = 0
                for d in range(la.size):
                    v = src[i, j, (a - (d - ha)) % na] + la[d]
                    if v > best:
                        best = v
                        bd = d - ha
                dst[i, j, a] = best
                arg[2, i, j, a] = bd
    for i in range(nx):
        for j in range(ny):
            for a in range(na):
                best = -np.inf
                bd = 0
                for d in range(lx.size):
                    jj = j - (d - hx)
                    if 0 <= jj < ny:
                        v = dst[i, jj, a] + lx[d]
                        if v > best:
                            best = v
                            bd = d - hx
                tmp[i, j, a] = best
                arg[1, i, j, a] = bd
    for i in range(nx):
        for j in range(ny):
            for a in range(na):
                best = -np.inf
                bd = 0
                for d in range(lx.size):
                    ii = i - (d - hx)
                    if 0 <= ii < nx:
                        v = tmp[ii, j, a] + lx[d]
                        if v > best:
                            best = v
                            bd = d - hx
                dst[i, j, a] = best
                arg[0, i, j, a] = bd


@numba.njit(cache=True)
def _viterbi_step(delta, steps, cost, lx, la, back):  # pragma: no cover - compiled
    """One window of the Viterbi recursion at one offset, in place: ``delta``
    (log scores, ``(nx, ny, na)``) max-walked ``steps`` times (one set of
    back-pointers per step in ``back[s]``, ``(steps, 3, nx, ny, na)``), then
    ``− cost``. ``steps = 0``: a track's first window (``delta = −cost``)."""
    nx, ny, na = delta.shape
    buf = np.empty((nx, ny, na))
    tmp = np.empty((nx, ny, na))
    if steps == 0:
        delta[:] = -cost
        return
    for s in range(steps):
        _walk_max(delta, buf, tmp, lx, la, back[s])
        delta[:] = buf
    top = -np.inf
    for i in range(nx):
        for j in range(ny):
            for a in range(na):
                delta[i, j, a] -= cost[i, j, a]
                if delta[i, j, a] > top:
                    top = delta[i, j, a]
    if math.isfinite(top):
        delta -= top  # keeps the scores bounded; the arg-max path is unchanged


def _window_terms(
    table: FloatArray, receiver_index: np.ndarray, rss_dbm: FloatArray, weight: FloatArray
) -> tuple[FloatArray, FloatArray, float]:
    """Per pose ``A = Σ w e² / 2`` and ``B = Σ w e`` of the residuals ``e = y −
    E(pose)`` without offset (``A = inf`` where a heard receiver has no
    expected RSS), and ``W = Σ w``."""
    e = rss_dbm[None, :] - table[:, receiver_index]
    bad = np.asarray(~np.isfinite(e).all(axis=1), dtype=bool)
    e = np.where(bad[:, None], 0.0, e)
    a_cost = 0.5 * (e * e) @ weight
    b_cost = e @ weight
    a_cost[bad] = np.inf
    b_cost[bad] = 0.0
    return a_cost, b_cost, float(weight.sum())


def coarse_track(
    model: FilterModel,
    records: Sequence[Record],
    sigma_db: float,
    reacquire_gap_s: float,
    settings: CoarseSettings | None = None,
    table: CoarseTable | None = None,
) -> CoarseTrack:
    """The file's coarse HMM: the evidence per offset and the best path at the
    best offset (module docstring; :func:`coarse_tracks`' first)."""
    return coarse_tracks(model, records, sigma_db, reacquire_gap_s, settings, table)[0]


def coarse_tracks(
    model: FilterModel,
    records: Sequence[Record],
    sigma_db: float,
    reacquire_gap_s: float,
    settings: CoarseSettings | None = None,
    table: CoarseTable | None = None,
    paths: int = 1,
) -> list[CoarseTrack]:
    """The file's coarse HMM: the evidence per offset and the best path at the
    best offset (module docstring), then at the next local maxima of the
    evidence over the offsets (:func:`evidence_peaks`), up to ``paths`` paths
    in all, largest evidence first (session 14: a file whose evidence has a
    second peak near the first may hold the truth's path there).

    Parameters
    ----------
    model
        The 2-D filter's device model.
    records
        Every packet ``(t_s, heard, key)`` in time order.
    sigma_db
        The readings' noise σ (the forward filter's estimate), dB.
    reacquire_gap_s
        A silence longer than this starts a new track (``FilterConfig.reacquire_gap_s``).
    settings
        Grid and model (default :class:`CoarseSettings`).
    table
        The coarse grid, if built already (it depends on the model and the
        settings' steps only).
    paths
        At most this many paths (fewer when the evidence has fewer peaks).

    Raises
    ------
    InputError
        σ not positive, ``paths`` below 1.
    """
    cs = settings or CoarseSettings()
    if not (math.isfinite(sigma_db) and sigma_db > 0):
        raise InputError(f"coarse_track: sigma_db {sigma_db!r} must be positive")
    if paths < 1:
        raise InputError(f"coarse_track: paths = {paths!r} must be at least 1")
    tab = table or CoarseTable.build(model, cs.position_step_m, cs.azimuth_step_deg)
    shape = _grid_shape(tab)
    offs = np.asarray(cs.offsets_db, dtype=float)
    kx = _kernel(cs.step_sd_cells)
    ka = _kernel(cs.turn_sd_cells)
    # the windows read (enough receivers) and the walk steps before each; the
    # per-pose terms are recomputed in each pass (not kept: a long file has
    # tens of thousands of windows of ~170 kB of terms each)
    read: list[tuple[int, HeardRss, FloatArray]] = []
    track_of: list[int] = []
    win_t: list[float] = []
    last_t = -math.inf
    track = -1
    for heard, n, t in timed_windows(records, cs.window_s):
        if heard.n_heard < cs.min_receivers:
            continue
        if t - last_t > reacquire_gap_s:
            track += 1
            steps = 0
        else:
            steps = min(max(round((t - last_t) / cs.window_s), 1), cs.max_steps)
        last_t = t
        read.append((steps, heard, n / ((math.pi / 2) * sigma_db**2 + cs.grid_sigma_db**2 * n)))
        track_of.append(track)
        win_t.append(t)

    def terms_on(grid: CoarseTable) -> Callable[[int], tuple[FloatArray, FloatArray, float]]:
        def terms(q: int) -> tuple[FloatArray, FloatArray, float]:
            _, heard, w = read[q]
            rx = np.asarray(heard.receiver_index)
            return _window_terms(grid.table_dbm, rx, np.asarray(heard.rss_dbm), w)

        return terms

    terms = terms_on(tab)

    ll = np.zeros(offs.size)
    tracks = np.asarray(track_of, dtype=np.int64)
    if not read:
        return [CoarseTrack(offs, ll, math.nan, np.asarray(win_t), np.empty((0, 3)), tracks)]
    alpha = np.empty((offs.size, *shape))
    for q in range(len(read)):
        _forward_window(alpha, read[q][0], *terms(q), offs, kx, ka, ll)
    # the paths' grid: the evidence's, or a finer one (the walk's size in metres kept)
    fine = cs.path_position_step_m
    if fine is not None and fine != cs.position_step_m:
        ptab = CoarseTable.build(model, fine, cs.azimuth_step_deg)
        shape = _grid_shape(ptab)
        terms = terms_on(ptab)
        kx = _kernel(cs.step_sd_cells * cs.position_step_m / fine)
    else:
        ptab = tab
    poses = ptab.poses.reshape(*shape, 3)
    out = []
    for i in evidence_peaks(ll)[:paths]:
        b = float(offs[i])
        path = _viterbi_path(read, tracks, terms, b, shape, np.log(kx), np.log(ka))
        out.append(
            CoarseTrack(offs, ll, b, np.asarray(win_t), np.array([poses[c] for c in path]), tracks)
        )
    return out


def _grid_shape(table: CoarseTable) -> tuple[int, int, int]:
    """The grid's ``(nx, ny, na)``: its distinct x, y and azimuth values (its
    poses run x, then y, then azimuth fastest: ``CoarseTable.build``)."""
    nx, ny, na = (int(np.unique(table.poses[:, k]).size) for k in range(3))
    return nx, ny, na


def evidence_peaks(log_evidence: FloatArray) -> list[int]:
    """The local maxima of ``ℓ`` over the offsets (an index whose finite ``ℓ``
    is at least each neighbour's; plateaus give their first index), largest
    first (ties: the lower index); ``[argmax]`` when none is finite."""
    ll = np.asarray(log_evidence, dtype=float)
    n = ll.size
    peaks = [
        i
        for i in range(n)
        if math.isfinite(ll[i])
        and (i == 0 or ll[i] > ll[i - 1])
        and (i == n - 1 or ll[i] >= ll[i + 1])
    ]
    if not peaks:
        return [int(np.argmax(ll))]
    return sorted(peaks, key=lambda i: (-ll[i], i))


_CHUNK_WINDOWS = 256
"""Windows per chunk of :func:`_viterbi_path`'s back-pointers (3 bytes per grid
cell and walk step are kept for one chunk at a time)."""


def _viterbi_path(
    read: Sequence[tuple[int, object, object]],
    tracks: np.ndarray,
    terms: Callable[[int], tuple[FloatArray, FloatArray, float]],
    offset_db: float,
    shape: tuple[int, int, int],
    lx: FloatArray,
    la: FloatArray,
) -> list[tuple[int, int, int]]:
    """The Viterbi path (grid cells, one per window read) at ``offset_db``, one
    track at a time. Memory stays bounded on long files: a first pass keeps the
    scores only at the start of every chunk of ``_CHUNK_WINDOWS`` windows (up
    to the last chunk's); the backtrack then computes one chunk's back-pointers
    at a time from its start, last chunk first (the same path as keeping them
    all; a track of one chunk is computed once)."""

    def cost(q: int) -> FloatArray:
        a_cost, b_cost, w_sum = terms(q)
        out: FloatArray = (a_cost - offset_db * b_cost + 0.5 * offset_db**2 * w_sum).reshape(shape)
        return out

    scratch = np.zeros((1, 3, *shape), dtype=np.int8)

    def step(delta: FloatArray, q: int, keep: bool) -> np.ndarray:
        steps = read[q][0]
        back = np.zeros((max(steps, 1), 3, *shape), dtype=np.int8) if keep else scratch
        if not keep and steps > scratch.shape[0]:
            back = np.zeros((steps, 3, *shape), dtype=np.int8)
        _viterbi_step(delta, steps, cost(q), lx, la, back)
        return back[:steps]

    cells: list[tuple[int, int, int]] = []
    for tr in np.unique(tracks):
        idx = np.flatnonzero(tracks == tr).tolist()
        chunks = [idx[i : i + _CHUNK_WINDOWS] for i in range(0, len(idx), _CHUNK_WINDOWS)]
        delta = np.empty(shape)
        starts: list[FloatArray] = []
        for chunk in chunks[:-1]:  # (the last chunk's pass is its backtrack's)
            starts.append(delta.copy())
            for q in chunk:
                step(delta, q, keep=False)
        starts.append(delta)
        mine: list[tuple[int, int, int]] = []
        s = (0, 0, 0)
        for c, (chunk, start) in enumerate(zip(reversed(chunks), reversed(starts), strict=True)):
            delta = start.copy()
            backs = [step(delta, q, keep=True) for q in chunk]
            if c == 0:  # the track's end: its best cell
                i0, j0, a0 = np.unravel_index(int(np.argmax(delta)), shape)
                s = (int(i0), int(j0), int(a0))
            for back in reversed(backs):
                mine.append(s)
                i, j, a = s
                for st in back[::-1]:
                    i = i - int(st[0, i, j, a])
                    j = j - int(st[1, i, j, a])
                    a = (a - int(st[2, i, j, a])) % shape[2]
                s = (i, j, a)
        mine.reverse()
        cells += mine
    return cells


__all__ = ["CoarseSettings", "CoarseTrack", "coarse_track", "coarse_tracks", "evidence_peaks"]
