"""The ``filter`` method: the adapter onto :class:`radiopose.filtering.ParticleFilter`.

Beyond the paper (docs/filter.md). One particle filter per device, built from
the device's candidate space and scorer (the scorer serves the filter's
re-entry of grid hypotheses). Its state is a
:class:`~radiopose.filtering.FilterState`, mutated in place by each step
(picklable, for live checkpoints).

Lag: with ``Device.lag_s = None`` the step returns its packet's causal
estimate. With a lag ``L`` (seconds) the fixed-lag smoother holds each
packet's estimate back: a step returns ``PENDING`` for its packet and the
smoothed estimates of the earlier packets at or before ``t − L``; a new track
(after a silence of ``FilterConfig.reacquire_gap_s``) and :meth:`FilterMethod.flush`
emit the rest. Offline :func:`~radiopose.tracker.locate` uses
``TrackerConfig.smoothing_lag_s`` (1 s); the live server ``LiveConfig.live_lag_s``
(0.25 s).

Offline (``Device.offline``, batch ``locate`` with a lag) the step also keeps
each packet, and :meth:`FilterMethod.flush` may replay them around candidate
device-level power offsets and re-emit every packet's estimate from the pass
whose marginal likelihood of the whole file is largest
(:mod:`radiopose.filtering.offset`; issue 15, unknown transmit power).
"""

from __future__ import annotations

import math
import weakref
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from radiopose.filtering import FilterEstimate, FilterModel, FilterState, ParticleFilter
from radiopose.filtering.forked import (
    ForkedCall,
    effective_workers,
    map_forked,
    result_or_none,
    try_fork,
)
from radiopose.filtering.offset import OffsetPass, select_offset
from radiopose.filtering.restart3d import midtrack_tracks3d
from radiopose.filtering.reverse import ReversedRun, reverse_pass, reversed_tracks3d, run_reversed
from radiopose.likelihood import HeardRss
from radiopose.site import Site, site_is_3d
from radiopose.tracker.config import filter_config
from radiopose.tracker.protocol import (
    Delayed,
    Device,
    Evidence,
    Method,
    Outcome,
    Step,
    needs_scorer,
)
from radiopose.tracker.reasons import (
    PENDING,
    SKIP_NO_TRACK,
    SKIP_OUT_OF_ORDER,
    SKIP_TOO_FEW_RECEIVERS,
)

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import FilterModel3d, ParticleFilter3d, Pose3dConfig
    from radiopose.filtering.refine2d import Refined2d
    from radiopose.filtering.refine3d import CoarseStart


