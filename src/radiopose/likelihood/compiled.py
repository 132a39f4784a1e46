"""The compiled likelihood kernel: circular-shift reads, fused top-k, exact rescoring.

Paper, "Enhanced Localisation Pipeline", steps 1–2, and "Performance". The
reference scores ``n_pos × n_orient × n_rx`` terms per packet (58 M on the
paper's 201 × 201 × 360 × 4 grid). This scorer does the same arithmetic in a
numba kernel (:mod:`~radiopose.likelihood.shift_kernels`) that reads memory
only contiguously and never materialises the scores; this module prepares the
kernel's tables and rescores its screened candidates exactly.

Structure exploited
-------------------
* For an azimuth-only candidate set (pitch = roll = 0) rotating the device by
  ``α`` about world ``z`` turns every body-frame direction by ``−α``: the
  pattern azimuth of receiver ``r`` seen from position ``p`` is
  ``φ_rp − α`` and its polar angle ``θ_rp`` does not change. With the pattern
  row at ``θ_rp`` written ``S`` (``n`` samples at step ``s_p``) and the
  candidate azimuths ``α_j = j·s`` with ``s = m·s_p`` (the pattern is
  upsampled to the candidate step when it is coarser — exactly, since
  bilinear interpolation of a piecewise-linear function at finer nodes is the
  same function), the bilinear lookup is

      D_j = (1 − f) S[i0 − m·j] + f S[i0 − m·j + 1]          (indices mod n)

  with ``i0``, ``f`` fixed per ``(r, p)``. Storing the row *reversed and
  repeated* (``Rv[k] = S[−k mod n]``) turns both reads into contiguous runs
  ``Rv[o + m·j]`` and ``Rv[o − 1 + m·j]``: no trigonometry, no gathers.
* A full-sphere pattern blends two such rows (``θ_rp`` between polar samples).
* Everything but the packet's RSS is prepared once per site and device:
  ``B_r(p) = M_r(p) + P_tx − c_r`` (centred by ``c_r`` to keep float32
  round-off small), ``o``, ``f``, row indices and weights.
* Per packet, ``w_r = RSS_r − c_r``; the kernel accumulates
  ``Σ_r (w_r − B_r(p) − D_rj)²`` in float32 over a window of azimuths for every
  position, in parallel over fixed chunks of positions, each chunk keeping its
  own ``k'`` best in a bounded buffer with a running threshold (fused top-k).

Exactness
---------
The float32 screen is within ``δ(v) = 2ε√v + ε² + 2h·eps₃₂·v`` of the exact
MSE ``v`` (``ε`` bounds the error of one residual, derived from the table's
magnitudes). The ``k'`` best screened candidates (``k' > k``) are rescored in
float64 by the reference's own function and the top-k taken with the same tie
rule. If the ``k'``-th screened value minus its ``δ`` is not above the
``k``-th plus its ``δ``, some true top-k candidate could be missing, so ``k'``
is quadrupled and the packet rescored (counted in :attr:`ShiftScorer.retries`).
Where ``ε`` is several dB (a horizontal slice pattern seen at pitch ±89–90°:
the rotated rows jump by the pattern's front-to-back difference) no shortlist
short of the whole window can be certified; then the window is scored exactly
in chunks, positions ordered by a lower bound of their MSE, and the search
stops once that bound exceeds the ``k``-th best (counted in
:attr:`ShiftScorer.exact_fallbacks`). On the paper's 201 × 201 positions
with a 5° azimuth step and pitch ``[-90, 0, 90]`` (8.7 M candidates) that is
about 1 s a packet in 0.2 GB, against 7 s and 2.9 GB for the retries up to
the whole grid (the same estimates; docs/performance.md).
The output therefore equals the reference's, candidate for candidate.

Bounded search
--------------
:meth:`ShiftScorer.score_window` scores only a list of positions and a window
of azimuths (the tracker's movement and rotation bounds); the full grid stays
available through :meth:`ShiftScorer.score_heard`.

Results do not depend on the number of threads: chunks are fixed and merged in
order.

The numba kernels themselves are in :mod:`radiopose.likelihood.shift_kernels`;
this module stays one piece (~940 lines, a quarter of it docstrings) because the
table preparation, the search thresholds and the exact rescoring all rest on
the one exactness bound above, which a split would state twice.
"""

from __future__ import annotations

import contextlib
import copy
import math
import os
import time
from collections.abc import Hashable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numpy.typing import NDArray

from radiopose.cores import available_cores
from radiopose.geometry import direction_to_pattern_angles_deg
from radiopose.likelihood.candidates import CandidateSpace, HeardRss, exact_mse_db2
from radiopose.likelihood.capabilities import ScorerBase
from radiopose.likelihood.shift_kernels import (
    dense_topk as _dense,
)
from radiopose.likelihood.shift_kernels import (
    prefilter as _prefilter,
)
from radiopose.likelihood.shift_kernels import (
    prune_cut as _prune_cut,
)
from radiopose.likelihood.shift_kernels import (
    shift_topk as _shift_topk,
)
from radiopose.likelihood.shift_kernels import (
    shift_topk_serial as _shift_topk_serial,
)
from radiopose.likelihood.shift_kernels import (
    shift_topk_shared as _shift_topk_shared,
)
from radiopose.likelihood.topk import TopK, merge_topk, select_topk
from radiopose.patterns.pattern import Pattern
from radiopose.units import wrap_deg

