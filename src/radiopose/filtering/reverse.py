"""Offline: a second filter pass over the time-reversed packets, combined per segment.

Beyond the paper (issue 15, wrong locks; docs/filter.md, "Accuracy round 5:
wrong locks offline"). The forward filter may hold a wrong mode for a second
and leave it late; a smoother over its particles cannot give back a mode the
filter never held. The motion model (nearly-constant velocity and turn rate)
is time-reversible, so the same filter run over the packets in reverse order,
at times ``t' = t_0 + t_end − t`` (its velocities and turn rate come out
negated, which the pose estimates do not read), enters such a stretch from the
other side, where the data often lead it into the right mode.

Combination (:func:`combine_tracks`): where the forward and the reversed
smoothed tracks disagree (more than ``disagree_m`` apart or ``disagree_deg``
in azimuth) the packets form segments (gaps shorter than ``merge_gap_s``
joined). For each segment two tracks of the whole file are compared: the
forward track, and the forward track with the reversed pass's poses in that
segment. Each is scored by the log-likelihood of every packet under its poses
(the filter's per-receiver Gaussian-plus-uniform mixture at the forward
filter's σ) at its own best single device offset (profiled over the whole
file: the offset is a constant of the device, and a wrong lock is often a
wrong (pose, offset) pair, so the forward track's offset would favour it),
minus ``log(1/jump_probability)`` nats for a jump at either end of the
segment (a step between consecutive packets beyond twice the motion model's
limits): the continuity check. Jumps inside the segment are not counted: at
σ = 3 dB the smoothed tracks step beyond those limits tens of times a second,
and counting them chose wrong tracks (docs/filter.md, round 5). The segment takes the reversed poses
if that score is the larger.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import FilterConfig, FilterEstimate
from radiopose.filtering.model import FilterModel
from radiopose.filtering.offset import run_pass, tight_config
from radiopose.filtering.particle import ParticleFilter
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray, angle_diff_deg

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import ParticleFilter3d, Pose3dConfig

Record = tuple[float, HeardRss, object]
"""One packet as the passes replay it: ``(t_s, heard, key)``."""

OFFSET_GRID_DB = np.arange(-15.0, 15.0 + 1e-9, 0.1)
"""Offsets over which a device offset is profiled, dB."""
_PROFILE_ROWS = 8
"""Offsets of :data:`OFFSET_GRID_DB` scored together by :func:`profile_offset`."""


def reversed_records(records: list[Record]) -> list[Record]:
    """The packets in reverse order at times ``t_0 + t_end − t`` (same keys)."""
    if not records:
        return []
    t0, t1 = records[0][0], records[-1][0]
    return [(t0 + t1 - t_s, heard, key) for t_s, heard, key in reversed(records)]


def pose_residuals_db(
    model: FilterModel, heards: list[HeardRss], position_m: FloatArray, orientation_deg: FloatArray
) -> tuple[FloatArray, np.ndarray]:
    """Residuals ``rss − expected`` (dB, offset not included) of each packet's
    readings under one pose per packet, concatenated, with each reading's packet
    index. ``position_m`` and ``orientation_deg`` are ``(n, 3)``.

    One call of the model for every packet at once (each packet's expected RSS
    at every receiver heard in the file, then each packet's own picked): the
    same numbers as one call per packet, each pose's lookup being its own."""
    n = len(heards)
    if n == 0:
        return np.empty(0), np.empty(0, dtype=np.int64)
    rx = np.concatenate([np.asarray(h.receiver_index, dtype=np.int64) for h in heards])
    if rx.size == 0:
        return np.empty(0), np.empty(0, dtype=np.int64)
    rss = np.concatenate([np.asarray(h.rss_dbm, dtype=float) for h in heards])
    idx = np.repeat(np.arange(n, dtype=np.int64), [h.n_heard for h in heards])
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M : K.Z_M + 1] = np.asarray(position_m, dtype=float)[:n]
    ori = np.deg2rad(np.asarray(orientation_deg, dtype=float))[:n]
    S[:, K.AZIMUTH_RAD], S[:, K.PITCH_RAD], S[:, K.ROLL_RAD] = ori[:, 0], ori[:, 1], ori[:, 2]
    all_rx = np.unique(rx)
    col = np.zeros(int(all_rx.max()) + 1, dtype=np.int64)
    col[all_rx] = np.arange(all_rx.size)
    return rss - model.expected(S, all_rx)[idx, col[rx]], idx