@dataclass(frozen=True)
class FilterMethod:
    """The Bayesian tracker (see the module docstring)."""

    name: str = "filter"
    label: str = "Bayesian tracker: particle filter with a fixed-lag smoother"
    evidence: frozenset[Evidence] = frozenset({Evidence.RSS, Evidence.DENSE})
    estimates_orientation: bool = True
    acquires: bool = False
    lagged: bool = True
    state_type: type = field(default=FilterState)

    def prepare(self, device: Device) -> None:
        # pose3d: a site with a height range or several pitches/rolls gets the 3-D filter
        if site_is_3d(device.site):
            from radiopose.filtering.particle3d import ParticleFilter3d

            p3 = device.config.pose3d  # [filter.pose3d] of the site's tracker.toml
            if device.offline and device.lag_s is not None:
                # batch locate with the smoother: Pose3dConfig.offline_n_particles
                # (its reversed pass and restarts reuse these settings)
                p3 = p3.offline()
            model3d = _shared_model3d(device, p3)
            cfg = filter_config(device.config)
            device.engine = ParticleFilter3d(model3d, cfg, device.lag_s, p3)
            return
        assert device.scorer is not None
        model = FilterModel.build(device.site, device.space, device.scorer)
        device.engine = ParticleFilter(model, filter_config(device.config), device.lag_s)

    def new_state(self, device: Device) -> FilterState:
        pf: ParticleFilter = device.engine
        return pf.new_state(filter_seed(device.config.seed, device.key))

    def step(
        self, device: Device, state: FilterState, heard: HeardRss, t_s: float, packet_id: str
    ) -> Step:
        pf: ParticleFilter = device.engine
        if state.last_time_s is not None and t_s < state.last_time_s:
            return Step(state, Outcome(reason=SKIP_OUT_OF_ORDER))
        if heard.n_heard == 0:
            return Step(state, Outcome(reason=SKIP_TOO_FEW_RECEIVERS))
        if _refines(device):
            _record_members(device, state)
        before = state.log_evidence
        resolves = _live_resolves(device)
        starts = resolves and pf.starts_track(state, t_s)
        est = pf.step(state, t_s, heard, (packet_id, t_s))
        if _replays(device):  # issue 15: the offline offset selection's record
            if state.records is None or state.beliefs_db is None:
                state.records, state.beliefs_db = [], []
            state.records.append((t_s, heard, (packet_id, t_s)))
            state.beliefs_db.append(est.offset_db if est is not None else math.nan)
        smoothed = pf.take_smoothed()
        if resolves:  # session 25: the live re-solve of a track's start
            from radiopose.tracker.resolve import live_resolve_step

            smoothed = live_resolve_step(
                device, state, t_s, heard, packet_id, est, starts, smoothed
            )
        if _refines(device):  # 3-D, offline: the batch refinement's record
            if state.records is None or state.refine_smoothed is None:
                state.records, state.refine_smoothed = [], []
            state.records.append((t_s, heard, (packet_id, t_s)))
            state.refine_smoothed.extend(smoothed)
        if _reverses(device) or _arbitrates(device):  # rounds 5, 6: the whole forward track
            ahead = device.shared.get(_ahead_key(device))
            if isinstance(ahead, _LookAhead) and ahead.pending() and _core_free(device):
                seed = filter_seed(device.config.seed, device.key)
                ahead.start(partial(run_reversed, pf, ahead.records, math.nan, seed))
            if state.forward_kept is None:
                state.forward_kept = []
            state.forward_kept += smoothed
            if state.forward_evidence is None:
                state.forward_evidence = {}
            state.forward_evidence[(packet_id, t_s)] = state.log_evidence - before
        earlier = _as_delayed(smoothed)
        if est is None:
            return Step(state, Outcome(reason=SKIP_NO_TRACK), earlier)
        if pf.lag_s is not None:
            return Step(state, Outcome(reason=PENDING), earlier)
        return Step(state, _outcome(est), earlier)

    def look_ahead(
        self,
        device: Device,
        state: FilterState,
        packets: Sequence[tuple[float, HeardRss, str]],
    ) -> None:
        """Offline (batch ``locate``): every packet ``(t_s, heard, packet_id)`` of
        the device before its first step. With the reversed pass on and
        ``FilterConfig.offline_workers`` ≥ 2 (and a second core), the reversed
        pass over these packets starts in a forked child after the first
        forward step (the compiled kernels loaded by then, shared with it),
        beside the forward pass (at most ``offline_workers − 1`` such children
        at once over the tracker's devices: a later device's starts when one
        ends); :meth:`flush` takes its result if the packets
        the forward pass kept are these and pass 1 stood (the reversed pass of
        a further offset-selection pass has another prior: then it runs there,
        as without a look-ahead). The estimates do not change."""
        if not (_reverses(device) and effective_workers(device.config.filter.offline_workers) > 1):
            return
        records: list[tuple[float, HeardRss, object]] = []
        last = state.last_time_s
        for t_s, heard, packet_id in packets:
            if heard.n_heard == 0 or (last is not None and t_s < last):
                continue  # as the step skips it
            records.append((t_s, heard, (packet_id, t_s)))
            last = t_s
        old = device.shared.pop(_ahead_key(device), None)
        if isinstance(old, _LookAhead):
            old.cancel()
        if records:
            device.shared[_ahead_key(device)] = _LookAhead(records)

    def flush(self, device: Device, state: FilterState) -> tuple[Delayed, ...]:
        return _as_delayed(self.flush_estimates(device, state))

    def flush_estimates(
        self, device: Device, state: FilterState
    ) -> list[tuple[object, FilterEstimate]]:
        """:meth:`flush` as the filter's ``((packet_id, t_s), estimate)`` pairs
        (with their power offsets), for :mod:`radiopose.tracker.resolve`."""
        ahead = device.shared.pop(_ahead_key(device), None)
        try:
            out = self._flush(device, state, ahead if isinstance(ahead, _LookAhead) else None)
            out = live_overridden(state, out)
            rs = getattr(state, "resolve", None)
            if rs is not None:  # a silent device does not keep the re-solve's forward
                rs.solver = None  # state (tens of MB); its next re-solve rebuilds it
            return out
        finally:
            if isinstance(ahead, _LookAhead):
                ahead.cancel()  # not taken (or taken: then a no-op)

    def _flush(
        self, device: Device, state: FilterState, ahead: _LookAhead | None
    ) -> list[tuple[object, FilterEstimate]]:
        pf: ParticleFilter = device.engine
        pf.flush(state)
        if _refines(device) and state.records:
            return _refine(device, state)
        if not (_replays(device) and state.records):
            return pf.take_smoothed()
        # issue 15: offline, the device-level offset chosen by the whole file's
        # marginal likelihood (radiopose.filtering.offset); re-emits every packet
        records, beliefs = state.records, np.asarray(state.beliefs_db, dtype=float)
        state.records = state.beliefs_db = None
        first = pf.take_smoothed()  # pass 1's rest: its earlier packets went out already
        seed = filter_seed(device.config.seed, device.key)
        tight_evidence: dict[object, float] = {}
        other_passes: list[dict[object, FilterEstimate]] = []
        workers = effective_workers(device.config.filter.offline_workers)
        if _selects_offset(device):
            chosen, passes = select_offset(
                pf,
                state,
                seed,
                records,
                first,
                beliefs,
                tight_evidence if _reverses(device) else None,
                other_passes if _arbitrates(device) else None,
                workers,
                _profile_db(device, records, state) if pf.config.offline_offset_profile else None,
            )
        else:
            chosen, passes = first, [OffsetPass(math.nan, state.log_evidence)]
        if not (_reverses(device) or _arbitrates(device)):
            return list(chosen)
        kept, state.forward_kept = state.forward_kept or [], None
        evidence, state.forward_evidence = state.forward_evidence or {}, None
        best = max(range(len(passes)), key=lambda i: (passes[i].log_evidence, -i))
        forward = dict(chosen if best > 0 else kept + chosen)
        sigma_db = math.sqrt(state.sigma2_db2)
        candidates = [forward]
        # session 13 (on by default): the coarse-grid HMM's paths and their
        # refinements on a child meanwhile (here at the end without a child)
        coarse_job: ForkedCall[_CoarseRefined] | None = None
        if pf.config.offline_coarse_track and _arbitrates(device) and workers > 1:
            coarse_job = try_fork(partial(_coarse_refined, pf, records, forward, sigma_db, True))
        try:
            # the offset selection's other passes (pass 1 when a further one won)
            others = [dict(kept + first)] if best > 0 else []
            # (round 8: the offset profile's pass only if it won, unless "always")
            keep_profile = pf.config.offset_profile_track == "always"
            others += [
                t
                for i, t in enumerate(other_passes, start=1)
                if i != best and (keep_profile or not passes[i].from_profile)
            ]
            cache: dict[tuple[object, ...], Refined2d] = {}
            if _reverses(device):
                # round 5: a pass over the reversed packets, combined per segment
                # (run beside the forward pass by the look-ahead when pass 1 stood,
                # else on a child now), while the candidates that do not need it
                # are refined here (round 6; the arbiter below reuses them)
                if ahead is not None and best != 0:
                    ahead.cancel()  # its prior is pass 1's, not the chosen pass's
                    ahead = None
                job: ForkedCall[ReversedRun] | None = None
                if ahead is None and workers > 1 and _arbitrates(device):
                    job = try_fork(partial(run_reversed, pf, records, passes[best].centre_db, seed))
                if _arbitrates(device) and (
                    job is not None or (ahead is not None and not ahead.ready())
                ):
                    _refine_meanwhile(pf, records, [forward, *others], sigma_db, cache, job)
                pre = ahead.take(records) if ahead is not None else result_or_none(job)
                rev: dict[object, FilterEstimate] = {}
                combined, _ = reverse_pass(
                    pf, records, forward, passes[best].centre_db, seed, sigma_db,
                    tight_evidence if best > 0 else evidence, rev, pre,
                )  # fmt: skip
                if not _arbitrates(device):
                    return list(combined)
                candidates += [dict(combined), rev]
                # session 11 (off by default): reversed passes at the runner-up
                # passes' offsets too, as more candidates of the arbiter
                candidates += [
                    dict(r) for r in _more_reversed(pf, records, passes, best, seed, workers)
                ]
        except BaseException:
            if coarse_job is not None:
                coarse_job.cancel()
            raise
        candidates += others
        if coarse_job is not None and not coarse_job.ready():
            # session 14: while the child runs the HMM, the other candidates'
            # refinements here (the same as the arbiter's own below)
            _refine_meanwhile(pf, records, candidates, sigma_db, cache, coarse_job)
        hand = [0.0] * len(candidates)
        if pf.config.offline_coarse_track:
            got = result_or_none(coarse_job)
            if got is None:  # no child (or it failed): its refinement runs with the others
                got = _coarse_refined(pf, records, forward, sigma_db, False)
            candidates += got[0]
            cache.update(got[1])
            # the coarse paths are outsiders: each wins only by coarse_track_margin
            hand += [pf.config.coarse_track_margin] * len(got[0])
        # round 6: each candidate refined by batch MAP, the lowest objective kept;
        # round 7: with the offset's evidence and a refit pass (both off by default)
        from radiopose.filtering.offset_refit import arbitrate_offline

        out, _, _ = arbitrate_offline(
            pf, records, candidates, sigma_db, passes, seed, workers=workers, cache=cache,
            handicaps_nats=hand,
        )  # fmt: skip
        return list(out)


