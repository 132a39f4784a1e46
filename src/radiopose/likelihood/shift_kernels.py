"""The numba kernels behind :class:`~radiopose.likelihood.compiled.ShiftScorer`.

Split from :mod:`radiopose.likelihood.compiled` the way scipy keeps its
rotation kernels apart from the class that prepares and calls them: this
module holds only compiled functions over plain arrays (no site, pattern or
packet objects); :mod:`~radiopose.likelihood.compiled` builds their tables,
chooses thresholds and slots, and rescores the screened candidates exactly.
Its module docstring derives the arithmetic (circular-shift reads, the float32
screen and its bound, the fused top-k).

* :func:`shift_topk` / :func:`shift_topk_serial`: the screen over fixed chunks
  of positions (parallel / one thread), each chunk keeping its ``k'`` best in a
  bounded heap with a running threshold.
* :func:`dense_topk`: one threshold pass scored densely (small passes).
* :func:`prefilter`: a lower bound per position that drops positions whose
  every azimuth is already worse than the threshold.
* :func:`prune_cut`: the threshold with its relative and absolute slack.

Results do not depend on the number of threads: chunks are fixed and merged in
order.
"""

from __future__ import annotations

import numba
import numpy as np

N_CHUNKS = 64
"""Fixed number of position chunks (independent of the thread count)."""


@numba.njit(cache=True, boundscheck=False)
def _worse(va, ia, vb, ib):  # pragma: no cover - compiled
    """(va, ia) ranks after (vb, ib): larger value, ties by larger index."""
    return va > vb or (va == vb and ia > ib)


@numba.njit(cache=True, boundscheck=False)
def _heap_push(hv, hi, count, val, idx):  # pragma: no cover - compiled
    """Max-heap on (value, index) of capacity len(hv): keep the kk best; returns count.

    The root ``hv[0]`` is the worst kept once the heap is full.
    """
    kk = hv.shape[0]
    if count < kk:  # sift up
        pos = count
        count += 1
        while pos > 0:
            parent = (pos - 1) >> 1
            if _worse(val, idx, hv[parent], hi[parent]):
                hv[pos] = hv[parent]
                hi[pos] = hi[parent]
                pos = parent
            else:
                break
        hv[pos] = val
        hi[pos] = idx
        return count
    if not _worse(hv[0], hi[0], val, idx):
        return count
    pos = 0  # replace the root, sift down
    while True:
        child = 2 * pos + 1
        if child >= kk:
            break
        if child + 1 < kk and _worse(hv[child + 1], hi[child + 1], hv[child], hi[child]):
            child += 1
        if _worse(hv[child], hi[child], val, idx):
            hv[pos] = hv[child]
            hi[pos] = hi[child]
            pos = child
        else:
            break
    hv[pos] = val
    hi[pos] = idx
    return count


_FAST = {"contract", "reassoc", "nsz", "arcp"}  # no nnan/ninf: +inf marks empty slots
_PRUNE_REL = np.float32(1e-4)
"""Relative slack of the block lower bound against float32 rounding."""
_PRUNE_ABS = np.float32(1e-6)


@numba.njit(cache=True, boundscheck=False, inline="always")
def prune_cut(thr, h):  # pragma: no cover - compiled
    """Bound on ``Σ_r d_r²`` beyond which a position or block is skipped, for
    the threshold ``thr`` (mean squared error) over ``h`` receivers; used by the
    kernel and by the prefilter alike, so both cut at exactly the same value."""
    return (thr * (np.float32(1.0) + _PRUNE_REL) + _PRUNE_ABS) * h


