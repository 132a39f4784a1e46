"""The exact expected RSS and MSE of listed candidates, compiled (float64, per element).

Paper, "Enhanced Localisation Pipeline", step 1. For candidate ``(p, o)`` and
receiver ``r``::

    d = r − p                      (world, metres)
    v = Rᵀ d                       (body frame; R = body-to-world matrix of o)
    φ = atan2(v_y, v_x) mod 360,  θ = arccos(v_z / |v|)    (degrees; (0, 90) if v = 0)
    RSS_r = M_r(p) + P_tx + D(φ, θ)                          (dBm)

with ``D`` the pattern's bilinear lookup (periodic in azimuth, polar clamped;
a slice is used for every polar angle) — the same conventions as
:func:`radiopose.geometry.direction_to_pattern_angles_deg` and
:meth:`radiopose.patterns.pattern.Pattern.lookup_dbi`, written out for one
element at a time. ``tests/test_likelihood.py`` checks it against those numpy
functions.

This is *the* exact value: the reference scorer and the final rescoring of
every fast scorer call these functions, so their MSEs agree bit for bit (each
element is computed on its own, in the same order, without fast-math, so the
value does not depend on the batch it is computed in or on threads).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

PARALLEL_MIN_CANDIDATES = 20_000
"""From this many candidates per call the loop runs on numba's threads."""


@numba.njit(cache=True, inline="always")
def _wrap360(a: float) -> float:  # pragma: no cover - compiled
    """``a mod 360`` in ``[0, 360)`` (as :func:`radiopose.units.wrap_deg`)."""
    a = a % 360.0
    return 0.0 if a >= 360.0 else a


@numba.njit(cache=True, inline="always")
def _rss_one(c, r, pos, rot, rx, chan, tx, d, az0, az_step, polar_step):  # pragma: no cover
    """Expected RSS (dBm) of candidate ``c`` at receiver ``r``; the arguments after
    ``r`` are :func:`_space_args`."""
    n_orient = rot.shape[0]
    p = c // n_orient
    o = c % n_orient
    m = chan[r, p]
    if math.isnan(m):
        return math.nan
    dx = rx[r, 0] - pos[p, 0]
    dy = rx[r, 1] - pos[p, 1]
    dz = rx[r, 2] - pos[p, 2]
    vx = dx * rot[o, 0, 0] + dy * rot[o, 1, 0] + dz * rot[o, 2, 0]
    vy = dx * rot[o, 0, 1] + dy * rot[o, 1, 1] + dz * rot[o, 2, 1]
    vz = dx * rot[o, 0, 2] + dy * rot[o, 1, 2] + dz * rot[o, 2, 2]
    norm = math.sqrt(vx * vx + vy * vy + vz * vz)
    if norm > 0.0:
        phi = _wrap360(math.atan2(vy, vx) * (180.0 / math.pi))
        cos_t = min(max(vz / norm, -1.0), 1.0)
        theta = math.acos(cos_t) * (180.0 / math.pi)
    else:
        phi = 0.0
        theta = 90.0
    n_az = d.shape[0]
    n_pol = d.shape[1]
    u = _wrap360(phi - az0) / az_step
    w = 0.0 if n_pol == 1 else min(max(theta, 0.0), 180.0) / polar_step
    fi0 = math.floor(u)
    fu = u - fi0
    i0 = int(fi0) % n_az
    i1 = (i0 + 1) % n_az
    j0 = min(int(w), n_pol - 1)  # w >= 0: truncation is the floor
    fw = w - j0
    j1 = min(j0 + 1, n_pol - 1)
    top = d[i0, j0] * (1.0 - fu) + d[i1, j0] * fu
    bot = d[i0, j1] * (1.0 - fu) + d[i1, j1] * fu
    return m + tx + (top * (1.0 - fw) + bot * fw)


@numba.njit(cache=True)
def _expected(cand, *sp):  # pragma: no cover - compiled
    """Expected RSS ``(n, n_rx)`` of every candidate at every receiver."""
    pos, rot, rx, chan, tx, d, az0, az_step, polar_step = sp
    n_rx = rx.shape[0]
    out = np.empty((cand.shape[0], n_rx))
    for i in range(cand.shape[0]):
        for r in range(n_rx):
            out[i, r] = _rss_one(cand[i], r, pos, rot, rx, chan, tx, d, az0, az_step, polar_step)
    return out


