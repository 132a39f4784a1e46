"""Offline: batch MAP refinement of 2-D tracks as the arbiter between candidates.

Beyond the paper (issue 15, wrong locks; docs/filter.md, "Accuracy round 6").
Round 5's combination of the forward and the time-reversed passes scored each
candidate track by the per-packet likelihood of its smoothed means: a track
sitting in a self-consistent wrong (pose, offset) mode is not penalised, a
right one with 0.4 m of smoothing error is. Here each candidate is first taken
to its own optimum of one objective, and the lowest optimum wins:

    Σ_packets Σ_heard ρ((rss − E(pose_i) − b) / σ)                  (data)
  + Σ motion-prior residuals² + (b / s_b)²                          (priors)

* ``E`` is the 2-D filter's own expected RSS (:meth:`FilterModel.expected`);
  ``ρ`` is ``soft_l1`` with scale ``robust_scale`` (σ units); σ is the
  forward filter's estimate, the same for every candidate.
* Variables: x, y (m) and azimuth (rad) per packet and the one device offset
  ``b`` (dB); height, pitch and roll stay at the candidate's values (a 2-D
  site has one of each).
* The motion prior is the filter's process model: a velocity change between
  consecutive intervals of x, y over ``accel_noise_mps2·√((dt₁ + dt₂)/3)``,
  of the (wrapped) azimuth over ``angular_accel_noise_dps2·√(…)`` (or
  ``refine_angular_accel_noise_dps2`` when set).
* Solved by :func:`radiopose.filtering.refine3d._levenberg_marquardt`
  (projected Levenberg–Marquardt, IRLS for ``ρ``, sparse normal equations;
  with ``FilterConfig.refine_banded`` the same iteration solves them in band
  form, :func:`_banded_levenberg_marquardt`);
  the data Jacobian by central differences (6 model evaluations), the prior's
  constant; x, y bounded by the survey map.

:func:`arbitrate` splits the packets into tracks (silences longer than
``reacquire_gap_s``), refines every candidate covering a track, and emits the
refined poses of the candidate with the lowest objective.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
import scipy.sparse as sp

from radiopose.errors import InputError
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import FilterConfig, FilterEstimate
from radiopose.filtering.forked import map_forked
from radiopose.filtering.model import FilterModel
from radiopose.filtering.refine3d import (
    _FD_STEP,
    _MIN_DT_S,
    _levenberg_marquardt,
    _wrap,
    checked_track,
    damped_least_squares,
    soft_l1_head,
)
from radiopose.filtering.reverse import pose_residuals_db, profile_offset
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray

_POSE = 3


@dataclass(frozen=True)
class Refined2d:
    """One refined candidate track (:func:`refine_track_2d`).

    Attributes
    ----------
    position_m
        ``(n, 3)`` positions, metres (height as given).
    orientation_deg
        ``(n, 3)`` azimuth in [0, 360), pitch and roll as given, degrees.
    offset_db
        The device offset, dB.
    cost
        The objective at the optimum (½ Σ ρ + ½ Σ prior²), σ² units.
    initial_cost
        The objective at the candidate as given (its best single offset).
    nfev
        Residual evaluations.
    log_volume
        ½ log det of the objective's Gauss–Newton Hessian ``JᵀWJ`` at the
        optimum (``W`` the robust loss's weights there), nats: the Laplace
        approximation's width term, so that ``cost + log_volume`` is −log of
        the candidate mode's posterior mass up to a constant shared by every
        candidate of the same track (``FilterConfig.arbiter_laplace``); ``nan``
        when not computed.
    """

    position_m: FloatArray
    orientation_deg: FloatArray
    offset_db: float
    cost: float
    initial_cost: float
    nfev: int
    log_volume: float = math.nan


def refine_track_2d(
    model: FilterModel,
    times_s: Sequence[float] | FloatArray,
    heard: Sequence[HeardRss],
    position_m: FloatArray,
    orientation_deg: FloatArray,
    sigma_db: float,
    config: FilterConfig,
    *,
    offset_db: float | None = None,
    robust_scale: float = 2.5,
    max_nfev: int = 30,
) -> Refined2d:
    """One 2-D track refined by batch MAP (module docstring).

    Parameters
    ----------
    model
        The 2-D filter's device model.
    times_s
        ``(n,)`` packet times, seconds, non-decreasing.
    heard
        The ``n`` packets' readings.
    position_m, orientation_deg
        ``(n, 3)`` the candidate track: metres; azimuth, pitch, roll degrees.
    sigma_db
        Reading noise σ, dB.
    config
        The filter's settings: motion noise densities, the offset prior's sd.
    offset_db
        Initial offset, dB; ``None``: the candidate's best single offset under
        the filter's mixture (:func:`radiopose.filtering.reverse.profile_offset`).
    robust_scale
        ``soft_l1`` scale of the data residuals, σ units.
    max_nfev
        Bound on the solver's residual evaluations.

    Raises
    ------
    InputError
        An empty track, arrays of different lengths, non-finite values, times
        going backwards, σ not positive.
    """
    t, pos, ori = checked_track("refine_track_2d", times_s, position_m, orientation_deg, heard)
    n = t.size
    if not (math.isfinite(sigma_db) and sigma_db > 0 and robust_scale > 0 and max_nfev >= 1):
        raise InputError(
            f"refine_track_2d: σ {sigma_db!r} dB and robust_scale must be positive, max_nfev >= 1"
        )
    pkt = np.concatenate([np.full(h.n_heard, i, dtype=np.int64) for i, h in enumerate(heard)])
    rx = np.concatenate([np.asarray(h.receiver_index, dtype=np.int64) for h in heard])
    rss = np.concatenate([np.asarray(h.rss_dbm, dtype=float) for h in heard])
    if rx.size == 0:
        raise InputError("refine_track_2d: no packet was heard by any receiver")
    if offset_db is None:
        res, _ = pose_residuals_db(model, list(heard), pos, ori)
        offset_db = profile_offset(
            res, sigma_db, config.outlier_probability, config.outlier_range_db
        )
    all_rx = np.unique(rx)
    col = np.zeros(int(all_rx.max()) + 1, dtype=np.int64)
    col[all_rx] = np.arange(all_rx.size)
    rcol = col[rx]
    m = rx.size
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.Z_M] = pos[:, 2]
    S[:, K.PITCH_RAD] = np.deg2rad(ori[:, 1])
    S[:, K.ROLL_RAD] = np.deg2rad(ori[:, 2])

    def expected(X: FloatArray) -> FloatArray:
        S[:, K.X_M] = X[:, 0]
        S[:, K.Y_M] = X[:, 1]
        S[:, K.AZIMUTH_RAD] = X[:, 2] % (2 * np.pi)
        return model.expected(S, all_rx)[pkt, rcol]

    # the motion prior's rows: ((x_{i+1} − x_i)/d2 − (x_i − x_{i−1})/d1) · w,
    # interior packets i = 1 … n − 2, one block of k rows per component
    dt = np.maximum(np.diff(t), _MIN_DT_S)
    q_az_dps2 = config.refine_angular_accel_noise_dps2 or config.angular_accel_noise_dps2
    qs = (config.accel_noise_mps2, config.accel_noise_mps2, math.radians(q_az_dps2))
    k = max(n - 2, 0)
    coef = np.zeros((3, k, 3))  # [component, row, (packet i + 1, i, i − 1)]
    w_az = np.zeros(0)
    if k:
        d1, d2 = dt[:-1], dt[1:]
        for comp, q in enumerate(qs):
            w_az = 1.0 / (q * np.sqrt((d1 + d2) / 3.0))  # the last: the azimuth's
            coef[comp] = np.column_stack([w_az / d2, -w_az / d2 - w_az / d1, w_az / d1])

    n_vars = _POSE * n + 1
    A = None
    if not config.refine_banded:  # the sparse rows, as before the banded solve
        i = np.arange(1, n - 1)
        rows = [c * k + np.arange(k) for c in range(3) for _ in range(3)]
        cols = [_POSE * j + c for c in range(3) for j in (i + 1, i, i - 1)]
        vals = [coef[c, :, a] for c in range(3) for a in range(3)]
        A = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 * k, n_vars),
        )

    def prior(x: FloatArray) -> FloatArray:
        if A is not None:
            out = np.asarray(A @ x)
        else:
            out = np.empty(3 * k)
            X = x[: _POSE * n].reshape(n, _POSE)
            for comp in range(2):  # as the CSR product sums the row: i + 1, i, i − 1
                c, v = coef[comp], X[:, comp]
                head = c[:, 0] * v[2:] + c[:, 1] * v[1:-1]
                out[comp * k : (comp + 1) * k] = head + c[:, 2] * v[:-2]
        if k:
            # azimuth first differences wrapped (the solver may cross ±π)
            d = _wrap(np.diff(x[2 : _POSE * n : _POSE]))
            out[2 * k :] = (d[1:] / dt[1:] - d[:-1] / dt[:-1]) * w_az
        return out

    sd_b = config.offset_prior_sd_db
    sig = float(sigma_db)
    c2 = float(robust_scale) ** 2

    def fun(x: FloatArray) -> FloatArray:
        X = x[: _POSE * n].reshape(n, _POSE)
        b = float(x[-1])
        data = (rss - expected(X) - b) / sig
        return np.concatenate([data, prior(x), [b / sd_b]])

    def data_jac(x: FloatArray) -> FloatArray:
        """``(m, 3)``: each reading's derivative by its packet's x, y, azimuth
        (central differences); its derivative by the offset is −1/σ."""
        X = x[: _POSE * n].reshape(n, _POSE)
        d = np.empty((m, _POSE))
        for c in range(_POSE):
            Xp, Xm = X.copy(), X.copy()
            Xp[:, c] += _FD_STEP
            Xm[:, c] -= _FD_STEP
            d[:, c] = -(expected(Xp) - expected(Xm)) / (2 * _FD_STEP * sig)
        return d

    loss = soft_l1_head(m, c2)

    box = np.asarray(model.box_m, dtype=float)
    lo = np.tile([box[0], box[2], -np.inf], n)
    hi = np.tile([box[1], box[3], np.inf], n)
    X0 = np.column_stack([pos[:, 0], pos[:, 1], np.unwrap(np.deg2rad(ori[:, 0]))])
    x0 = np.concatenate([X0.ravel(), [float(offset_db)]])
    x0 = np.clip(x0, np.append(lo, -np.inf) + 1e-9, np.append(hi, np.inf) - 1e-9)
    f0 = fun(x0)
    initial_cost = 0.5 * float(loss(f0 * f0)[0].sum())
    lb, ub = np.append(lo, -np.inf), np.append(hi, np.inf)
    # the normal equations in band form: the banded solve's, and the Laplace
    # term's whichever solve ran (the same matrix as the sparse rows')
    normal = _BandedNormal(n, pkt, coef, sig, sd_b) if A is None or config.arbiter_laplace else None
    if A is None:
        assert normal is not None
        x_opt, cost, nfev = _banded_levenberg_marquardt(
            fun, data_jac, normal, loss, x0, lb, ub, max_nfev
        )
    else:
        data_rows = np.repeat(np.arange(m), _POSE)
        data_cols = (_POSE * pkt[:, None] + np.arange(_POSE)[None, :]).ravel()
        last = sp.csr_matrix(([1.0 / sd_b], ([0], [n_vars - 1])), shape=(1, n_vars))
        bcol = sp.csr_matrix(
            (np.full(m, -1.0 / sig), (np.arange(m), np.full(m, n_vars - 1))), shape=(m, n_vars)
        )
        prior_rows = A

        def jac(x: FloatArray) -> sp.csr_matrix:
            data = sp.csr_matrix((data_jac(x).ravel(), (data_rows, data_cols)), shape=(m, n_vars))
            return sp.vstack([data + bcol, prior_rows, last], format="csr")

        x_opt, cost, nfev = _levenberg_marquardt(fun, jac, loss, x0, lb, ub, max_nfev)
    log_volume = math.nan
    if normal is not None and config.arbiter_laplace:
        f_opt = fun(x_opt)
        ab, c, d_bb, _, _ = normal.build(data_jac(x_opt), loss(f_opt * f_opt)[1], f_opt)
        log_volume = _half_log_det(ab, c, d_bb)
    X = x_opt[: _POSE * n].reshape(n, _POSE)
    out_pos = pos.copy()
    out_pos[:, :2] = X[:, :2]
    out_ori = ori.copy()
    out_ori[:, 0] = np.rad2deg(X[:, 2]) % 360.0
    return Refined2d(out_pos, out_ori, float(x_opt[-1]), cost, initial_cost, nfev, log_volume)


_BAND = 2 * _POSE
"""Upper bandwidth of the pose block of the normal equations: the motion prior
couples a packet's variables with those of the packets two either side."""


class _BandedNormal:
    """The normal equations ``JᵀWJ δ = −JᵀWf`` of :func:`refine_track_2d` in
    LAPACK's banded form: the pose block (x, y, azimuth per packet, interleaved)
    is banded (bandwidth :data:`_BAND`), the offset adds one dense row and
    column, solved by its Schur complement (``FilterConfig.refine_banded``).
    The same system as the sparse LU of
    :func:`radiopose.filtering.refine3d._levenberg_marquardt` (the default, and
    the 3-D refinement's), ≈ 4× cheaper; the solutions agree to ~1e-9
    relative (docs/performance.md, "Ninth pass")."""

    def __init__(
        self, n: int, pkt: np.ndarray, coef: FloatArray, sigma_db: float, sd_b: float
    ) -> None:
        self.n, self.pkt, self.sig, self.sd_b = n, pkt, sigma_db, sd_b
        self.coef = coef
        k = coef.shape[1]
        nv = _POSE * n
        # the prior's constant part AᵀA, upper band: ab[_BAND + i − j, j] = (AᵀA)[i, j]
        ab = np.zeros((_BAND + 1, nv))
        if k:
            i = np.arange(1, n - 1)
            for comp in range(_POSE):
                cols = [_POSE * (i + 1) + comp, _POSE * i + comp, _POSE * (i - 1) + comp]
                for a in range(3):
                    for b in range(3):
                        ra, rb = cols[a], cols[b]
                        if ra[0] <= rb[0]:  # upper triangle (the same order for every row)
                            np.add.at(
                                ab, (_BAND + ra - rb, rb), coef[comp, :, a] * coef[comp, :, b]
                            )
        self.prior_band = ab

    def prior_t(self, r: FloatArray) -> FloatArray:
        """``Aᵀ r`` for the prior's residuals ``r`` (``(3k,)``)."""
        n, coef = self.n, self.coef
        k = coef.shape[1]
        out = np.zeros((n, _POSE))
        if k:
            for comp in range(_POSE):
                rc = r[comp * k : (comp + 1) * k]
                out[2:, comp] += coef[comp, :, 0] * rc
                out[1:-1, comp] += coef[comp, :, 1] * rc
                out[:-2, comp] += coef[comp, :, 2] * rc
        return out.ravel()

    def build(
        self, d: FloatArray, w: FloatArray, f: FloatArray
    ) -> tuple[FloatArray, FloatArray, float, FloatArray, float]:
        """``(band, c, d_bb, g_pose, g_b)`` of ``JᵀWJ`` and ``g = JᵀWf`` for the
        data Jacobian ``d`` (``(m, 3)``, :func:`refine_track_2d`'s), the IRLS
        weights ``w`` and residuals ``f`` (data, prior, offset)."""
        n, pkt, m = self.n, self.pkt, d.shape[0]
        nv = _POSE * n
        wd, fd = w[:m], f[:m]
        ab = self.prior_band.copy()
        for a in range(_POSE):
            for b in range(a, _POSE):
                s = np.bincount(pkt, weights=wd * d[:, a] * d[:, b], minlength=n)
                ab[_BAND + a - b, b::_POSE] += s
        inv = -1.0 / self.sig
        c = np.empty(nv)
        g = np.empty(nv)
        for a in range(_POSE):
            c[a::_POSE] = np.bincount(pkt, weights=wd * d[:, a] * inv, minlength=n)
            g[a::_POSE] = np.bincount(pkt, weights=wd * d[:, a] * fd, minlength=n)
        k = self.coef.shape[1]
        g += self.prior_t(f[m : m + 3 * k])
        d_bb = float(wd.sum()) * inv * inv + 1.0 / self.sd_b**2
        g_b = float((wd * fd).sum()) * inv + f[-1] / self.sd_b
        return ab, c, d_bb, g, g_b


def _banded_step(
    ab: FloatArray, c: FloatArray, d_bb: float, g: FloatArray, g_b: float
) -> FloatArray:
    """``−M⁻¹ [g, g_b]`` for ``M = [[P, c], [cᵀ, d_bb]]`` with ``P`` in upper
    band form ``ab`` (symmetric positive definite): a banded Cholesky of ``P``
    and the offset's Schur complement. A ``P`` that is not numerically positive
    definite falls back to a sparse LU of ``M``."""
    from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded

    try:
        cb = cholesky_banded(ab, lower=False, check_finite=False)
    except LinAlgError:
        return _sparse_step(ab, c, d_bb, g, g_b)
    y = cho_solve_banded((cb, False), np.column_stack([g, c]), check_finite=False)
    yg, yc = y[:, 0], y[:, 1]
    db = (g_b - float(c @ yg)) / (d_bb - float(c @ yc))
    return -np.append(yg - yc * db, db)


def _half_log_det(ab: FloatArray, c: FloatArray, d_bb: float) -> float:
    """½ log det ``M`` for ``M = [[P, c], [cᵀ, d_bb]]`` with ``P`` in upper band
    form ``ab`` (:func:`_banded_step`'s matrix): the banded Cholesky's diagonal
    and the offset's Schur complement; ``nan`` if ``M`` is not numerically
    positive definite."""
    from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded

    try:
        cb = cholesky_banded(ab, lower=False, check_finite=False)
    except LinAlgError:
        return math.nan
    schur = d_bb - float(c @ cho_solve_banded((cb, False), c, check_finite=False))
    if not schur > 0:
        return math.nan
    return float(np.log(cb[-1]).sum()) + 0.5 * math.log(schur)


def _sparse_step(
    ab: FloatArray, c: FloatArray, d_bb: float, g: FloatArray, g_b: float
) -> FloatArray:
    """:func:`_banded_step` by a sparse LU of the whole matrix."""
    import scipy.sparse.linalg as spla

    u, nv = ab.shape[0] - 1, ab.shape[1]
    offs = list(range(u + 1))
    P = sp.diags([ab[u - o, o:] for o in offs], offs, shape=(nv, nv))
    P = P + sp.triu(P, 1).T
    M = sp.bmat([[P, c[:, None]], [c[None, :], np.array([[d_bb]])]], format="csc")
    return -np.asarray(spla.spsolve(M, np.append(g, g_b)))


def _banded_levenberg_marquardt(
    fun: Callable[[FloatArray], FloatArray],
    data_jac: Callable[[FloatArray], FloatArray],
    normal: _BandedNormal,
    loss: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lb: FloatArray,
    ub: FloatArray,
    max_nfev: int,
) -> tuple[FloatArray, float, int]:
    """:func:`radiopose.filtering.refine3d._levenberg_marquardt` (the same
    damping, accept test and stop: :func:`~radiopose.filtering.refine3d.damped_least_squares`)
    with the normal equations solved in band form (:class:`_BandedNormal`).
    Returns ``(x, cost, residual evaluations)``."""
    nv = x0.size - 1

    def linearise(x: FloatArray, f: FloatArray, w: FloatArray) -> Callable[[float], FloatArray]:
        ab, c, d_bb, g, g_b = normal.build(data_jac(x), w, f)
        dA = np.append(ab[_BAND], d_bb)
        dA = np.where(dA > 0, dA, 1.0)

        def step(lam: float) -> FloatArray:
            mb = ab.copy()
            mb[_BAND] += lam * dA[:nv]
            return _banded_step(mb, c, d_bb + lam * dA[nv], g, g_b)

        return step

    return damped_least_squares(fun, linearise, loss, x0, lb, ub, max_nfev)


@dataclass(frozen=True)
class Arbitration:
    """What :func:`arbitrate` chose for one track.

    Attributes
    ----------
    start, stop
        Packet indices ``[start, stop)`` of the track in the records' order.
    costs
        Each candidate's refined objective (``nan``: it did not cover the track).
    initial_costs
        Each candidate's objective before the refinement.
    chosen
        Index of the candidate kept.
    offsets_db
        Each candidate's refined device offset, dB (``nan``: it did not cover
        the track).
    penalties
        Each candidate's offset penalty, nats (``offset_penalty`` of
        :func:`arbitrate`; zeros without one): the choice is the lowest
        ``costs + penalties`` (``+ log_volumes`` with
        ``FilterConfig.arbiter_laplace``).
    log_volumes
        Each candidate's Laplace width term, nats (:attr:`Refined2d.log_volume`;
        ``nan`` where not computed).
    """

    start: int
    stop: int
    costs: tuple[float, ...]
    initial_costs: tuple[float, ...]
    chosen: int
    offsets_db: tuple[float, ...] = ()
    penalties: tuple[float, ...] = ()
    log_volumes: tuple[float, ...] = ()


_Job = tuple[FloatArray, list[HeardRss], FloatArray, FloatArray]


def _refinement_jobs(
    records: Sequence[tuple[float, HeardRss, object]],
    candidates: Sequence[dict[object, FilterEstimate]],
    sigma_db: float,
    config: FilterConfig,
    max_nfev: int,
) -> tuple[
    list[tuple[float, HeardRss, object]],
    list[tuple[int, int]],
    float,
    list[_Job],
    list[tuple[object, ...]],
    list[list[int | None]],
]:
    """:func:`arbitrate`'s work list: the reference's heard packets, their
    tracks (``(start, stop)`` rows; silences longer than ``reacquire_gap_s``
    split them), the σ used, every distinct (track, candidate) refinement
    ``(t, heard, position, orientation)`` with its cache key, and per track the
    job of each candidate (``None``: the candidate does not cover the track).
    A candidate identical to an earlier one over a track shares its job."""
    ref = candidates[0]
    rows = [r for r in records if r[2] in ref and r[1].n_heard > 0]
    sig = config.sigma_prior_db
    if math.isfinite(sigma_db):
        sig = max(float(sigma_db), config.sigma_floor_db)
    spans: list[tuple[int, int]] = []
    start = 0
    for j in range(1, len(rows) + 1):
        if j < len(rows) and rows[j][0] - rows[j - 1][0] <= config.reacquire_gap_s:
            continue
        spans.append((start, j))
        start = j
    # every (track, candidate) refinement, a candidate identical to an earlier
    # one over the track (e.g. the combined track where no segment took the
    # reversed poses) refined once: the same input gives the same optimum
    jobs: list[_Job] = []
    keys: list[tuple[object, ...]] = []
    job_of: list[list[int | None]] = []
    for a, b in spans:
        track = rows[a:b]
        t = np.array([r[0] for r in track])
        h = [r[1] for r in track]
        mine: list[int | None] = []
        for cand in candidates:
            if not all(r[2] in cand for r in track):
                mine.append(None)
                continue
            ests = [cand[r[2]] for r in track]
            pos = np.array([e.position_m for e in ests], dtype=float)
            ori = np.array([e.orientation_deg for e in ests], dtype=float)
            same = next(
                (
                    q
                    for q in mine
                    if q is not None
                    and np.array_equal(jobs[q][2], pos)
                    and np.array_equal(jobs[q][3], ori)
                ),
                None,
            )
            if same is None:
                jobs.append((t, h, pos, ori))
                keys.append((a, b, sig, max_nfev, pos.tobytes(), ori.tobytes()))
                same = len(jobs) - 1
            mine.append(same)
        job_of.append(mine)
    return rows, spans, sig, jobs, keys, job_of


def refine_for_arbiter(
    model: FilterModel,
    records: Sequence[tuple[float, HeardRss, object]],
    reference: dict[object, FilterEstimate],
    candidates: Sequence[dict[object, FilterEstimate]],
    sigma_db: float,
    config: FilterConfig,
    max_nfev: int,
) -> dict[tuple[object, ...], Refined2d]:
    """The refinements :func:`arbitrate` would compute for ``candidates`` with
    ``reference`` as its ``candidates[0]`` (the same ``records``, σ, settings),
    by their cache keys: computed ahead (e.g. on another process) and handed to
    a later :func:`arbitrate` through its ``cache``, they spare it that work
    (the same input, the same result; a track identical in two candidates is
    refined once)."""
    _, _, sig, jobs, keys, job_of = _refinement_jobs(
        records, [reference, *candidates], sigma_db, config, max_nfev
    )
    mine = {q for row in job_of for q in row[1:] if q is not None}
    out: dict[tuple[object, ...], Refined2d] = {}
    for q in sorted(mine):
        t, h, pos, ori = jobs[q]
        out[keys[q]] = refine_track_2d(model, t, h, pos, ori, sig, config, max_nfev=max_nfev)
    return out


def arbitrate(
    model: FilterModel,
    records: Sequence[tuple[float, HeardRss, object]],
    candidates: Sequence[dict[object, FilterEstimate]],
    sigma_db: float,
    config: FilterConfig,
    max_nfev: int,
    refine_output: bool = True,
    workers: int = 1,
    cache: dict[tuple[object, ...], Refined2d] | None = None,
    offset_penalty: Callable[[float], float] | None = None,
    handicaps_nats: Sequence[float] | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], list[Arbitration]]:
    """Every packet's estimate from the candidate track of the lowest refined
    objective, per track (module docstring).

    ``records`` are the packets ``(t_s, heard, key)`` in time order;
    ``candidates[0]`` is the reference (a packet it has no estimate for is left
    out). A candidate that lacks an estimate of some packet of a track does not
    compete there. ``refine_output``: emit the refined poses (else the chosen
    candidate's own). Spread and σ of the reference are kept. ``workers``:
    processes the refinements may use, this one included
    (:func:`radiopose.filtering.forked.map_forked`; the result does not depend
    on it). A candidate identical to an earlier one over a track is refined
    once there (the same input, the same optimum). ``cache``: refinements by
    their input (track, σ, ``max_nfev``, the candidate's poses), read and
    filled: an earlier call with the same ``records``, ``candidates[0]`` and
    settings over some of the candidates (e.g. while another process runs the
    pass that gives the others) spares this one their work.
    ``offset_penalty``: nats added to a candidate's refined objective as a
    function of its refined device offset (dB) before the lowest is taken
    (round 7, :func:`radiopose.filtering.offset_refit.evidence_penalty`).
    ``handicaps_nats``: per candidate, nats added to its refined objective
    before the lowest is taken (session 13: an outsider must win by that
    margin; ``None``: none). Both appear in the log's ``penalties``.
    """
    if not candidates:
        raise InputError("arbitrate: no candidate track")
    hand = tuple(float(v) for v in handicaps_nats) if handicaps_nats is not None else None
    if hand is not None and (len(hand) != len(candidates) or not all(map(math.isfinite, hand))):
        raise InputError(
            f"arbitrate: {len(hand)} handicaps for {len(candidates)} candidates, or not finite"
        )
    ref = candidates[0]
    rows, spans, sig, jobs, keys, job_of = _refinement_jobs(
        records, candidates, sigma_db, config, max_nfev
    )
    out = dict(ref)
    log: list[Arbitration] = []
    memo = {} if cache is None else cache
    todo = [q for q, key in enumerate(keys) if key not in memo]
    done = map_forked(
        [
            partial(refine_track_2d, model, t, h, pos, ori, sig, config, max_nfev=max_nfev)
            for t, h, pos, ori in (jobs[q] for q in todo)
        ],
        workers,
        weights=[float(jobs[q][0].size) for q in todo],
    )
    memo.update({keys[q]: r for q, r in zip(todo, done, strict=True)})
    refined = [memo[key] for key in keys]
    for (a, j), mine in zip(spans, job_of, strict=True):
        track = rows[a:j]
        results = [None if q is None else refined[q] for q in mine]
        costs = tuple(r.cost if r is not None else math.nan for r in results)
        offs = tuple(r.offset_db if r is not None else math.nan for r in results)
        pen = tuple(
            (0.0 if r is None or offset_penalty is None else float(offset_penalty(r.offset_db)))
            + (0.0 if r is None or hand is None else hand[i])
            for i, r in enumerate(results)
        )
        vols = tuple(r.log_volume if r is not None else math.nan for r in results)
        occam = config.arbiter_laplace and all(
            math.isfinite(v) for v, r in zip(vols, results, strict=True) if r is not None
        )
        best = min(
            (i for i, r in enumerate(results) if r is not None),
            key=lambda i: costs[i] + pen[i] + (vols[i] if occam else 0.0),
        )
        chosen = results[best]
        assert chosen is not None
        for i, r in enumerate(track):
            if refine_output:
                p, o = chosen.position_m[i], chosen.orientation_deg[i]
                est = replace(
                    ref[r[2]],
                    position_m=(float(p[0]), float(p[1]), float(p[2])),
                    orientation_deg=(float(o[0]), float(o[1]), float(o[2])),
                    offset_db=chosen.offset_db,
                )
            else:
                est = candidates[best][r[2]]
            out[r[2]] = est
        inits = tuple(r.initial_cost if r is not None else math.nan for r in results)
        log.append(Arbitration(a, j, costs, inits, best, offs, pen, vols))
    return [(r[2], out[r[2]]) for r in records if r[2] in ref], log


__all__ = ["Arbitration", "Refined2d", "arbitrate", "refine_for_arbiter", "refine_track_2d"]
