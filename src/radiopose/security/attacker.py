"""The attacker model: best transmit power, matching locations, sustained paths.

Paper, "System and Attacker Model" and "Security Analysis". An attacker who
knows the site (receiver positions, survey map) and the victim's enrolled
pattern wants the system to report the victim at a *target* pose ``L`` while
it transmits from somewhere else.

Match (what :func:`find_matches` tests, see ``docs/security.md``)
------------------------------------------------------------------
The target's RSS is ``y`` (by default the system's noise-free expected RSS of
the target candidate, ``M_r(p) + P_tx + D_t``). The system's own threshold
``τ`` is the ``k``-th best (``k = 100``) MSE over every candidate for ``y``
(enrolled pattern, enrolled power) — the score a candidate needs to enter the
top ``k``. An attacker pose ``L'`` (a grid candidate at least ``d`` metres from
the target position) transmitting with power ``P_tx + δ`` produces
``A_r(L') + δ``, ``A`` being the expected RSS with the *attacker's real*
pattern. Its residual is ``e_r = y_r − A_r(L')``; the MSE

    MSE(δ) = (1/h) Σ_r (e_r − δ)² = var(e) + (ē − δ)²

is minimised over ``|δ| ≤ Δ`` by ``δ* = clip(ē, −Δ, Δ)`` (closed form), so

    MSE*(L') = var(e) + (|ē| − Δ)₊²                                       (dB²)

``L'`` *matches* ``L`` iff ``MSE*(L') ≤ τ``: inserted into the system's ranking
for ``y`` it would be among the top ``k``. For a noise-free ``y`` the same number
is the MSE of the target candidate for the attacker's (noise-free) RSS, so the
test also reads "the attacker's RSS scores the target as well as the
``k``-th best candidate of a genuine packet".

Computation
-----------
:class:`MatchTable` holds, per candidate, the attacker's expected RSS centred
across receivers (float32, ``G̃``), its across-receiver mean ``Ḡ`` and
``S = Σ_r G̃_r²``. Per target one float32 matrix-vector product gives
``h·var(e) = Σ w̃² − 2 w̃·G̃ + S`` for every candidate at once; candidates
screened within ``δ_f`` (a float32 round-off bound) of ``τ`` are rescored
exactly in float64 (:func:`exact_best_power_mse_db2`), so the match set equals
the exhaustive float64 answer (:func:`brute_force_matches`).

Sustained paths
---------------
:class:`PathSearch` follows every chain of matching poses the attacker could
transmit from while moving within the movement and rotation limits and never
staying silent longer than ``t/2``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from radiopose.errors import InputError, check_setting_types
from radiopose.likelihood.candidates import CandidateSpace, HeardRss, expected_rss_dbm
from radiopose.likelihood.numpy_kernel import TableScorer, build_table
from radiopose.likelihood.power import best_power_mse_db2
from radiopose.motion import axis_change_deg
from radiopose.patterns.pattern import Pattern
from radiopose.tracker.config import TrackerConfig
from radiopose.units import FloatArray

IntArray = NDArray[np.int64]
_EPS32 = float(np.finfo(np.float32).eps)


@dataclass(frozen=True)
class AttackerModel:
    """What the attacker may do in the match search.

    Attributes
    ----------
    min_distance_m
        ``d``: the attacker stands at least this far from the target position, metres.
    power_range_db
        ``Δ``: its transmit power is ``P_tx + δ`` with ``|δ| ≤ Δ``, dB
        (``P_tx`` the victim's enrolled power).
    k
        The system's top-k (a match must rank among them).
    """

    min_distance_m: float = 5.0
    power_range_db: float = 10.0
    k: int = 100

    def __post_init__(self) -> None:
        check_setting_types(self, "attacker")
        if not (self.min_distance_m >= 0 and self.power_range_db >= 0 and self.k >= 1):
            raise InputError(f"attacker model out of range: {self}")


# ----------------------------------------------------------------------------- kernels
def exact_best_power_mse_db2(
    space: CandidateSpace, rss_dbm: FloatArray, candidate_idx: IntArray, power_range_db: float
) -> tuple[FloatArray, FloatArray]:
    """Exact float64 best-power MSE and offset of candidates of ``space`` against ``rss_dbm``.

    ``space`` carries the attacker's pattern; ``rss_dbm`` is ``(n_rx,)``.
    """
    pos, ori = space.split(candidate_idx)
    a = expected_rss_dbm(space, pos, ori)  # (n, n_rx)
    return best_power_mse_db2(np.asarray(rss_dbm, np.float64)[None, :] - a, power_range_db)


# ----------------------------------------------------------------------------- tables
@dataclass(frozen=True, eq=False)
class MatchTable:
    """Packet-independent arrays for the best-power match search (module docstring).

    Attributes
    ----------
    space
        Candidate space with the *attacker's* pattern.
    centre_db
        ``(n_rx,)`` per-receiver centres ``c_r`` (as in the numpy scorer), dB.
    centred
        ``(n_cand, n_rx)`` float32, ``G̃ = G' − Ḡ'`` with ``G' = A − c``.
    mean_db
        ``(n_cand,)`` float32, ``Ḡ'`` (mean of ``G'`` over receivers).
    sum_sq_db2
        ``(n_cand,)`` float32, ``S = Σ_r G̃_r²`` (``+inf`` where a survey value is NaN).
    sum_sq_max_db2, mean_abs_max_db
        ``max S`` over finite entries and ``max |Ḡ'|`` (for the round-off bound).
    """

    space: CandidateSpace
    centre_db: FloatArray
    centred: NDArray[np.float32]
    mean_db: NDArray[np.float32]
    sum_sq_db2: NDArray[np.float32]
    sum_sq_max_db2: float
    mean_abs_max_db: float

    @property
    def nbytes(self) -> int:
        return int(self.centred.nbytes + self.mean_db.nbytes + self.sum_sq_db2.nbytes)


def attacker_space(space: CandidateSpace, pattern: Pattern | None = None) -> CandidateSpace:
    """The victim's candidate space with the attacker's real ``pattern`` (same if None)."""
    return space if pattern is None else replace(space, pattern=pattern)


def build_match_table(space: CandidateSpace) -> MatchTable:
    """Precompute :class:`MatchTable` for ``space`` (already carrying the attacker's pattern)."""
    table, centre, _valid, _gmax = build_table(space)
    n = space.n_receivers
    g = table[:, :n]
    gbar = g.mean(axis=1, dtype=np.float64).astype(np.float32)
    centred = np.empty(g.shape, dtype=np.float32)
    s = np.zeros(g.shape[0], dtype=np.float32)
    for r in range(n):
        centred[:, r] = g[:, r] - gbar
        s += centred[:, r] * centred[:, r]
    s[~np.isfinite(table[:, n])] = np.inf
    finite = np.isfinite(s)
    s_max = float(s[finite].max()) if finite.any() else 0.0
    m_max = float(np.abs(gbar).max()) if gbar.size else 0.0
    del table
    return MatchTable(space, centre, centred, gbar, s, s_max, m_max)


@numba.njit(cache=True, boundscheck=False)
def _screen(centred, sum_sq, mean, wt, wbar, c0, power_range, limit):  # pragma: no cover
    """One fused float32 pass: ``var(e) + (|ē| − Δ)₊² ≤ limit`` for every candidate."""
    n_c, n = centred.shape
    inv = np.float32(1.0) / np.float32(n)
    out = np.zeros(n_c, dtype=np.bool_)
    for i in range(n_c):
        acc = np.float32(0.0)
        for r in range(n):
            acc += wt[r] * centred[i, r]
        v = c0 + (sum_sq[i] - np.float32(2.0) * acc) * inv
        ex = abs(wbar - mean[i]) - power_range
        if ex > 0:
            v += ex * ex
        out[i] = v <= limit
    return out


# ----------------------------------------------------------------------------- search
@dataclass(frozen=True, eq=False)
class MatchResult:
    """The attacker poses matching one target.

    Attributes
    ----------
    threshold_db2
        ``τ``: the system's ``k``-th best MSE for the target's RSS, dB².
    candidate_idx
        ``(m,)`` matching candidates (``≥ d`` from the target), best first.
    mse_db2
        ``(m,)`` their best-power MSE, dB².
    offset_db
        ``(m,)`` the power offset ``δ*`` each needs, dB.
    n_screened
        Candidates rescored exactly (diagnostic).
    """

    threshold_db2: float
    candidate_idx: IntArray
    mse_db2: FloatArray
    offset_db: FloatArray
    n_screened: int = 0

    @property
    def any(self) -> bool:
        return bool(self.candidate_idx.size)

    def __len__(self) -> int:
        return int(self.candidate_idx.size)


def system_threshold_db2(scorer: object, rss_dbm: FloatArray, k: int) -> float:
    """``τ``: the ``k``-th best MSE the system's scorer gives a packet heard by every receiver.

    ``scorer`` is any radiopose scorer (``score_heard``) over the *enrolled* space.
    """
    y = np.asarray(rss_dbm, dtype=np.float64)
    heard = HeardRss(np.arange(y.size, dtype=np.int64), y)
    top = scorer.score_heard(heard, k)  # type: ignore[attr-defined]
    if len(top) == 0:
        return -np.inf
    return float(top.mse_db2[-1])


def _far_enough(
    space: CandidateSpace, candidate_idx: IntArray, target_xyz_m: FloatArray, min_distance_m: float
) -> np.ndarray:
    p = space.candidate_positions_m(candidate_idx)
    return (
        np.linalg.norm(p - np.asarray(target_xyz_m, float)[None, :], axis=1)
        >= min_distance_m - 1e-9
    )


def _select(
    space: CandidateSpace,
    idx: IntArray,
    rss: FloatArray,
    tau: float,
    target_xyz_m: FloatArray,
    model: AttackerModel,
    n_screened: int,
) -> MatchResult:
    idx = idx[_far_enough(space, idx, target_xyz_m, model.min_distance_m)]
    mse, off = exact_best_power_mse_db2(space, rss, idx, model.power_range_db)
    ok = np.isfinite(mse) & (mse <= tau)
    idx, mse, off = idx[ok], mse[ok], off[ok]
    order = np.lexsort((idx, mse))
    return MatchResult(tau, idx[order], mse[order], off[order], n_screened)


def find_matches(
    table: MatchTable,
    rss_dbm: FloatArray,
    threshold_db2: float,
    target_xyz_m: FloatArray,
    model: AttackerModel,
) -> MatchResult:
    """Every candidate matching a target (module docstring), exact in float64.

    Parameters
    ----------
    table
        The attacker's :class:`MatchTable`.
    rss_dbm
        ``(n_rx,)`` the target's RSS at every receiver, dBm.
    threshold_db2
        ``τ`` (:func:`system_threshold_db2`).
    target_xyz_m
        ``(3,)`` the target position, metres.
    model
        Distance and power limits.
    """
    s = table.space
    n = s.n_receivers
    w = np.asarray(rss_dbm, dtype=np.float64) - table.centre_db
    wbar = float(w.mean())
    wt = w - wbar
    # float32 round-off bound of the screen (generous), then exact rescoring.
    s_max = table.sum_sq_max_db2 / n
    g_max = table.mean_abs_max_db + abs(wbar) + model.power_range_db
    scale = float(np.sum(wt * wt)) / n + s_max + g_max * g_max
    delta = 16.0 * (n + 4) * _EPS32 * scale + 1e-12
    # h·var(e) = Σ w̃² − 2 w̃·G̃ + S and (|ē| − Δ)₊² with ē = w̄ − Ḡ', every candidate (float32).
    keep = _screen(
        table.centred,
        table.sum_sq_db2,
        table.mean_db,
        wt.astype(np.float32),
        np.float32(wbar),
        np.float32(np.sum(wt * wt) / n),
        np.float32(model.power_range_db),
        np.float32(threshold_db2 + delta),
    )
    idx = np.flatnonzero(keep).astype(np.int64)
    return _select(s, idx, rss_dbm, threshold_db2, target_xyz_m, model, int(idx.size))


def brute_force_matches(
    space: CandidateSpace,
    rss_dbm: FloatArray,
    threshold_db2: float,
    target_xyz_m: FloatArray,
    model: AttackerModel,
    chunk: int = 200_000,
) -> MatchResult:
    """The same as :func:`find_matches`, exhaustively in float64 (slow; for tests)."""
    keep = []
    for start in range(0, space.n_candidates, chunk):
        idx = np.arange(start, min(start + chunk, space.n_candidates), dtype=np.int64)
        mse, _ = exact_best_power_mse_db2(space, rss_dbm, idx, model.power_range_db)
        keep.append(idx[np.isfinite(mse) & (mse <= threshold_db2)])
    idx = np.concatenate(keep)
    return _select(space, idx, rss_dbm, threshold_db2, target_xyz_m, model, space.n_candidates)


def system_scorer(space: CandidateSpace) -> object:
    """The fastest exact scorer for ``space``: the compiled one if registered and supported.

    Every registered scorer returns the reference's top-k, so only speed depends
    on the choice; a space the compiled kernel does not support (it raises a
    ``ValueError``) falls back to the numpy scorer.
    """
    from radiopose.likelihood import SCORERS, make_scorer

    if "numba" in SCORERS:
        try:
            return make_scorer("numba", space)
        except ValueError:
            pass
    return TableScorer(space)


# ----------------------------------------------------------------------------- paths
@dataclass(frozen=True)
class MotionLimits:
    """The bounds a spoofed path must keep (the tracker's, scaled).

    Attributes
    ----------
    max_speed_mps, max_rotation_deg, rotation_period_s
        The system's movement and rotation models; the defaults are
        :class:`~radiopose.tracker.TrackerConfig`'s (10 m/s; 180° per 0.5 s),
        :meth:`of` takes them from a given configuration.
    scale
        Fraction of those bounds the attacker keeps to (1, or 0.1 as in the paper).
    max_silence_s
        Longest silence between two spoofed packets; ``None`` = ``rotation_period_s / 2``.
    """

    max_speed_mps: float = TrackerConfig.max_speed_mps
    max_rotation_deg: float = TrackerConfig.max_rotation_deg
    rotation_period_s: float = TrackerConfig.rotation_period_s
    scale: float = 1.0
    max_silence_s: float | None = None

    @classmethod
    def of(cls, config: TrackerConfig, scale: float = 1.0) -> MotionLimits:
        """The limits of the tracker configured by ``config``, scaled by ``scale``."""
        return cls(
            config.max_speed_mps, config.max_rotation_deg, config.rotation_period_s, scale=scale
        )

    @property
    def silence_s(self) -> float:
        return self.rotation_period_s / 2.0 if self.max_silence_s is None else self.max_silence_s

    @property
    def speed_mps(self) -> float:
        return self.scale * self.max_speed_mps

    @property
    def rate_deg_s(self) -> float:
        return self.scale * self.max_rotation_deg / self.rotation_period_s


@dataclass(frozen=True, eq=False)
class PathAttack:
    """How far a spoofed path could be sustained.

    Attributes
    ----------
    packets_until_failure
        Index of the first packet at which the attacker has been silent (no
        feasible matching transmission) for longer than ``t/2`` — the packets
        the spoofed track survived; ``n_packets`` if it never failed.
    failed
        Whether the attack failed within the packets examined.
    sustained_packets
        Index of the last packet the attacker could transmit, plus one (0: none).
    chain
        ``(m, 2)`` int: ``(packet index, candidate index)`` of the longest
        feasible sequence of spoofed packets, in time order.
    n_packets
        Packets examined.
    """

    packets_until_failure: int
    failed: bool
    sustained_packets: int
    chain: IntArray
    n_packets: int


class PathSearch:
    """Reachable attacker states along a target path, one packet at a time.

    A state is a spoofed transmission ``(candidate, time)`` reachable by a chain
    starting within ``t/2`` of the first packet whose consecutive elements are
    at most ``t/2`` apart and within the movement and rotation limits for
    their time difference (grid poses compared exactly, no slack).

    Parameters
    ----------
    limits
        Movement, rotation and silence limits.
    """

    def __init__(self, limits: MotionLimits) -> None:
        self.limits = limits
        self._pos: list[FloatArray] = []
        self._ori: list[FloatArray] = []
        self._cand: list[IntArray] = []
        self._parent: list[IntArray] = []
        self._t: list[float] = []
        self._offset: list[int] = []
        self._n_states = 0
        self.failure: int | None = None
        self.last_ok: int | None = None
        self._t0: float | None = None

    @property
    def alive(self) -> bool:
        return self.failure is None

    def step(
        self,
        t_s: float,
        positions_m: FloatArray,
        orientations_deg: FloatArray,
        candidate_idx: IntArray,
    ) -> bool:
        """Add the next packet's matching poses; return whether the attack is still alive."""
        i = len(self._t)
        lim = self.limits
        if self._t0 is None:
            self._t0 = t_s
        p = np.asarray(positions_m, float).reshape(-1, 3)
        o = np.asarray(orientations_deg, float).reshape(-1, 3)
        c = np.asarray(candidate_idx, np.int64).reshape(-1)
        start = t_s - self._t0 <= lim.silence_s + 1e-12
        window = [
            j for j in range(i) if t_s - self._t[j] <= lim.silence_s + 1e-12 and self._cand[j].size
        ]
        parent = np.full(c.size, -1, dtype=np.int64)
        ok = np.full(c.size, start, dtype=bool)
        if window and c.size and self.alive:
            wc = np.concatenate([self._cand[j] for j in window])  # time order
            wid = np.concatenate([self._offset[j] + np.arange(self._cand[j].size) for j in window])
            wt = np.concatenate([np.full(self._cand[j].size, self._t[j]) for j in window])
            # Within the window a candidate's earliest reach dominates its later ones
            # (more time → more slack; the silence bound holds for all of them).
            uc, first = np.unique(wc, return_index=True)
            _, last_rev = np.unique(wc[::-1], return_index=True)
            wid_last = wid[wc.size - 1 - last_rev]
            wid, wt = wid[first], wt[first]
            # Staying on the same pose is always feasible; its parent is the latest
            # visit, so the reconstructed chain transmits as often as it can.
            hit = np.searchsorted(uc, c).clip(0, uc.size - 1)
            same = uc[hit] == c
            ok[same] = True
            parent[same] = wid_last[hit[same]]
            rest = np.flatnonzero(~same)
            if rest.size:
                wp, wo = self._state_poses(wid)
                tree = cKDTree(wp)
                radius = lim.speed_mps * float(t_s - wt.min()) + 1e-9
                near = tree.query_ball_point(p[rest], r=radius)
                counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
                if counts.sum():
                    a = np.repeat(rest, counts)
                    b = np.concatenate([np.asarray(x, np.int64) for x in near if len(x)])
                    dt = t_s - wt[b]
                    good = (np.linalg.norm(p[a] - wp[b], axis=1) <= lim.speed_mps * dt + 1e-9) & (
                        axis_change_deg(o[a], wo[b]).max(axis=1) <= lim.rate_deg_s * dt + 1e-9
                    )
                    a, b = a[good], b[good]
                    ok[a] = True
                    parent[a] = wid[b]  # any feasible parent will do
        if not self.alive:
            ok[:] = False
        self._offset.append(self._n_states)
        self._pos.append(p[ok])
        self._ori.append(o[ok])
        self._cand.append(c[ok])
        self._parent.append(parent[ok])
        self._t.append(float(t_s))
        self._n_states += int(ok.sum())
        if ok.any():
            self.last_ok = i
        if self.alive and not start and not window and not ok.any():
            self.failure = i
        return self.alive

    def _state_poses(self, state_id: IntArray) -> tuple[FloatArray, FloatArray]:
        """Positions and orientations ``(n, 3)`` of global state ids."""
        offsets = np.asarray(self._offset)
        j = np.searchsorted(offsets, state_id, side="right") - 1
        k = state_id - offsets[j]
        pos = np.array([self._pos[jj][kk] for jj, kk in zip(j, k, strict=True)]).reshape(-1, 3)
        ori = np.array([self._ori[jj][kk] for jj, kk in zip(j, k, strict=True)]).reshape(-1, 3)
        return pos, ori

    def result(self) -> PathAttack:
        """The outcome so far and the longest chain."""
        n = len(self._t)
        chain = np.zeros((0, 2), dtype=np.int64)
        if self.last_ok is not None:
            cand = np.concatenate(self._cand)
            parent = np.concatenate(self._parent)
            packet = np.concatenate([np.full(x.size, j) for j, x in enumerate(self._cand)])
            sid = self._offset[self.last_ok]
            rows = []
            while sid >= 0:
                rows.append((int(packet[sid]), int(cand[sid])))
                sid = int(parent[sid])
            chain = np.array(rows[::-1], dtype=np.int64)
        return PathAttack(
            packets_until_failure=n if self.failure is None else self.failure,
            failed=self.failure is not None,
            sustained_packets=0 if self.last_ok is None else self.last_ok + 1,
            chain=chain,
            n_packets=n,
        )


def sustain_path(
    times_s: FloatArray,
    positions_m: list[FloatArray],
    orientations_deg: list[FloatArray],
    limits: MotionLimits,
) -> PathAttack:
    """Run :class:`PathSearch` over given per-packet match sets (candidate ids = row numbers).

    Parameters
    ----------
    times_s
        ``(n,)`` packet times, increasing.
    positions_m, orientations_deg
        Per packet, the matching poses: ``(m_i, 3)`` positions and ``(m_i, 3)`` orientations
        (equal poses in different packets are the same candidate).
    limits
        Movement, rotation and silence limits.
    """
    search = PathSearch(limits)
    ids: dict[tuple[float, ...], int] = {}
    for t, p, o in zip(times_s, positions_m, orientations_deg, strict=True):
        pp = np.asarray(p, float).reshape(-1, 3)
        oo = np.asarray(o, float).reshape(-1, 3)
        keys = [tuple(np.r_[a, b].round(9)) for a, b in zip(pp, oo, strict=True)]
        c = np.array([ids.setdefault(k, len(ids)) for k in keys], dtype=np.int64)
        search.step(float(t), pp, oo, c)
        if not search.alive:
            break
    return search.result()