def mixture_loglik(
    residual_db: FloatArray, offset_db: FloatArray | float, sigma_db: float,
    outlier_probability: float, outlier_range_db: float,
) -> FloatArray:  # fmt: skip
    """Per-reading log-likelihood (nats) of residuals at an offset: the filter's
    Gaussian (σ dB) plus uniform outlier (probability, range dB) mixture.
    ``offset_db`` may be a column ``(m, 1)`` for ``m`` offsets at once."""
    z = (residual_db - offset_db) / sigma_db
    gauss = (1.0 - outlier_probability) * np.exp(-0.5 * z * z) / (math.sqrt(2 * math.pi) * sigma_db)
    return np.asarray(np.log(gauss + outlier_probability / outlier_range_db))


def profile_offset(
    residual_db: FloatArray, sigma_db: float, outlier_probability: float, outlier_range_db: float
) -> float:
    """The offset (dB, on :data:`OFFSET_GRID_DB`) that maximises the summed mixture
    log-likelihood of the residuals (0 if there are none)."""
    if residual_db.size == 0:
        return 0.0
    # a few offsets at a time: the same per-reading values and per-offset sums
    # as the whole grid at once, with the temporaries in cache (≈ 3× faster;
    # docs/performance.md, "Ninth pass")
    ll = np.empty(OFFSET_GRID_DB.size)
    for a in range(0, OFFSET_GRID_DB.size, _PROFILE_ROWS):
        ll[a : a + _PROFILE_ROWS] = mixture_loglik(
            residual_db[None, :], OFFSET_GRID_DB[a : a + _PROFILE_ROWS, None], sigma_db,
            outlier_probability, outlier_range_db,
        ).sum(axis=1)  # fmt: skip
    return float(OFFSET_GRID_DB[int(np.argmax(ll))])


@dataclass(frozen=True)
class Segment:
    """One stretch where the two tracks disagree and the choice made there.

    Attributes
    ----------
    start, stop
        Packet indices ``[start, stop)`` in time order.
    forward_score, reverse_score
        The whole file's log-likelihood (each at its own best single device
        offset) with the forward track, or with the reversed pass's track in
        this segment, minus the jump penalties, nats.
    chose_reverse
        Whether the reversed pass's track was taken there.
    forward_jumps, reverse_jumps
        Jumps of each track at the segment's ends.
    forward_evidence, reverse_evidence
        Each pass's log evidence summed over the segment's packets, nats
        (``nan`` when not given).
    """

    start: int
    stop: int
    forward_score: float
    reverse_score: float
    chose_reverse: bool
    forward_jumps: int = 0
    reverse_jumps: int = 0
    forward_evidence: float = math.nan
    reverse_evidence: float = math.nan


def _poses(ests: list[FilterEstimate]) -> tuple[FloatArray, FloatArray]:
    pos = np.array([e.position_m for e in ests], dtype=float).reshape(-1, 3)
    ori = np.array([e.orientation_deg for e in ests], dtype=float).reshape(-1, 3)
    return pos, ori


def _jumps(
    pos: FloatArray, az: FloatArray, t_s: FloatArray, max_speed_mps: float, max_rate_dps: float
) -> np.ndarray:
    """``(n − 1,)``: whether the step from packet ``i`` to ``i + 1`` is beyond the
    motion model's reach (twice its speed and turn-rate limits over the step,
    at least 0.25 m and 10°)."""
    dt = np.diff(t_s)
    step_m = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
    step_deg = np.abs(angle_diff_deg(az[1:], az[:-1]))
    return np.asarray(
        (step_m > np.maximum(0.25, 2 * max_speed_mps * dt))
        | (step_deg > np.maximum(10.0, 2 * max_rate_dps * dt))
    )