_EPS32 = float(np.finfo(np.float32).eps)
DENSE_MAX_VALUES = 65_536
"""Largest threshold pass scored densely (one array, then a partition); larger
ones use the kernel's per-chunk heaps."""
_LAST_CALL = object()  # `slot` of a search that uses (and sets) the last call's hint
_NO_HINT = np.empty(0, np.int64)
PARALLEL_MIN_TERMS = 1_000_000
"""Full-grid candidate-receiver terms from which the kernel runs on several threads."""
HOPELESS_FACTOR = 16.0
"""A search whose screened values cannot be told from the k-th best up to
``HOPELESS_FACTOR`` × the last kept value + 1 dB² scores its window exactly
instead of retrying with ever larger heaps (:meth:`ShiftScorer._screen_hopeless`)."""
EXACT_CHUNK = 1 << 20
"""Candidates scored per exact pass of :meth:`ShiftScorer._exact_window`."""


class UnsupportedSpaceError(ValueError):
    """The candidate space lacks the structure this kernel needs."""


# ---------------------------------------------------------------------------- tables
def _row_grid(pattern: Pattern, candidate_step_deg: float) -> tuple[float, int]:
    """Azimuth step of the kernel's pattern rows and the samples per candidate step ``m``.

    The pattern's own step when the candidate step is a multiple of it; else
    the candidate step (upsampling a bilinear pattern to finer nodes is exact).
    """
    sp = pattern.azimuth_step_deg
    ratio = candidate_step_deg / sp
    if abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1:
        return sp, round(ratio)
    up = sp / candidate_step_deg
    if abs(up - round(up)) > 1e-9:
        raise UnsupportedSpaceError(
            f"candidate azimuth step {candidate_step_deg:g} deg and pattern step {sp:g} deg "
            "are not integer multiples of one another"
        )
    if abs(pattern.azimuth_deg[0]) > 1e-12:
        raise UnsupportedSpaceError("pattern azimuths must start at 0")
    return candidate_step_deg, 1


def _rotated_rows(
    pattern: Pattern, qs_deg: NDArray, row_step_deg: float, polar_deg: NDArray, ts_deg: float
) -> tuple[NDArray, float]:
    """Pattern rows seen in the azimuth-rotated frame of each (pitch, roll) combination.

    With ``R = Rz(α)·A`` and ``A = Rx(pitch)·Ry(roll)``, a world direction ``d``
    has body direction ``Aᵀ u`` where ``u = Rz(α)ᵀ d`` has angles
    ``(φ_w − α, θ_w)``. So ``P_q(φ', θ') = D(Aᵀ u(φ', θ'))`` turns every
    combination into a shift in ``φ'``. Rows are sampled at the grid nodes
    ``(φ' = i·row_step, θ' = polar)``; for ``A = I`` they are the pattern's own
    values (bilinear lookups at nodes), so the kernel is exact. For other
    combinations the kernel interpolates the sampled rows; the largest
    deviation from direct lookups, sampled at three points per cell and
    doubled, is returned (dB) and widens the exactness margin.

    Returns
    -------
    rows
        ``(n_q · n_polar, n)`` dBi, combination-major.
    error_db
        The resampling error bound (0 when every combination is the identity).
    """
    from radiopose.geometry import stored_orientation_matrices

    n = round(360.0 / row_step_deg)
    phi = np.arange(n) * row_step_deg
    out = []
    err = 0.0
    qs = np.asarray(qs_deg, dtype=np.float64).reshape(-1, 2)
    # all combinations at once, memoised (the same matrices as one call each)
    mats = stored_orientation_matrices(np.column_stack([np.zeros(len(qs)), qs]))
    for (pitch, roll), a in zip(qs.tolist(), mats, strict=True):

        def lookup(ph: NDArray, th: NDArray, a: NDArray = a) -> NDArray:
            p, t = np.deg2rad(ph), np.deg2rad(th)
            u = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
            bp, bt = direction_to_pattern_angles_deg(u @ a)  # (Aᵀ u)ᵀ = uᵀ A
            return pattern.lookup_dbi(bp, bt)

        ph, th = np.meshgrid(phi, polar_deg, indexing="xy")
        rows_q = lookup(ph, th)  # (n_polar, n)
        out.append(rows_q)
        if pitch != 0.0 or roll != 0.0:
            fp = (np.arange(3 * n) + 0.5) * row_step_deg / 3.0
            ft = np.linspace(polar_deg[0], polar_deg[-1], 3 * max(polar_deg.size - 1, 1) + 1)
            gp, gt = np.meshgrid(fp, ft, indexing="xy")
            exact = lookup(gp, gt)
            approx = _bilinear(rows_q, gp / row_step_deg, (gt - polar_deg[0]) / ts_deg)
            err = max(err, float(np.max(np.abs(exact - approx))))
    return np.concatenate(out, axis=0), 2.0 * err


def _bilinear(rows: NDArray, u: NDArray, v: NDArray) -> NDArray:
    """The kernel's interpolation of ``rows`` (n_polar, n) at fractional indices
    ``u`` (azimuth, periodic) and ``v`` (polar, clamped)."""
    n = rows.shape[1]
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    i0 %= n
    i1 = (i0 + 1) % n
    if rows.shape[0] == 1:
        return (1 - f) * rows[0, i0] + f * rows[0, i1]
    j0 = np.clip(np.floor(v), 0, rows.shape[0] - 2).astype(np.int64)
    g = np.clip(v - j0, 0.0, 1.0)
    top = (1 - f) * rows[j0, i0] + f * rows[j0, i1]
    bot = (1 - f) * rows[j0 + 1, i0] + f * rows[j0 + 1, i1]
    return (1 - g) * top + g * bot