@numba.njit(cache=True)
def _mse_one(i, cand, heard, rss, *sp):  # pragma: no cover - compiled
    """MSE of candidate ``cand[i]`` over the heard receivers (in their order)."""
    pos, rot, rx, chan, tx, d, az0, az_step, polar_step = sp
    acc = 0.0
    for q in range(heard.shape[0]):
        e = _rss_one(cand[i], heard[q], pos, rot, rx, chan, tx, d, az0, az_step, polar_step)
        diff = rss[q] - e
        acc += diff * diff
    return acc / heard.shape[0]


@numba.njit(cache=True)
def _mse_serial(cand, heard, rss, *sp):  # pragma: no cover - compiled
    """:func:`_mse_one` of every candidate; ``sp``: :func:`_space_args`."""
    out = np.empty(cand.shape[0])
    for i in range(cand.shape[0]):
        out[i] = _mse_one(i, cand, heard, rss, *sp)
    return out


@numba.njit(cache=True, parallel=True)
def _mse_parallel(cand, heard, rss, *sp):  # pragma: no cover - compiled
    """:func:`_mse_serial` on numba's threads."""
    out = np.empty(cand.shape[0])
    for i in numba.prange(cand.shape[0]):
        out[i] = _mse_one(i, cand, heard, rss, *sp)
    return out


def _space_args(space) -> tuple:
    pat = space.pattern
    return (
        space.positions_m,
        space.rotations,
        space.receiver_positions_m,
        space.channel_db,
        float(space.tx_power_dbm),
        pat.directivity_dbi,
        float(pat.azimuth_deg[0]),
        float(pat.azimuth_step_deg),
        float(pat.polar_step_deg) if not pat.is_slice else 1.0,
    )


def _candidates(space, candidate_idx: NDArray) -> NDArray[np.int64]:
    """Candidate indices as a flat int64 array, checked: the compiled loops do not
    check bounds, so an index outside ``[0, n_candidates)`` is an ``IndexError`` here."""
    cand = np.ascontiguousarray(np.asarray(candidate_idx, dtype=np.int64).reshape(-1))
    n = space.n_positions * space.n_orientations
    if cand.size and (int(cand.min()) < 0 or int(cand.max()) >= n):
        raise IndexError(f"candidate index outside [0, {n})")
    return cand


def expected_rss_all_dbm(space, candidate_idx: NDArray) -> NDArray[np.float64]:
    """Expected RSS ``(n, n_rx)`` dBm of candidates (NaN where ``M_r(p)`` is NaN)."""
    return _expected(_candidates(space, candidate_idx), *_space_args(space))


_SERIAL_ONLY = [False]


def serial_only() -> None:
    """From now on this process computes :func:`mse_db2` on one thread (the same
    values: each candidate's MSE is independent). Called first in a child forked
    by :mod:`radiopose.filtering.forked`: numba terminates a child that enters
    a parallel region after its parent launched GNU OpenMP ("fork() called
    from a process already using GNU OpenMP")."""
    _SERIAL_ONLY[0] = True


def mse_db2(
    space,
    receiver_index: NDArray,
    rss_dbm: NDArray,
    candidate_idx: NDArray,
    parallel: bool = True,
) -> NDArray:
    """Exact MSE ``(n,)`` dB² of candidates over the heard receivers.

    ``(1/h) Σ_q (rss_q − RSS_{r_q})²``, summed in the order of ``receiver_index``
    (NaN where a heard receiver's ``M_r(p)`` is NaN). On numba's threads for
    :data:`PARALLEL_MIN_CANDIDATES` or more candidates, unless ``parallel`` is
    false or :func:`serial_only` was called (the same values either way).
    """
    cand = _candidates(space, candidate_idx)
    parallel = parallel and cand.size >= PARALLEL_MIN_CANDIDATES and not _SERIAL_ONLY[0]
    fn = _mse_parallel if parallel else _mse_serial
    return fn(
        cand,
        np.ascontiguousarray(receiver_index, dtype=np.int64),
        np.ascontiguousarray(rss_dbm, dtype=np.float64),
        *_space_args(space),
    )