def _more_reversed(
    pf: ParticleFilter,
    records: list[tuple[float, HeardRss, object]],
    passes: list[OffsetPass],
    best: int,
    seed: int,
    workers: int,
) -> list[list[tuple[object, FilterEstimate]]]:
    """The reversed tracks of the offset selection's runner-up passes
    (``FilterConfig.offset_selection_reversed_passes − 1`` of them, largest
    evidence first after the chosen pass ``best``), each over the time-reversed
    packets with that pass's offset prior (:func:`run_reversed`); none when the
    setting is 1 (the default) or the selection ran no further pass."""
    n = pf.config.offset_selection_reversed_passes - 1
    if n <= 0 or len(passes) < 2:
        return []
    order = sorted(range(len(passes)), key=lambda i: (-passes[i].log_evidence, i))
    calls = [partial(run_reversed, pf, records, passes[i].centre_db, seed)
             for i in order if i != best][:n]  # fmt: skip
    return [rev for rev, _ in map_forked(calls, workers)]


def _refine_meanwhile(
    pf: ParticleFilter,
    records: list[tuple[float, HeardRss, object]],
    candidates: list[dict[object, FilterEstimate]],
    sigma_db: float,
    cache: dict[tuple[object, ...], Refined2d],
    job: ForkedCall[Any] | None,
) -> None:
    """The arbiter's refinements of ``candidates`` (``candidates[0]`` its
    reference) into ``cache`` while ``job``'s child works: the arbiter later
    finds them there (the same refinements as its own, so the estimates do not
    change). The child is killed if this raises."""
    # (imported here: scipy.optimize pulls scipy.spatial, which a plain offline
    # locate does not import; tests/test_startup_cache.py)
    from radiopose.filtering.refine2d import arbitrate

    try:
        cfg = pf.config
        arbitrate(pf.model, records, candidates, sigma_db, cfg, cfg.refine_max_nfev, cache=cache)
    except BaseException:
        if job is not None:
            job.cancel()
        raise