def disagreement_segments(
    fwd_pos: FloatArray, fwd_az: FloatArray, rev_pos: FloatArray, rev_az: FloatArray,
    t_s: FloatArray, disagree_m: float, disagree_deg: float, merge_gap_s: float,
) -> list[tuple[int, int]]:  # fmt: skip
    """Packet ranges ``[start, stop)`` where the tracks are more than ``disagree_m``
    or ``disagree_deg`` (azimuth) apart, ranges less than ``merge_gap_s`` apart joined."""
    bad = (np.linalg.norm(fwd_pos[:, :2] - rev_pos[:, :2], axis=1) > disagree_m) | (
        np.abs(angle_diff_deg(fwd_az, rev_az)) > disagree_deg
    )
    out: list[tuple[int, int]] = []
    i, n = 0, bad.size
    while i < n:
        if not bad[i]:
            i += 1
            continue
        j = i
        while j < n and bad[j]:
            j += 1
        if out and t_s[i] - t_s[out[-1][1] - 1] < merge_gap_s:
            out[-1] = (out[-1][0], j)
        else:
            out.append((i, j))
        i = j
    return out


def _whole_file_ll(residual_db: FloatArray, mix: tuple[float, float, float]) -> float:
    """Summed mixture log-likelihood of residuals at their best single offset, nats."""
    off = profile_offset(residual_db, *mix)
    return float(mixture_loglik(residual_db, off, *mix).sum())


def combine_tracks(
    model: FilterModel,
    records: list[Record],
    forward: dict[object, FilterEstimate],
    reverse: dict[object, FilterEstimate],
    *,
    sigma_db: float,
    outlier_probability: float,
    outlier_range_db: float,
    jump_probability: float,
    max_speed_mps: float,
    max_rate_dps: float,
    disagree_m: float = 1.0,
    disagree_deg: float = 30.0,
    merge_gap_s: float = 0.1,
    evidence: tuple[dict[object, float], dict[object, float]] | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], list[Segment]]:
    """The combined track (module docstring): the forward estimates, except in
    the segments where the reversed pass's track is the more likely.

    Packets without a forward estimate are left out; a packet without a reversed
    one keeps the forward estimate. ``evidence`` (each pass's log evidence of
    each packet by key, forward and reversed, nats) is summed over each
    segment into :class:`Segment` for the record; it does not decide (as a
    second test it kept 7001 right and lost 7030, docs/filter.md round 5).
    Returns ``(key, estimate)`` in time order and the segments with their
    scores.
    """
    rows = [(t_s, h, key) for t_s, h, key in records if key in forward]
    both = [r for r in rows if r[2] in reverse]
    if len(both) < 2:
        return [(key, forward[key]) for _, _, key in rows], []
    t_s = np.array([r[0] for r in both])
    heards = [r[1] for r in both]
    fe = [forward[r[2]] for r in both]
    re = [reverse[r[2]] for r in both]
    fp, fo = _poses(fe)
    rp, ro = _poses(re)
    segs = disagreement_segments(
        fp, fo[:, 0], rp, ro[:, 0], t_s, disagree_m, disagree_deg, merge_gap_s
    )
    chosen = dict(forward)
    if not segs:
        return [(key, chosen[key]) for _, _, key in rows], []
    n = len(both)
    mix = (sigma_db, outlier_probability, outlier_range_db)
    fres, fidx = pose_residuals_db(model, heards, fp, fo)
    rres, ridx = pose_residuals_db(model, heards, rp, ro)
    limits = (max_speed_mps, max_rate_dps)
    fj = _jumps(fp, fo[:, 0], t_s, *limits)
    penalty = math.log(jump_probability)
    f_ll = _whole_file_ll(fres, mix)
    out_segs: list[Segment] = []
    for a, b in segs:
        # each candidate (the forward track, or the reversed one in this segment)
        # with its own device offset, profiled over the whole file
        in_f, in_r = (fidx >= a) & (fidx < b), (ridx >= a) & (ridx < b)
        r_res = np.concatenate([fres[~in_f], rres[in_r]])
        r_ll = _whole_file_ll(r_res, mix)
        # the continuity check: a jump at either end of the segment (the steps
        # into it and out of it; inside it each track is the filter's own)
        ends = [(i, i + 1) for i in (a - 1, b - 1) if i >= 0 and i + 1 < n]
        f_jumps = sum(int(fj[i]) for i, _ in ends)
        r_jumps = 0
        for i, j in ends:
            pi, ai = (rp[i], ro[i, 0]) if i >= a else (fp[i], fo[i, 0])
            pj, aj = (rp[j], ro[j, 0]) if j < b else (fp[j], fo[j, 0])
            step = _jumps(np.vstack([pi, pj]), np.array([ai, aj]), t_s[[i, j]], *limits)
            r_jumps += int(step[0])
        fs = f_ll + penalty * f_jumps
        rs = r_ll + penalty * r_jumps
        f_ev = r_ev = math.nan
        if evidence is not None:
            f_ev = sum(evidence[0].get(r[2], 0.0) for r in both[a:b])
            r_ev = sum(evidence[1].get(r[2], 0.0) for r in both[a:b])
        # the evidence is reported, not used: measured uninformative (docs/filter.md)
        take = rs > fs
        out_segs.append(Segment(a, b, fs, rs, take, f_jumps, r_jumps, f_ev, r_ev))
        if take:
            for r in both[a:b]:
                chosen[r[2]] = reverse[r[2]]
    return [(key, chosen[key]) for _, _, key in rows], out_segs