def _window_tables(rv: NDArray, m: int, block: int, length: int, n_az: int) -> tuple[NDArray, ...]:
    """Block bound tables ``(blo, bhi, blo2, bhi2)``, each ``(n_rows, K, n_blocks)`` float32.

    ``blo[t, k, b]`` is the minimum of the samples that the ``b``-th block of
    ``block`` candidates blends when the window starts at offset ``k``:
    ``Rv[k + m·b·block − 1 … k + m·(b·block + block − 1)]``; ``blo2`` the same
    over rows ``t`` and ``t + 1`` (polar blending). Laid out with the block
    index last so that one position's bounds are contiguous reads.
    """
    span = m * (block - 1) + 2
    pad = np.concatenate([rv[:, :1], rv, np.repeat(rv[:, -1:], span, axis=1)], axis=1)
    win = np.lib.stride_tricks.sliding_window_view(pad, span, axis=1)[:, :length]
    bmin = win.min(axis=2)
    bmax = win.max(axis=2)
    nxt = np.concatenate([np.arange(1, rv.shape[0]), [rv.shape[0] - 1]])
    n_blocks = -(-n_az // block)
    starts = np.arange(length - m * (n_az - 1))[:, None] + m * block * np.arange(n_blocks)[None]
    starts = np.minimum(starts, length - 1)
    return tuple(
        np.ascontiguousarray(a[:, starts], dtype=np.float32)
        for a in (bmin, bmax, np.minimum(bmin, bmin[nxt]), np.maximum(bmax, bmax[nxt]))
    )


class ShiftScorer(ScorerBase):
    """Compiled circular-shift scorer (see module docstring).

    Parameters
    ----------
    space
        The device's candidate space. Orientations must be azimuths
        ``0, s, 2s, …`` (fastest) × any (pitch, roll) combinations, with ``s``
        and the pattern's azimuth step integer multiples of one another —
        otherwise :class:`UnsupportedSpaceError`.
    oversample
        The screened shortlist starts at ``k + oversample`` candidates.
    block
        Azimuths per pruning block.
    prune
        Skip positions and blocks whose lower bound cannot make the cut.
    parallel
        Run the kernel on numba's threads; ``None`` (default): only when a
        full-grid packet has at least :data:`PARALLEL_MIN_TERMS`
        candidate-receiver terms and more than one thread is configured — on a
        small grid, starting the threads costs more than it saves, and on a
        busy machine (a live server) a parallel region waits for its slowest
        thread. Results do not depend on it.
    """

    name = "numba"
    borrow_hints = False
    """Searches named by a slot (:meth:`score_heard_slot`) also lower their
    starting threshold on the other slots' hints (:meth:`_borrowed_threshold`);
    on for the particle filter's searches (``FilterModel.build``). Speed only:
    the results are the same either way."""
    supports_window = True
    supports_position_mse = True

    def __init__(
        self,
        space: CandidateSpace,
        oversample: int = 64,
        block: int = 24,
        prune: bool = True,
        parallel: bool | None = None,
    ) -> None:
        o = space.orientations_deg
        n_o = o.shape[0]
        n_az = int(np.argmax(np.r_[o[1:, 0] <= o[:-1, 0], True])) + 1
        step = 360.0 / n_az
        if n_o % n_az:
            raise UnsupportedSpaceError(
                "orientations are not azimuths × (pitch, roll) combinations"
            )
        grid = o.reshape(n_o // n_az, n_az, 3)
        if not (
            np.allclose(grid[:, :, 0], np.arange(n_az) * step, atol=1e-9)
            and np.all(grid[:, :, 1:] == grid[:, :1, 1:])
        ):
            raise UnsupportedSpaceError(
                "candidate azimuths must be 0, s, 2s, ... (fastest) covering 360"
            )
        self.space = space
        self.n_az = n_az
        self.qs_deg = np.ascontiguousarray(grid[:, 0, 1:])  # (n_q, 2) pitch, roll
        self.n_q = self.qs_deg.shape[0]
        self.oversample = int(oversample)
        self.block = int(block)
        self.prune = bool(prune)
        self.retries = 0
        self.exact_fallbacks = 0
        self._hint = np.empty(0, np.int64)
        self._slot_hints: dict[Hashable, np.ndarray] = {}

        pattern = space.pattern
        row_step, m = _row_grid(pattern, step)
        self.m = m
        n = round(360.0 / row_step)
        d = space.receiver_positions_m[:, None, :] - space.positions_m[None, :, :]
        phi, theta = direction_to_pattern_angles_deg(d)  # world angles (n_rx, n_pos)
        u = wrap_deg(phi) / row_step
        i0 = np.floor(u)
        frac = (u - i0).astype(np.float32)
        i0 = i0.astype(np.int64) % n
        off = (((-i0 - 1) % n) + 1).astype(np.int32)

        identity = bool(np.all(self.qs_deg == 0.0))
        if pattern.is_slice and identity:
            polar = np.array([90.0])  # one row serves every polar angle
            ts = 1.0
        else:
            ts = pattern.polar_step_deg if not pattern.is_slice else 1.0
            lo = np.floor(np.min(theta) / ts + 1e-9) * ts
            hi = np.ceil(np.max(theta) / ts - 1e-9) * ts
            polar = lo + ts * np.arange(round((hi - lo) / ts) + 1)
        self.rows_per_q = polar.size
        if polar.size == 1:
            row0 = np.zeros(phi.shape, np.int32)
            roww = np.zeros(phi.shape, np.float32)
        else:
            tt = (np.clip(theta, 0.0, 180.0) - polar[0]) / ts
            t0 = np.clip(np.floor(tt), 0, polar.size - 2)
            row0 = t0.astype(np.int32)
            roww = np.clip(tt - t0, 0.0, 1.0).astype(np.float32)
        rows, self.resample_error_db = _rotated_rows(pattern, self.qs_deg, row_step, polar, ts)

        # Reversed, repeated rows: Rv[k] = S[(-k) mod n], long enough for any window.
        length = n + m * 2 * n_az + 2
        rv = rows[:, (-np.arange(length)) % n]
        self.rows = np.ascontiguousarray(rv, dtype=np.float32)
        drv = np.zeros_like(rv)
        drv[:, 1:] = rv[:, :-1] - rv[:, 1:]
        self.drows = np.ascontiguousarray(drv, dtype=np.float32)
        self.bounds = _window_tables(rv, m, self.block, length, n_az)
        nxt = np.minimum(np.arange(rv.shape[0]) + 1, rv.shape[0] - 1)
        rmin = rv.min(axis=1)
        rmax = rv.max(axis=1)
        self.row_min = np.minimum(rmin, rmin[nxt]).astype(np.float32)
        self.row_max = np.maximum(rmax, rmax[nxt]).astype(np.float32)

        valid = np.isfinite(space.channel_db)
        base = space.channel_db + space.tx_power_dbm
        self.centre_db = np.array(
            [
                float(np.mean(base[r][valid[r]])) if valid[r].any() else 0.0
                for r in range(space.n_receivers)
            ]
        )
        base = (base - self.centre_db[:, None]).astype(np.float32)
        with np.errstate(invalid="ignore"):
            self.base_max = np.nanmax(np.abs(base), axis=1).astype(np.float64)
        self.d_max = float(np.max(np.abs(rows)))
        # Per-(receiver, position) terms, stored position-major for the kernels
        # (``base``, ``frac``, ``roww``, ``off``, ``row0`` are views of these).
        self.posf = np.ascontiguousarray(np.stack([base, frac, roww], axis=-1).transpose(1, 0, 2))
        self.posi = np.ascontiguousarray(np.stack([off, row0], axis=-1).transpose(1, 0, 2))
        self.all_positions = np.arange(space.n_positions, dtype=np.int64)
        if parallel is None:
            terms = space.n_positions * n_o * space.n_receivers
            parallel = terms >= PARALLEL_MIN_TERMS and threads() > 1
        self.parallel = bool(parallel)
        self._kernel = _shift_topk if self.parallel else _shift_topk_serial
        # Whole-row bounds per (receiver, position) over every (pitch, roll)
        # combination, for the vectorised prefilter (float64; ±inf: excluded).
        qoff = np.arange(self.n_q)[:, None, None] * self.rows_per_q
        lo_q = self.row_min[row0[None] + qoff].min(axis=0).astype(np.float64)
        hi_q = self.row_max[row0[None] + qoff].max(axis=0).astype(np.float64)
        b64 = base.astype(np.float64)
        bad = ~np.isfinite(b64)
        self.pre_lo = np.ascontiguousarray(np.where(bad, np.inf, b64 + lo_q))
        self.pre_hi = np.ascontiguousarray(np.where(bad, -np.inf, b64 + hi_q))

    @property
    def base(self) -> np.ndarray:
        """``(n_rx, n_pos)`` float32 ``M + P_tx − centre`` (NaN: excluded); a view."""
        return self.posf[:, :, 0].T

    @property
    def frac(self) -> np.ndarray:
        """``(n_rx, n_pos)`` float32 fractional azimuth offset ``f``; a view."""
        return self.posf[:, :, 1].T

    @property
    def roww(self) -> np.ndarray:
        """``(n_rx, n_pos)`` float32 weight of the second pattern row (0: single row); a view."""
        return self.posf[:, :, 2].T

    @property
    def off(self) -> np.ndarray:
        """``(n_rx, n_pos)`` int32 azimuth offset ``o`` in ``[1, n]``; a view."""
        return self.posi[:, :, 0].T

    @property
    def row0(self) -> np.ndarray:
        """``(n_rx, n_pos)`` int32 first pattern row; a view."""
        return self.posi[:, :, 1].T

    @property
    def nbytes(self) -> int:
        """Memory held by the precomputed tables, bytes."""
        arrays = (
            self.rows,
            self.drows,
            *self.bounds,
            self.posf,
            self.posi,
            self.pre_lo,
            self.pre_hi,
        )
        return int(sum(a.nbytes for a in arrays))

    # ------------------------------------------------------------------ scoring
    def _delta(self, v: np.ndarray | float, heard: HeardRss, w: np.ndarray) -> np.ndarray:
        """Bound on |screened − exact| MSE at screened value(s) ``v`` (dB²)."""
        r = heard.receiver_index
        eps = 6.0 * _EPS32 * float(np.max(np.abs(w) + self.base_max[r] + self.d_max + 1.0))
        eps += self.resample_error_db
        v = np.maximum(np.asarray(v, np.float64), 0.0)
        h = heard.n_heard
        return 2.0 * eps * np.sqrt(v + eps) + eps * eps + 2.0 * (h + 2) * _EPS32 * v

    def _screen_hopeless(self, kth: float, excluded: float, heard: HeardRss, w: np.ndarray) -> bool:
        """Whether the screened values cannot single out the ``k`` best.

        A candidate left out of the shortlist may be dropped only if its
        screened value ``x`` has ``x − δ(x) > kth + δ(kth)`` (:meth:`_delta`).
        ``x − δ(x)`` is convex in ``x``, so if it fails at ``X`` =
        :data:`HOPELESS_FACTOR` × ``excluded`` + 1 dB² it fails for every
        ``x ≤ X``: every candidate up to ``X`` would have to be scored exactly,
        far more than the next retry's heap holds. That happens when the
        pattern rows cannot be resampled closely (:attr:`resample_error_db` of
        several dB: a horizontal slice pattern seen at pitch ±89–90°, where the
        body azimuth of a horizontal direction jumps by 180°). Only speed and
        memory depend on this answer, never the result."""
        x = HOPELESS_FACTOR * max(excluded, 0.0) + 1.0
        target = kth + float(self._delta(kth, heard, w))
        return x - float(self._delta(x, heard, w)) <= target

    def _exact_window(
        self, heard: HeardRss, k: int, positions: np.ndarray, j0: int, cnt: int
    ) -> TopK:
        """Top-k of every candidate in ``positions`` × the azimuth window
        ``[j0, j0 + cnt)`` (every pitch and roll), each scored exactly
        (:func:`exact_mse_db2`), :data:`EXACT_CHUNK` candidates at a time with a
        running top-k: the result of a shortlist that holds every scorable
        candidate, in bounded memory (:func:`select_topk` orders by MSE, then
        index, so chunking does not change it)."""
        n_o = self.n_az * self.n_q
        js = (j0 + np.arange(cnt)) % self.n_az
        orient = (np.arange(self.n_q)[:, None] * self.n_az + js[None, :]).ravel()
        per = max(1, EXACT_CHUNK // orient.size)
        # positions by a lower bound of their exact MSE, lowest first: once a
        # chunk's first bound exceeds the k-th best so far, no later one can enter
        lb = self._position_lower_bound(heard, positions)
        order = np.argsort(lb, kind="stable")
        pos, lb = positions[order], lb[order]
        best = TopK(np.empty(0, np.int64), np.empty(0))
        for s in range(0, pos.size, per):
            if len(best) == k:
                kth = float(best.mse_db2[-1])
                if lb[s] > kth + 1e-9 * (1.0 + kth):
                    break
            idx = (pos[s : s + per, None] * n_o + orient[None, :]).ravel()
            mse = exact_mse_db2(self.space, heard, idx, parallel=spare_core())
            best = merge_topk(best, select_topk(idx, mse, k), k)
        return best

    def _position_lower_bound(self, heard: HeardRss, positions: np.ndarray) -> np.ndarray:
        """Per position, a lower bound of the exact MSE of every orientation there
        (dB², float64; inf where a heard receiver's survey map is NaN): each
        receiver's residual ``rss − M_r(p) − P_tx`` measured from the interval
        of the pattern's directivity, whose bilinear lookups stay inside it."""
        d = self.space.pattern.directivity_dbi
        d_lo, d_hi = float(np.min(d)), float(np.max(d))
        r = heard.receiver_index
        res = (
            heard.rss_dbm[:, None]
            - self.space.channel_db[r][:, positions]
            - float(self.space.tx_power_dbm)
        )
        gap = np.maximum(d_lo - res, 0.0) + np.maximum(res - d_hi, 0.0)
        lb = np.mean(gap * gap, axis=0)
        return np.where(np.isfinite(lb), lb, np.inf)

    def _kernel_args(self) -> tuple:
        return (
            self.posf,
            self.posi,
            self.rows,
            self.drows,
            *self.bounds,
            self.row_min,
            self.row_max,
            self.m,
            self.n_az,
            self.n_q,
            self.rows_per_q,
        )

    def _threshold(
        self,
        w: np.ndarray,
        r: np.ndarray,
        positions: np.ndarray,
        j0: int,
        cnt: int,
        kk: int,
        hint: np.ndarray,
    ) -> float:
        """An upper bound on the ``kk``-th best screened value (inf if none found).

        Scores a few positions fully — those of the previous packet's shortlist
        when they are among ``positions`` (consecutive packets of a track are
        near each other), else every 25th position — and returns their
        ``kk``-th best value. Only speed depends on this choice, never the result.
        """
        if positions is self.all_positions:
            pick = hint
        else:
            pick = hint[np.isin(hint, positions)]
        per_pos = cnt * self.n_q
        if pick.size * per_pos < kk:
            pick = positions[:: max(1, min(25, positions.size * per_pos // (4 * kk)))]
        pick = np.ascontiguousarray(pick)
        if pick.size * per_pos > DENSE_MAX_VALUES:
            # many (pitch, roll) rows or a cold start: per-chunk heaps, not one big array
            kernel = self._kernel if spare_core() else _shift_topk_serial  # busy: one thread
            pv, _ = kernel(
                w, r, *self._kernel_args(), pick, j0, cnt, kk, self.block, np.float32(np.inf)
            )
            vals = pv[np.isfinite(pv)]
        else:
            vals = _dense(w, r, *self._kernel_args(), pick, j0, cnt)
        if vals.size < kk:
            return np.inf
        return float(np.partition(vals, kk - 1)[kk - 1])  # +inf if too few are scorable

    def _borrowed_threshold(
        self,
        w: np.ndarray,
        r: np.ndarray,
        positions: np.ndarray,
        j0: int,
        cnt: int,
        kk: int,
        slot: Hashable,
        thr0: float,
    ) -> float:
        """``thr0`` lowered by the other slots' hints: the shortlist positions of
        the caller's other recurring searches (the filter's other power offsets,
        among them the offset belief searched a moment before, which knows where
        the track is now) scored by the pruned kernel under ``thr0``; their
        ``kk``-th best screened value if lower. Like :meth:`_threshold`, an upper
        bound on the ``kk``-th best (``kk`` real candidates score at most it), so
        only speed depends on it, never the result."""
        # a snapshot: concurrent searches (score_heard_many) add their own slots
        others = [v for s, v in tuple(self._slot_hints.items()) if s != slot and v.size]
        if not others:
            return thr0
        pick = np.unique(np.concatenate(others))
        if positions is not self.all_positions:
            pick = pick[np.isin(pick, positions)]
        if np.isfinite(thr0):
            cut = float(_prune_cut(np.float32(thr0), r.size))
            pick = _prefilter(w, r, self.pre_lo, self.pre_hi, pick, False, cut)
        if pick.size * cnt * self.n_q < kk:
            return thr0
        _, _, thr = _shift_topk_shared(
            w, r, *self._kernel_args(), pick, j0, cnt, kk, self.block, np.float32(thr0)
        )
        return min(thr0, float(thr))

    def _run(
        self,
        heard: HeardRss,
        k: int,
        positions: np.ndarray,
        j0: int,
        cnt: int,
        slot: Hashable = _LAST_CALL,
    ) -> TopK:
        # the threshold hint: the last call's shortlist positions, or those of
        # the last search of the caller's `slot` (score_heard_slot)
        hint = self._hint if slot is _LAST_CALL else self._slot_hints.get(slot, _NO_HINT)
        r = heard.receiver_index
        w64 = heard.rss_dbm - self.centre_db[r]
        w = w64.astype(np.float32)
        kk = k + self.oversample
        n_total = positions.size * cnt * self.n_q
        exact: TopK | None = None  # the exact fallback's answer, when it ran
        while True:
            kk_eff = int(min(kk, max(n_total, 1)))
            thr0 = np.inf
            if self.prune and n_total > 8 * kk_eff:
                thr0 = self._threshold(w, r, positions, j0, cnt, kk_eff, hint)
                if self.borrow_hints and slot is not _LAST_CALL:
                    thr0 = self._borrowed_threshold(w, r, positions, j0, cnt, kk_eff, slot, thr0)
            run_pos = positions
            if np.isfinite(thr0):
                cut = float(_prune_cut(np.float32(thr0), r.size))
                run_pos = _prefilter(
                    w, r, self.pre_lo, self.pre_hi, positions, positions is self.all_positions, cut
                )
            args = (*self._kernel_args(), run_pos, j0, cnt, kk_eff, self.block, np.float32(thr0))
            if self.parallel and spare_core():
                out_v, out_i = self._kernel(w, r, *args)
                thr_used = float(thr0)
            else:  # one thread (or no core spare): the chunks share their threshold
                out_v, out_i, thr_used = _shift_topk_shared(w, r, *args)
            ok = out_i.ravel() >= 0
            v = out_v.ravel()[ok].astype(np.float64)
            i = out_i.ravel()[ok]
            # Every candidate not kept scored above `excluded`: above the prune bound
            # (the last one, with shared thresholds), or dropped by a chunk whose heap
            # was full (so above its worst kept value).
            full = np.isfinite(out_v).sum(axis=1) == kk_eff
            excluded = float(thr_used)
            if full.any():
                excluded = min(excluded, float(out_v[full].max(axis=1).min()))
            if not np.isfinite(excluded):
                short = i[np.lexsort((i, v))]  # nothing was excluded: every scorable candidate
                break
            if v.size > kk_eff + 1:
                # only the kk_eff + 1 best (ties included) are read below: sort just those
                keep = v <= np.partition(v, kk_eff)[kk_eff]
                v, i = v[keep], i[keep]
            order = np.lexsort((i, v))
            v, i = v[order], i[order]
            if v.size > kk_eff:
                excluded = min(excluded, float(v[kk_eff]))
            short = i[:kk_eff]
            if v.size >= k:
                kth = float(v[k - 1])
                lo_ex = excluded - float(self._delta(excluded, heard, w64))
                if lo_ex > kth + float(self._delta(kth, heard, w64)):
                    break
                if self._screen_hopeless(kth, excluded, heard, w64):
                    self.exact_fallbacks += 1
                    exact = self._exact_window(heard, k, positions, j0, cnt)
                    short = exact.candidate_idx  # (the next packet's hint)
                    break
            if kk_eff >= n_total:
                # every candidate was scored and kept (``k`` is more than the grid or
                # the bounded window holds): ``short`` is all of them, best first
                break
            self.retries += 1
            kk *= 4
        hint = np.unique(short // (self.n_az * self.n_q))
        if slot is _LAST_CALL:
            self._hint = hint
        else:
            self._slot_hints[slot] = hint
        if exact is not None:
            return exact
        # its parallel kernel only with a spare core; chosen here rather than by
        # numba.set_num_threads, which would start numba's threading layer: once
        # started as OpenMP the process may not fork the filter's offline passes
        # (forked.numba_fork_safe)
        mse = exact_mse_db2(self.space, heard, short, parallel=spare_core())
        return select_topk(short, mse, k)

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        """Top-k candidates of one packet over the full grid (best first)."""
        return self._run(heard, k, self.all_positions, 0, self.n_az)

    def score_heard_slot(self, heard: HeardRss, k: int, slot: Hashable) -> TopK:
        """:meth:`score_heard` with the threshold hint of ``slot`` instead of the
        last call's: a caller that alternates between several recurring searches
        (the particle filter's re-entry searches the grid at several power
        offsets, each recurring every few re-entries) gives each its own key, so
        each starts from the shortlist positions of its own previous search
        rather than from another offset's. Only speed depends on ``slot``, never
        the result."""
        return self._run(heard, k, self.all_positions, 0, self.n_az, slot)

    def score_heard_many(
        self, heards: Sequence[HeardRss], k: int, slots: Sequence[Hashable]
    ) -> list[TopK]:
        """:meth:`score_heard_slot` of each ``heards[i]`` with ``slots[i]``, run
        concurrently on up to :func:`threads` Python threads when this scorer is
        single-threaded and a core is spare (:func:`spare_core`; the compiled
        search releases the GIL): independent searches of a few milliseconds
        each use both cores without a parallel region's per-call
        synchronisation. The same results as one by one."""
        n_threads = min(len(heards), threads())
        if self.parallel or n_threads < 2 or not spare_core():
            return [self.score_heard_slot(h, k, s) for h, s in zip(heards, slots, strict=True)]
        pool = thread_pool(n_threads)
        futures = [
            pool.submit(self.score_heard_slot, h, k, s) for h, s in zip(heards, slots, strict=True)
        ]
        return [f.result() for f in futures]

    def score_window(
        self,
        heard: HeardRss,
        k: int,
        positions: np.ndarray,
        azimuth_lo_deg: float,
        azimuth_span_deg: float,
    ) -> TopK:
        """Top-k among ``positions`` × a window of candidate azimuths (wrapping).

        The window is the first grid azimuth at or after ``lo`` and the next
        ``floor(span / step)`` ones. With ``lo`` on the grid that is ``[lo, lo +
        span]``; with ``lo`` off it, the last may lie up to one step past ``lo +
        span`` (``lo`` 355°, ``span`` 10°, step 10°: 0° and 10°). The paper's
        rotation windows use this, and their outputs are pinned
        (``tests/test_method_registry.py``).

        Parameters
        ----------
        positions
            Position indices to score.
        azimuth_lo_deg, azimuth_span_deg
            The azimuth window's start and width, degrees (width ≥ 360: all).
        """
        step = 360.0 / self.n_az
        if azimuth_span_deg >= 360.0 - 1e-9:
            j0, cnt = 0, self.n_az
        else:
            j0 = math.ceil((azimuth_lo_deg % 360.0) / step - 1e-9) % self.n_az
            cnt = min(self.n_az, math.floor(azimuth_span_deg / step + 1e-9) + 1)
        pos = np.ascontiguousarray(np.unique(np.asarray(positions, np.int64)))
        if pos.size == 0:
            return TopK(np.empty(0, np.int64), np.empty(0))
        return self._run(heard, k, pos, j0, cnt)

    def position_mse_db2(self, heard: HeardRss, chunk_positions: int = 8192) -> np.ndarray:
        """Per position, the MSE minimised over every candidate orientation ``(n_pos,)``,
        dB² (inf where excluded) — for maps, not the hot path (vectorised numpy
        over the same tables, float32)."""
        r = heard.receiver_index
        w = (heard.rss_dbm - self.centre_db[r]).astype(np.float32)
        out = np.full(self.space.n_positions, np.inf)
        js = self.m * np.arange(self.n_az)
        for start in range(0, self.space.n_positions, chunk_positions):
            p = np.arange(start, min(start + chunk_positions, self.space.n_positions))
            best = np.full(p.size, np.inf, dtype=np.float32)
            for q in range(self.n_q):
                acc = np.zeros((p.size, self.n_az), dtype=np.float32)
                for wq, rq in zip(w, r, strict=True):
                    idx = self.off[rq, p][:, None] + js[None, :]
                    t = (self.row0[rq, p] + q * self.rows_per_q)[:, None]
                    g = self.roww[rq, p][:, None]
                    a = self.rows[t, idx]
                    dl = self.drows[t, idx]
                    if np.any(g != 0):
                        t1 = np.minimum(t + 1, self.rows.shape[0] - 1)
                        a = (1 - g) * a + g * self.rows[t1, idx]
                        dl = (1 - g) * dl + g * self.drows[t1, idx]
                    d = (wq - self.base[rq, p])[:, None] - a - self.frac[rq, p][:, None] * dl
                    acc += d * d
                best = np.minimum(best, acc.min(axis=1))
            out[p] = best / r.size
        out[~np.all(np.isfinite(self.base[r]), axis=0)] = np.inf
        return out

    def with_parallel(
        self, parallel: bool, oversample: int | None = None, borrow_hints: bool | None = None
    ) -> ShiftScorer:
        """The same scorer on numba's threads or on one (and, if given, with
        another ``oversample`` and :attr:`borrow_hints`): the prepared tables are
        shared, not copied; its own hints start empty. Results do not depend on
        any of these."""
        twin = copy.copy(self)
        if oversample is not None:
            twin.oversample = int(oversample)
        if borrow_hints is not None:
            twin.borrow_hints = bool(borrow_hints)
        twin.parallel = bool(parallel)
        twin._kernel = _shift_topk if twin.parallel else _shift_topk_serial
        twin._hint = np.empty(0, np.int64)
        twin._slot_hints = {}
        return twin


_POOL: tuple[ThreadPoolExecutor, int, int] | None = None  # pool, its threads, its process


def thread_pool(n_threads: int) -> ThreadPoolExecutor:
    """The process's pool of Python threads for compiled work that releases the
    GIL (concurrent searches, the filter's particle halves): made on first use,
    remade larger if more threads are asked for, and remade in a forked child
    (whose copy of the parent's pool has no threads)."""
    global _POOL
    if _POOL is None or _POOL[1] < n_threads or _POOL[2] != os.getpid():
        pool = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="radiopose")
        _POOL = (pool, n_threads, os.getpid())
    return _POOL[0]


def drop_thread_pool() -> None:
    """Shut this process's thread pool down (its idle threads end; the next
    :func:`thread_pool` makes a new one): called before a fork
    (:mod:`radiopose.filtering.forked`), so that no Python thread of ours is
    alive while the process is copied."""
    global _POOL
    if _POOL is not None and _POOL[2] == os.getpid():
        _POOL[0].shutdown(wait=True)
    _POOL = None


_SPARE = [-math.inf, False]  # monotonic time of the last look at the load, and its answer
_CLAIMED = [0]  # cores taken by this process's forked workers (radiopose.filtering.forked)


def claim_core(n: int = 1) -> None:
    """Note that a forked worker of this process now runs on a core (``n`` = −1:
    it ended): :func:`spare_core` then answers no while the cores left are
    fewer than two, so that the parent's compiled work does not start a second
    thread that would wait for a core the worker holds. Only speed depends on
    it."""
    _CLAIMED[0] = max(0, _CLAIMED[0] + n)


def spare_core() -> bool:
    """Whether a second thread is worth starting for compiled work now: numba may
    use two or more threads (``NUMBA_NUM_THREADS``) and the other processes on
    this process's cores left at least :data:`SPARE_CORES_MIN` of them free since
    the last look (:func:`free_cores`; looked at most once a second). On a busy
    machine a parallel region's second thread waits for a core, and the first
    waits for it at the region's end: `full` streamed 190 packets/s beside one
    busy process on 2 cores with two threads and 450 with one
    (docs/performance.md, "A spare core, measured"). Results never depend on it.
    No while this process's forked workers (:func:`claim_core`) leave fewer than
    two of numba's threads' cores."""
    now = time.monotonic()
    if now - _SPARE[0] >= 1.0:
        free = free_cores()
        _SPARE[0], _SPARE[1] = now, threads() > 1 and free >= SPARE_CORES_MIN
    return bool(_SPARE[1]) and threads() - _CLAIMED[0] > 1


SPARE_CORES_MIN = 1.5
"""Cores of this process's affinity that the other processes must leave free for
:func:`spare_core` to answer yes: this process's own thread and most of another
core."""

_STAT_SAMPLE: list[tuple[float, float, float] | None] = [None]  # the last cpu_sample()


def busy_cpu_s(stat_text: str, cpus: set[int], clock_ticks_per_s: float) -> float:
    """CPU seconds that the processors ``cpus`` have spent busy since boot, from
    the text of Linux's ``/proc/stat``: per ``cpuN`` line, every column but idle
    and iowait (user, nice, system, irq, softirq, steal; guest time is counted
    in user), in clock ticks. Raises :class:`ValueError` for a malformed line or
    when none of ``cpus`` is listed."""
    busy, seen = 0, 0
    for line in stat_text.splitlines():
        name, _, rest = line.partition(" ")
        if not name.startswith("cpu") or name == "cpu":
            continue
        if int(name[3:]) not in cpus:
            continue
        ticks = [int(x) for x in rest.split()[:8]]
        if len(ticks) < 5:
            raise ValueError(f"/proc/stat: {name} has {len(ticks)} columns, not 5 or more")
        busy += sum(ticks) - ticks[3] - ticks[4]
        seen += 1
    if not seen:
        raise ValueError("/proc/stat lists none of this process's processors")
    return busy / clock_ticks_per_s


def cpu_sample() -> tuple[float, float, float] | None:
    """``(monotonic s, busy CPU s of this process's processors, this process's
    CPU s)`` now, or ``None`` where Linux's ``/proc/stat`` cannot be read."""
    try:
        cpus = os.sched_getaffinity(0)
        with open("/proc/stat", encoding="ascii") as f:
            text = f.read()
        busy = busy_cpu_s(text, cpus, float(os.sysconf("SC_CLK_TCK")))
    except (AttributeError, OSError, ValueError):
        return None
    return time.monotonic(), busy, time.process_time()


def free_cores() -> float:
    """Cores of this process's affinity not used by other processes (forked
    workers of this one included) since the last call, averaged over that
    interval: their number minus (the processors' busy CPU seconds minus this
    process's own) per second. Where ``/proc/stat`` cannot be read, or the last
    call was less than 0.2 s ago (or there was none), the 1-minute load average
    stands in: cores minus the load plus one (the load counts this process's
    own running thread)."""
    sample, last = cpu_sample(), _STAT_SAMPLE[0]
    cores = available_cores()
    if sample is not None and last is not None and sample[0] - last[0] >= 0.2:
        _STAT_SAMPLE[0] = sample
        others = ((sample[1] - last[1]) - (sample[2] - last[2])) / (sample[0] - last[0])
        return cores - max(others, 0.0)
    if last is None:
        _STAT_SAMPLE[0] = sample
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        load = 0.0
    return cores - load + 1.0


_STAT_SAMPLE[0] = cpu_sample()  # the first look's interval starts at import


def threads() -> int:
    """Threads numba uses (``NUMBA_NUM_THREADS``, default: all cores)."""
    return int(os.environ.get("NUMBA_NUM_THREADS", numba.config.NUMBA_NUM_THREADS))


@contextlib.contextmanager
def spare_core_threads() -> Iterator[None]:
    """numba's parallel kernels (``parallel=True``) called inside the block run on
    all of numba's threads when a core is spare (:func:`spare_core`) and on one
    otherwise, for the reason given there; the calling thread's setting is
    restored afterwards. Results never depend on it (a parallel kernel's rows are
    each one thread's)."""
    before = numba.get_num_threads()
    if before == 1 or spare_core():
        yield
        return
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)