_CoarseRefined = tuple[list[dict[object, FilterEstimate]], dict[tuple[object, ...], "Refined2d"]]


def _coarse_refined(
    pf: ParticleFilter,
    records: list[tuple[float, HeardRss, object]],
    reference: dict[object, FilterEstimate],
    sigma_db: float,
    refine: bool,
) -> _CoarseRefined:
    """Session 13: the whole file's coarse-grid HMM paths as more arbiter
    candidates (:func:`_coarse_candidates`) and, with ``refine``, the arbiter's
    refinements of them (:func:`radiopose.filtering.refine2d.refine_for_arbiter`,
    by their cache keys; the arbiter computes them itself otherwise)."""
    cands = _coarse_candidates(pf, records, reference, sigma_db)
    if not refine:
        return cands, {}
    from radiopose.filtering.refine2d import refine_for_arbiter

    cfg = pf.config
    return cands, refine_for_arbiter(
        pf.model, records, reference, cands, sigma_db, cfg, cfg.refine_max_nfev
    )


def _coarse_candidates(
    pf: ParticleFilter,
    records: list[tuple[float, HeardRss, object]],
    reference: dict[object, FilterEstimate],
    sigma_db: float,
) -> list[dict[object, FilterEstimate]]:
    """Session 13: the whole file's coarse-grid HMM paths
    (:func:`radiopose.filtering.coarse_track.coarse_tracks` at ``sigma_db``,
    ``FilterConfig.coarse_track_paths`` of them) as more arbiter candidates:
    ``reference``'s estimates with a path's x, y and azimuth at each packet's
    time (height, pitch and roll kept)."""
    from radiopose.filtering.coarse_track import CoarseSettings, coarse_tracks

    cfg = pf.config
    sig = sigma_db if math.isfinite(sigma_db) else cfg.sigma_prior_db
    settings = CoarseSettings(path_position_step_m=float(cfg.coarse_track_path_step_m))
    cts = coarse_tracks(pf.model, records, max(sig, cfg.sigma_floor_db), cfg.reacquire_gap_s,
                        settings, paths=cfg.coarse_track_paths)  # fmt: skip
    rows = [r for r in records if r[2] in reference]
    if cts[0].window_times_s.size == 0 or not rows:
        return [dict(reference)]
    times_s = np.array([r[0] for r in rows])
    out = []
    for ct in cts:
        xy, az = ct.poses_at(times_s)
        cand = dict(reference)
        for (_, _, key), p, a in zip(rows, xy, az, strict=True):
            e = reference[key]
            cand[key] = replace(
                e,
                position_m=(float(p[0]), float(p[1]), e.position_m[2]),
                orientation_deg=(float(a), e.orientation_deg[1], e.orientation_deg[2]),
            )
        out.append(cand)
    return out