@numba.njit(cache=True, inline="always")
def _position_buffers(h):  # pragma: no cover - compiled
    """Per-receiver buffers ``e, k, f, t, g`` filled by :func:`_load_position`."""
    return (
        np.empty(h, np.float32),
        np.empty(h, np.int64),
        np.empty(h, np.float32),
        np.empty(h, np.int64),
        np.empty(h, np.float32),
    )


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, inline="always")
def _load_position(w, heard, posf, posi, m, p, j0, e, k, f, t, g):
    """Per-receiver terms of position ``p`` into ``e, k, f, t, g``; False if excluded.

    ``posf[p, r] = (B, f, row weight)`` and ``posi[p, r] = (o, first row)`` are
    position-major, so one position's terms for every receiver share a cache line
    or two, where receiver-major tables cost one cache miss per receiver and field
    on the sparse positions that survive the prefilter.
    """  # pragma: no cover - compiled
    for q in range(heard.shape[0]):
        r = heard[q]
        b = posf[p, r, 0]
        if np.isnan(b):
            return False
        e[q] = w[q] - b
        k[q] = posi[p, r, 0] + m * j0
        f[q] = posf[p, r, 1]
        t[q] = posi[p, r, 1]
        g[q] = posf[p, r, 2]
    return True


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, inline="always")
def _block_bounds(e, k, t, g, toff, blo, bhi, blo2, bhi2, nbw, lb):
    """Lower bounds ``lb[b]`` on Σ_r d_r² over each block ``b`` of the window.

    Every looked-up directivity in a block lies between the minimum and maximum
    of the pattern samples the block blends, so ``|d_r|`` is at least the
    distance of ``e_r`` from that interval.
    """  # pragma: no cover - compiled
    for b in range(nbw):
        lb[b] = 0.0
    for q in range(e.shape[0]):
        tq = t[q] + toff
        if g[q] == 0.0:
            lo = blo[tq, k[q]]
            hi = bhi[tq, k[q]]
        else:
            lo = blo2[tq, k[q]]
            hi = bhi2[tq, k[q]]
        eq = e[q]
        for b in range(nbw):
            x = max(lo[b] - eq, np.float32(0.0)) + max(eq - hi[b], np.float32(0.0))
            lb[b] += x * x


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, inline="always")
def _accumulate(acc, e, k, f, t, g, toff, rows, drows, m, b0, nb):  # pragma: no cover - compiled
    """``acc[jj] = Σ_q d_q²`` for the ``nb`` window azimuths from ``b0`` of one position,
    with the residual ``d = e − (a_j + f·Δ_j)`` (the bilinear lookup at ``φ − α_j``)."""
    for q in range(e.shape[0]):
        eq = e[q]
        o = k[q] + m * b0
        fq = f[q]
        gq = g[q]
        tq = t[q] + toff
        if gq == 0.0 and m == 1:
            ra = rows[tq]  # 1-D, C-contiguous: slices stay contiguous (SIMD)
            rd = drows[tq]
            sa = ra[o : o + nb]
            sd = rd[o : o + nb]
            if q == 0:
                for jj in range(nb):
                    d = eq - sa[jj] - fq * sd[jj]
                    acc[jj] = d * d
            else:
                for jj in range(nb):
                    d = eq - sa[jj] - fq * sd[jj]
                    acc[jj] += d * d
        else:
            g1 = np.float32(1.0) - gq
            t1 = tq + 1 if gq != 0.0 else tq
            for jj in range(nb):
                k1 = o + m * jj
                a = g1 * rows[tq, k1] + gq * rows[t1, k1]
                dl = g1 * drows[tq, k1] + gq * drows[t1, k1]
                d = eq - a - fq * dl
                if q == 0:
                    acc[jj] = d * d
                else:
                    acc[jj] += d * d


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, nogil=True)
def dense_topk(
    w,
    heard,
    posf,
    posi,
    rows,
    drows,
    blo,
    bhi,
    blo2,
    bhi2,
    rmin,
    rmax,
    m,
    n_az,
    n_q,
    rows_per_q,
    positions,
    j0,
    cnt,
):  # pragma: no cover - compiled
    """Every screened MSE of ``positions`` × (pitch, roll) × window azimuths, flat
    float32 (``+inf`` for excluded positions); the kernel's values, without top-k —
    for the threshold pass over a few positions. Arguments: those of :func:`_chunk`
    from ``w`` to ``rows_per_q`` (the bound tables unused), then ``positions, j0, cnt``."""
    h = heard.shape[0]
    inv_h = np.float32(1.0 / h)
    out = np.full(positions.shape[0] * n_q * cnt, np.inf, dtype=np.float32)
    acc = np.empty(cnt, dtype=np.float32)
    e, k, f, t, g = _position_buffers(h)
    for pi in range(positions.shape[0]):
        if not _load_position(w, heard, posf, posi, m, positions[pi], j0, e, k, f, t, g):
            continue
        for qq in range(n_q):
            _accumulate(acc, e, k, f, t, g, qq * rows_per_q, rows, drows, m, 0, cnt)
            at = (pi * n_q + qq) * cnt
            for jj in range(cnt):
                out[at + jj] = acc[jj] * inv_h
    return out


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False)
def _chunk(
    c,  # int  chunk index
    out_v,  # (N_CHUNKS, kk) float32  heaps' values (per chunk)
    out_i,  # (N_CHUNKS, kk) int64  heaps' candidate indices
    w,  # (h,) float32  RSS − centre of the heard receivers
    heard,  # (h,) int64   their receiver indices
    posf,  # (n_pos, n_rx, 3) float32  B = M + P_tx − centre (NaN: excluded), f, row weight
    posi,  # (n_pos, n_rx, 2) int32  o in [1, n], first pattern row
    rows,  # (n_rows, L) float32  reversed, repeated pattern rows  Rv[k]
    drows,  # (n_rows, L) float32  Rv[k − 1] − Rv[k]
    blo,
    bhi,
    blo2,
    bhi2,  # (n_rows, K, n_blocks) float32  block bounds (single, pair)
    rmin,
    rmax,  # (n_rows,) float32  row min / max (over rows t and t + 1 where blended)
    m,  # int  pattern samples per candidate azimuth step
    n_az,  # int  candidate azimuths
    n_q,  # int  (pitch, roll) combinations; orientation index = q·n_az + j
    rows_per_q,  # int  pattern rows of each combination
    positions,  # (n_p,) int64  positions to score
    j0,  # int  first azimuth index of the window
    cnt,  # int  window length (<= n_az)
    kk,  # int  heap size per chunk
    blk,  # int  block length (candidate azimuths) for pruning
    thr0,  # float32  prune bound: candidates above it are not wanted (inf: none)
):  # pragma: no cover - compiled
    """Score chunk ``c`` of ``positions`` into its heap ``out_v[c], out_i[c]``."""
    n_p = positions.shape[0]
    h = heard.shape[0]
    inv_h = np.float32(1.0 / h)
    nbw = (cnt + blk - 1) // blk
    acc = np.empty(cnt, dtype=np.float32)
    e, k, f, t, g = _position_buffers(h)
    lb = np.empty(nbw, np.float32)
    bv = out_v[c]
    bi = out_i[c]
    count = 0
    for pi in range((n_p * c) // N_CHUNKS, (n_p * (c + 1)) // N_CHUNKS):
        p = positions[pi]
        if not _load_position(w, heard, posf, posi, m, p, j0, e, k, f, t, g):
            continue
        for qq in range(n_q):
            toff = qq * rows_per_q
            thr = thr0
            if count == kk and bv[0] < thr:
                thr = bv[0]
            prune = thr < np.inf
            cut = prune_cut(thr, h)
            if prune:
                # whole-position bound first (row extremes), then per block
                lb0 = np.float32(0.0)
                for q in range(h):
                    x = max(rmin[t[q] + toff] - e[q], np.float32(0.0)) + max(
                        e[q] - rmax[t[q] + toff], np.float32(0.0)
                    )
                    lb0 += x * x
                if lb0 > cut:
                    continue
                _block_bounds(e, k, t, g, toff, blo, bhi, blo2, bhi2, nbw, lb)
            b = 0
            while b < nbw:
                # one contiguous run of surviving blocks at a time (long SIMD loops)
                if prune and lb[b] > cut:
                    b += 1
                    continue
                be = b + 1
                while be < nbw and not (prune and lb[be] > cut):
                    be += 1
                b0 = b * blk
                nb = min(be * blk, cnt) - b0
                b = be
                _accumulate(acc, e, k, f, t, g, toff, rows, drows, m, b0, nb)
                # fused top-k: a vectorised minimum first; the scalar pass only
                # when something in the block can enter the heap
                lim = thr0
                if count == kk and bv[0] < lim:
                    lim = bv[0]
                mn = acc[0]
                for jj in range(1, nb):
                    mn = min(mn, acc[jj])
                if mn * inv_h > lim:
                    continue
                for jj in range(nb):
                    v = acc[jj] * inv_h
                    if v > thr0:
                        continue
                    if count < kk or v <= bv[0]:
                        j = j0 + b0 + jj
                        if j >= n_az:
                            j -= n_az
                        count = _heap_push(bv, bi, count, v, (p * n_q + qq) * n_az + j)


_KK_ARG = 19
"""Position of ``kk`` among the kernel's arguments (those of :func:`_chunk` after ``c,
out_v, out_i``)."""


@numba.njit(parallel=True, cache=True, fastmath=_FAST, boundscheck=False)
def shift_topk(*args):  # pragma: no cover - compiled
    """The ``kk`` best screened candidates of every chunk, ``(out_v, out_i)`` each
    ``(N_CHUNKS, kk)``; chunks in parallel. Arguments: those of :func:`_chunk`
    after ``c, out_v, out_i``."""
    kk = args[_KK_ARG]
    out_v = np.full((N_CHUNKS, kk), np.inf, dtype=np.float32)
    out_i = np.full((N_CHUNKS, kk), -1, dtype=np.int64)
    for c in numba.prange(N_CHUNKS):
        _chunk(c, out_v, out_i, *args)
    return out_v, out_i


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, nogil=True)
def shift_topk_serial(*args):  # pragma: no cover - compiled
    """:func:`shift_topk` (same arguments) on one thread: no parallel start-up;
    it releases the GIL, so independent searches can run on Python threads
    (:meth:`ShiftScorer.score_heard_many`)."""
    kk = args[_KK_ARG]
    out_v = np.full((N_CHUNKS, kk), np.inf, dtype=np.float32)
    out_i = np.full((N_CHUNKS, kk), -1, dtype=np.int64)
    for c in range(N_CHUNKS):
        _chunk(c, out_v, out_i, *args)
    return out_v, out_i