ReversedRun = tuple[list[tuple[object, FilterEstimate]], dict[object, float]]
"""What :func:`run_reversed` returns: the reversed pass's smoothed estimates
``(key, estimate)`` and its log evidence of each packet by key, nats."""


def reversed_config(config: FilterConfig, centre_db: float) -> tuple[FilterConfig, float]:
    """The reversed pass's settings and offset prior centre (dB) after a forward
    pass whose prior was centred on ``centre_db`` (``nan``: pass 1's wide prior)."""
    if math.isnan(centre_db):
        rcfg, centre = replace(config, offline_offset_selection=False), 0.0
    else:
        rcfg, centre = tight_config(config), centre_db
    return replace(rcfg, offline_reverse_pass=False), centre


def run_reversed(
    pf: ParticleFilter, records: list[Record], centre_db: float, seed: int
) -> ReversedRun:
    """The filter (``pf``'s model, settings and lag, a fresh state) over the
    time-reversed ``records``, its offset prior as after a forward pass centred
    on ``centre_db`` (:func:`reversed_config`), seeded from ``seed`` on a stream
    of its own. Depends on nothing else: it may run before or beside the
    forward pass."""
    rcfg, centre = reversed_config(pf.config, centre_db)
    rev_evidence: dict[object, float] = {}
    rev, _ = run_pass(
        ParticleFilter(pf.model, rcfg, pf.lag_s), (seed + 1) % 2**63, reversed_records(records),
        centre, rev_evidence,
    )  # fmt: skip
    return rev, rev_evidence


def reverse_pass(
    pf: ParticleFilter,
    records: list[Record],
    forward: dict[object, FilterEstimate],
    centre_db: float,
    seed: int,
    sigma_db: float,
    forward_evidence: dict[object, float] | None = None,
    reversed_out: dict[object, FilterEstimate] | None = None,
    precomputed: ReversedRun | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], list[Segment]]:
    """Run the filter over the reversed ``records`` (:func:`run_reversed`) and
    combine its smoothed track with ``forward`` (:func:`combine_tracks`).

    Parameters
    ----------
    pf
        The forward pass's filter (its model, settings and lag are reused).
    records
        Every packet of the device, in time order.
    forward
        The chosen forward pass's smoothed estimate of each packet, by key.
    centre_db
        The chosen forward pass's offset prior centre, dB: ``nan`` for pass 1
        (the configured wide prior around ``devices.csv``'s power), else the
        candidate of the offset selection's tight pass, which the reversed pass
        then shares (:func:`radiopose.filtering.offset.tight_config`).
    seed
        The filter's seed (the reversed pass draws from a stream of its own).
    sigma_db
        σ of the combination's likelihood, dB (the forward filter's estimate).
    forward_evidence
        The chosen forward pass's log evidence of each packet by key, nats
        (reported in the segments, :func:`combine_tracks`; ``None``: not).
    reversed_out
        When given, filled with the reversed pass's own smoothed estimates by
        key (round 6's arbiter refines that track too).
    precomputed
        :func:`run_reversed`'s result for the same ``pf``, ``records``,
        ``centre_db`` and ``seed`` (e.g. from a forked child,
        :mod:`radiopose.filtering.forked`); ``None``: run it here.
    """
    cfg = pf.config
    if precomputed is None:
        precomputed = run_reversed(pf, records, centre_db, seed)
    rev, rev_evidence = precomputed
    if reversed_out is not None:
        reversed_out.update(rev)
    return combine_tracks(
        pf.model, records, forward, dict(rev),
        sigma_db=sigma_db,
        outlier_probability=cfg.outlier_probability,
        outlier_range_db=cfg.outlier_range_db,
        jump_probability=cfg.jump_probability,
        max_speed_mps=cfg.max_speed_mps,
        max_rate_dps=cfg.max_rate_dps,
        disagree_m=cfg.reverse_disagree_m,
        disagree_deg=cfg.reverse_disagree_deg,
        evidence=None if forward_evidence is None else (forward_evidence, rev_evidence),
    )  # fmt: skip