def _profile_db(
    device: Device, records: list[tuple[float, HeardRss, object]], state: FilterState
) -> Callable[[], float]:
    """Round 8: the device's offset by the data alone, computed when the offset
    selection asks (:func:`radiopose.filtering.offset_profile.data_offset_db`
    at the forward filter's σ)."""
    from radiopose.filtering.offset_profile import data_offset_db

    pf: ParticleFilter = device.engine
    return partial(data_offset_db, pf.model, records, math.sqrt(state.sigma2_db2))


def _ahead_key(device: Device) -> str:
    """The key of a device's :class:`_LookAhead` in ``Device.shared``."""
    return f"filter.look_ahead.{device.key}"


class _LookAhead:
    """The reversed pass of one device run in a forked child beside the forward
    pass (:meth:`FilterMethod.look_ahead`): the packets it was given, its job."""

    def __init__(self, records: list[tuple[float, HeardRss, object]]) -> None:
        self.records = records
        self.job: ForkedCall[ReversedRun] | None = None
        self._result: ReversedRun | None = None
        self._done = False

    def start(self, call: Callable[[], ReversedRun]) -> None:
        """Fork the child running ``call`` (:func:`run_reversed` over
        :attr:`records` with pass 1's prior); it is killed when this object is
        dropped untaken (e.g. when ``locate`` raises)."""
        self.job = try_fork(call)
        if self.job is None:  # no child: flush runs the pass
            self._done = True
            return
        weakref.finalize(self, self.job.cancel)

    def pending(self) -> bool:
        """Whether its child is still to be started."""
        return self.job is None and not self._done

    def running(self) -> bool:
        """Whether its child is started and still working."""
        return self.job is not None and not self._done and not self.job.ready()

    def ready(self) -> bool:
        """Whether the child's result can be taken without waiting."""
        return self.job is None or self._done or self.job.ready()

    def wait(self) -> None:
        """Wait for the child's result (kept for :meth:`take`); a failed child
        leaves none."""
        if self._done or self.job is None:
            return
        self._done = True
        self._result = result_or_none(self.job)

    def take(self, records: list[tuple[float, HeardRss, object]]) -> ReversedRun | None:
        """The child's result if it ran over exactly ``records`` (the packets
        the forward pass kept), else ``None`` (then the caller runs it)."""
        if not _same_records(self.records, records):
            self.cancel()
            return None
        self.wait()
        out, self._result = self._result, None
        return out

    def cancel(self) -> None:
        """Kill the child if it still runs; forget its result."""
        if self.job is not None and not self._done:
            self.job.cancel()
        self._done, self._result = True, None