@numba.njit(cache=True, boundscheck=False, nogil=True)
def prefilter(w, heard, pre_lo, pre_hi, positions, every, cut):  # pragma: no cover - compiled
    """Positions whose whole-row lower bound ``Σ_r dist(w_r, [LO_rp, HI_rp])²``
    is within ``cut`` (the same bound the main kernel applies first, evaluated
    in float64 over contiguous arrays so that it vectorises).

    ``LO_rp``/``HI_rp`` are ``B_r(p)`` plus the minimum/maximum of every pattern
    row position ``p`` can blend toward receiver ``r`` (``+inf``/``−inf`` where
    ``p`` is excluded, so it never survives). ``every``: ``positions`` is
    ``0 … n_pos − 1``.
    """
    n_p = positions.shape[0]
    lb = np.zeros(n_p, dtype=np.float64)
    for q in range(heard.shape[0]):
        r = heard[q]
        wq = np.float64(w[q])
        lo = pre_lo[r]
        hi = pre_hi[r]
        if every:  # positions = 0 … n−1: contiguous reads (SIMD)
            for i in range(n_p):
                x = max(lo[i] - wq, 0.0) + max(wq - hi[i], 0.0)
                lb[i] += x * x
        else:
            for i in range(n_p):
                p = positions[i]
                x = max(lo[p] - wq, 0.0) + max(wq - hi[p], 0.0)
                lb[i] += x * x
    out = np.empty(n_p, dtype=np.int64)
    n = 0
    for i in range(n_p):
        if lb[i] <= cut:
            out[n] = positions[i]
            n += 1
    return out[:n]