def reversed_tracks3d(
    pf: ParticleFilter3d, records: list[Record], seed: int, members: bool
) -> list[list[tuple[object, FilterEstimate]]]:
    """The 3-D filter's pass over the time-reversed packets (offline; docs/pose3d.md,
    "Reversed pass, 2026-11-27"): smoothed tracks ``(key, estimate)`` of the same
    packets, to be refined as more starts by
    :func:`radiopose.filtering.refine3d.refine_smoothed`.

    A fresh filter with ``pf``'s model, settings and lag runs over
    :func:`reversed_records` from a new state seeded ``seed``. The 3-D motion
    model is time-reversible: x, y nearly constant velocity and azimuth constant
    turn rate (their velocity and rate come out negated, which the pose
    estimates do not read), height, pitch and roll random walks (symmetric,
    reflected at the same supports). The optional heading prior is not (it
    ties the azimuth to the velocity, which the reversal negates), so the
    reversed pass runs without it. Returns the pass's own smoothed track (the
    offset bank's chosen member by its whole-track evidence) and, with
    ``members`` and the offset bank on, each bank member's own smoothed track.
    """
    p3 = replace(pf.pose3d, heading_prior_deg=0.0)  # not time-reversible: off
    return pass_tracks3d(pf, reversed_records(records), seed, members, p3)


def pass_tracks3d(
    pf: ParticleFilter3d,
    records: list[Record],
    seed: int,
    members: bool,
    pose3d: Pose3dConfig | None = None,
) -> list[list[tuple[object, FilterEstimate]]]:
    """A fresh filter with ``pf``'s model, settings and lag (its 3-D settings
    replaced by ``pose3d`` if given) over ``records`` (in the given order and
    times) from a new state seeded ``seed``: its smoothed track (the offset
    bank's chosen member by evidence) and, with ``members`` and the offset bank
    on, each member's own smoothed track."""
    from radiopose.filtering.particle3d import FilterState3d, ParticleFilter3d

    rpf = ParticleFilter3d(pf.model3d, pf.config, pf.lag_s, pose3d or pf.pose3d)
    st = rpf.new_state(seed)
    if members and isinstance(st, FilterState3d) and st.bank:
        st.bank_smoothed = [[] for _ in st.bank]
    chosen: list[tuple[object, FilterEstimate]] = []
    for t_s, heard, key in records:
        rpf.step(st, t_s, heard, key)
        chosen += rpf.take_smoothed()
    rpf.flush(st)
    chosen += rpf.take_smoothed()
    out = [chosen]
    if isinstance(st, FilterState3d) and st.bank_smoothed is not None:
        out += st.bank_smoothed
        st.bank_smoothed = None
    return out


__all__ = [
    "OFFSET_GRID_DB",
    "Record",
    "ReversedRun",
    "Segment",
    "combine_tracks",
    "disagreement_segments",
    "mixture_loglik",
    "pass_tracks3d",
    "pose_residuals_db",
    "profile_offset",
    "reverse_pass",
    "reversed_config",
    "reversed_records",
    "reversed_tracks3d",
    "run_reversed",
]