def _core_free(device: Device) -> bool:
    """Whether a look-ahead child may start now: the tracker's running ones
    (one per device) fewer than ``offline_workers − 1``."""
    running = sum(1 for v in device.shared.values() if isinstance(v, _LookAhead) and v.running())
    return running < effective_workers(device.config.filter.offline_workers) - 1


def _same_records(
    a: list[tuple[float, HeardRss, object]], b: list[tuple[float, HeardRss, object]]
) -> bool:
    """Whether two packet lists are the same packets: keys, times and readings."""
    return len(a) == len(b) and all(
        ka == kb
        and ta == tb
        and np.array_equal(ha.receiver_index, hb.receiver_index)
        and np.array_equal(ha.rss_dbm, hb.rss_dbm)
        for (ta, ha, ka), (tb, hb, kb) in zip(a, b, strict=True)
    )


def _outcome(est: FilterEstimate) -> Outcome:
    return Outcome(
        est.position_m, est.orientation_deg, None, est.position_std_m, est.azimuth_std_deg
    )


def _as_delayed(smoothed: list[tuple[object, FilterEstimate]]) -> tuple[Delayed, ...]:
    return tuple(
        Delayed(t_s, packet_id, _outcome(est))
        for (packet_id, t_s), est in cast(
            "list[tuple[tuple[str, float], FilterEstimate]]", smoothed
        )
    )


def _live_resolves(device: Device) -> bool:
    """Whether the live re-solve of a track's start runs for ``device``: the
    filter with a lag at a 2-D site, ``live_resolve_times_s`` set, and no pass
    over the whole file (the live server; batch ``locate`` with the offline
    passes off gives the same, as for the lag itself)."""
    return (
        device.lag_s is not None
        and device.lag_s > 0.0  # lag 0 is the causal filter, as lag None
        and type(device.engine) is ParticleFilter
        and (
            bool(device.engine.config.live_resolve_times_s)
            or device.engine.config.live_resolve_every_s > 0
        )
        and not _replays(device)
    )


def live_overridden(
    state: FilterState, estimates: list[tuple[object, FilterEstimate]]
) -> list[tuple[object, FilterEstimate]]:
    """``estimates`` with those a live re-solve replaced (:mod:`radiopose.tracker.resolve`)."""
    rs = getattr(state, "resolve", None)
    if rs is None or not rs.overrides:
        return estimates
    return [(key, rs.overrides.pop(key, est)) for key, est in estimates]


def _replays(device: Device) -> bool:
    """Whether the offline passes after the first (offset selection, reversed
    pass) may run for ``device``, so that its packets are kept."""
    return _selects_offset(device) or _reverses(device) or _arbitrates(device)


def _offline_2d(device: Device) -> bool:
    """Whether ``device`` is tracked offline (batch ``locate``) with a smoothing
    lag by the 2-D filter: where the passes after the first may run."""
    return device.offline and device.lag_s is not None and type(device.engine) is ParticleFilter