@numba.njit(cache=True, fastmath=_FAST, boundscheck=False, nogil=True)
def shift_topk_shared(  # pragma: no cover - compiled
    w, heard, posf, posi, rows, drows, blo, bhi, blo2, bhi2, rmin, rmax,
    m, n_az, n_q, rows_per_q, positions, j0, cnt, kk, blk, thr0,
):  # fmt: skip
    """:func:`shift_topk_serial` (same arguments) with a threshold shared by the
    chunks: after each chunk the ``kk``-th best value kept so far by all chunks
    (once ``kk`` are kept) lowers the prune bound of the chunks after it, so a
    chunk need not fill its own heap with candidates the earlier chunks already
    beat. Returns ``(out_v, out_i, thr)``, ``thr`` the last (smallest) bound
    used: every candidate not kept scored above ``thr`` or above the worst of a
    full heap, as with ``thr0`` in :func:`shift_topk_serial`, so the caller's
    exactness check reads ``thr`` instead of ``thr0``. Every candidate better
    than ``thr`` is kept, so the screened best ``kk`` are
    :func:`shift_topk_serial`'s up to float32 rounding (where a run of
    surviving blocks splits into SIMD body and tail depends on the bound, as
    it does with any other ``thr0``); the caller's exact rescoring and
    exactness check make the top-k the same."""
    out_v = np.full((N_CHUNKS, kk), np.inf, dtype=np.float32)
    out_i = np.full((N_CHUNKS, kk), -1, dtype=np.int64)
    gv = np.full(kk, np.inf, dtype=np.float32)  # max-heap: the kk best so far
    gi = np.full(kk, -1, dtype=np.int64)
    gcount = 0
    thr = thr0
    for c in range(N_CHUNKS):
        _chunk(
            c, out_v, out_i, w, heard, posf, posi, rows, drows, blo, bhi, blo2, bhi2,
            rmin, rmax, m, n_az, n_q, rows_per_q, positions, j0, cnt, kk, blk, thr,
        )  # fmt: skip
        for j in range(kk):
            v = out_v[c, j]
            if v < np.inf and (gcount < kk or v <= gv[0]):
                gcount = _heap_push(gv, gi, gcount, v, out_i[c, j])
        if gcount == kk and gv[0] < thr:
            thr = gv[0]
    return out_v, out_i, thr