def _reverses(device: Device) -> bool:
    """Whether the offline reversed pass runs for ``device`` (round 5):
    :func:`_offline_2d`, switched on (``FilterConfig.offline_reverse_pass``)."""
    return _offline_2d(device) and device.config.filter.offline_reverse_pass


def _arbitrates(device: Device) -> bool:
    """Whether the offline 2-D batch MAP arbiter runs for ``device`` (round 6):
    :func:`_offline_2d`, switched on (``FilterConfig.offline_refine``)."""
    return _offline_2d(device) and device.config.filter.offline_refine


def _selects_offset(device: Device) -> bool:
    """Whether the offline offset selection runs for ``device``: offline (batch
    ``locate``) with a smoothing lag, switched on
    (``FilterConfig.offline_offset_selection``), a 2-D filter (the 3-D filter
    has its own offset handling): :func:`_offline_2d`."""
    return _offline_2d(device) and device.config.filter.offline_offset_selection


def _refines(device: Device) -> bool:
    """Whether the 3-D batch refinement runs for ``device``: offline (batch
    ``locate``) with a smoothing lag, a 3-D filter, switched on
    (``Pose3dConfig.refine``); never the causal or live filter."""
    from radiopose.filtering.particle3d import ParticleFilter3d

    pf = device.engine
    return (
        device.offline
        and device.lag_s is not None
        and isinstance(pf, ParticleFilter3d)
        and pf.pose3d.refine
    )


def _record_members(device: Device, state: FilterState) -> None:
    """Start recording each bank member's smoothed estimates (before the first
    packet) when the refinement starts from them too."""
    from radiopose.filtering.particle3d import FilterState3d, ParticleFilter3d

    pf = device.engine
    if (
        isinstance(state, FilterState3d)
        and isinstance(pf, ParticleFilter3d)
        and pf.pose3d.refine_from_members
        and state.bank
        and state.bank_smoothed is None
    ):
        state.bank_smoothed = [[] for _ in state.bank]


def _refine(device: Device, state: FilterState) -> list[tuple[object, FilterEstimate]]:
    """Every smoothed estimate of the file, each track refined by batch MAP
    (:func:`radiopose.filtering.refine3d.refine_smoothed`); clears the record."""
    from radiopose.filtering.particle3d import FilterState3d, ParticleFilter3d
    from radiopose.filtering.refine3d import refine_smoothed, segment_misfit_ratio

    pf = device.engine
    assert isinstance(pf, ParticleFilter3d)
    records, smoothed = state.records or [], list(state.refine_smoothed or [])
    smoothed.extend(pf.take_smoothed())
    state.records = state.refine_smoothed = None
    members: list[list[tuple[object, FilterEstimate]]] = []
    if isinstance(state, FilterState3d) and state.bank_smoothed is not None:
        members, state.bank_smoothed = state.bank_smoothed, None
    p3 = pf.pose3d
    if p3.refine_reverse_pass and records:
        # the filter over the time-reversed packets: its smoothed track (and its
        # members') as more starts (docs/pose3d.md, "Reversed pass, 2026-11-27")
        seed = (filter_seed(device.config.seed, device.key) + 1) % 2**63
        members = members + reversed_tracks3d(pf, records, seed, p3.refine_reverse_members)
    if p3.refine_restarts and records:
        # the filter restarted inside the track, forward and reversed from each
        # point (docs/pose3d.md, "Mid-track restarts, 2026-11-27")
        seed = (filter_seed(device.config.seed, device.key) + 2) % 2**63
        members = members + midtrack_tracks3d(
            pf, records, seed, p3.refine_restarts, p3.refine_restart_members
        )

    memo: dict[tuple[object, ...], object] = {}  # solves shared by an escalation's second call

    def refined(
        alternatives: list[list[tuple[object, FilterEstimate]]],
    ) -> list[tuple[object, FilterEstimate]]:
        return refine_smoothed(
            pf.model3d, records, smoothed, pf.config, p3.height_noise_mps, p3.tilt_noise_dps,
            p3.refine_max_nfev, alternatives=alternatives,
            hybrid_segment_s=p3.refine_hybrid_segment_s,
            height_accel_noise_mps2=p3.refine_height_accel_noise_mps2,
            tilt_accel_noise_dps2=p3.refine_tilt_accel_noise_dps2,
            polish_starts=p3.refine_polish_starts, polish_margin=p3.refine_polish_margin,
            polish_switch=p3.refine_polish_switch, anneal_sigma=p3.refine_anneal_sigma,
            anneal_keep_direct=p3.refine_anneal_keep_direct, coarse_start=_coarse_start(pf),
            heading=(
                (p3.refine_heading_deg, p3.heading_prior_time_s, p3.heading_prior_speed_mps)
                if p3.refine_heading_deg > 0 else None
            ),
            memo=memo, orientation_path=p3.refine_orientation_path, band=p3.hand_band(),
        )  # fmt: skip

    out = refined(members)
    if p3.refine_escalate_ratio > 0 and records and not p3.refine_restarts:
        # a poor fit over part of the file: mid-track restarts as more starts
        # (docs/pose3d.md, "Session 17")
        ratio = segment_misfit_ratio(pf.model3d, records, out, pf.config)
        if ratio > p3.refine_escalate_ratio:
            seed = (filter_seed(device.config.seed, device.key) + 2) % 2**63
            more = midtrack_tracks3d(pf, records, seed, p3.refine_escalate_restarts, False)
            out = refined(members + more)
    return out


def _coarse_start(pf: ParticleFilter3d) -> CoarseStart | None:
    """The whole-file coarse HMM's paths as refinement starts, when
    ``Pose3dConfig.refine_coarse_path`` is on (docs/pose3d.md, "A coarse-path
    start, 2026-11-28")."""
    from radiopose.filtering.coarse3d import coarse_paths3d

    p3, grid = pf.pose3d, pf.model3d.coarse
    if not p3.refine_coarse_path or grid is None:
        return None
    return partial(
        coarse_paths3d, grid, walk_m=p3.refine_coarse_walk_m, walk_deg=p3.refine_coarse_walk_deg,
        offset_prior_sd_db=pf.config.offset_prior_sd_db, paths=p3.refine_coarse_paths,
    )  # fmt: skip


def _shared_model3d(device: Device, p3: Pose3dConfig) -> FilterModel3d:
    """The 3-D filter's arrays for ``device`` (:meth:`FilterModel3d.build3d
    <radiopose.filtering.particle3d.FilterModel3d.build3d>`: the height model's
    maps and the coarse acquisition table), built once per pattern, transmit
    power and settings among a tracker's devices (kept in ``device.shared``)
    and shared by the others with their own candidate space: the filter only
    reads them. On the simulated 3-D site a device's build took ≈ 0.6 s and
    35–70 MB."""
    from radiopose.filtering.particle3d import FilterModel3d

    enrolled = device.site.device(device.transmitter)
    models = device.shared.setdefault("filter.model3d", {})
    key = (enrolled.pattern, float(enrolled.tx_power_dbm), p3)
    built = models.get(key)
    if built is not None:
        return replace(built, space=device.space)
    models[key] = model3d = FilterModel3d.build3d(device.site, device.space, p3)
    return model3d


def reads_site_scorer(method: Method, site: Site) -> bool:
    """Whether ``method`` reads the site's scorer at ``site``, so that one must be
    built: a method that needs one (:func:`~radiopose.tracker.protocol.needs_scorer`),
    except the ``filter`` at a 3-D site (it scores its own coarse grid; the
    site's full 3-D candidate table would take minutes and gigabytes to build)."""
    return needs_scorer(method) and not (isinstance(method, FilterMethod) and site_is_3d(site))


def filter_seed(seed: int, transmitter_key: str) -> int:
    """The filter's random seed for one transmitter (``TrackerConfig.seed`` and its key)."""
    return (seed * 1_000_003 + zlib.crc32(transmitter_key.encode())) % 2**63


FILTER = FilterMethod()
