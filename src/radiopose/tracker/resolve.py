"""The live re-solve of a track's start (``FilterConfig.live_resolve_times_s``).

Issue 15, session 25 (docs/filter.md, "The live re-solve"). The live server
runs ``filter`` causally with a fixed lag (0.25 s): a packet's estimate is
emitted once a packet at least the lag later has been processed. In a track's
first half second the particle filter often holds a wrong mode that the
offline passes — forward and time-reversed passes, the coarse-grid HMM and the
batch MAP arbiter, which batch ``locate`` runs over a whole file — would not
pick from the same packets. This module runs those passes in the live path,
within the lag:

* at each time ``r`` of ``live_resolve_times_s`` after a track's first packet,
  the track's packets so far are re-solved by the offline passes (one serial
  run: no forked child inside the server; :func:`resolve_track`);
* the estimates the smoother still holds (every packet not yet emitted) are
  replaced by the re-solve's when they are emitted, so each packet's estimate
  uses only packets up to the time it is emitted, as the smoother's own;
* where the re-solve's estimate of the current packet lies more than
  :data:`RESEED_M` or :data:`RESEED_DEG` from the filter's, the particles are
  re-seeded around it (:meth:`ParticleFilter.reseed
  <radiopose.filtering.particle.ParticleFilter.reseed>`), so the track goes on
  from the re-solved pose.

The default times are every 0.05 s from 0.25 to 0.5 s, then every 0.25 s to
1.5 s, with no gate on the filter's σ estimate (session 26; session 25's
default stopped at 0.5 s and ran only at σ ≤ 1.5 dB).
``FilterConfig.live_resolve_every_s`` (an option, off) goes on re-solving the
track's last ``live_resolve_window_s`` periodically. A re-solve of n packets
costs about 40 ms + (2.5–5 ms) × n of one core.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from radiopose.filtering import FilterEstimate, FilterState, ParticleFilter
from radiopose.likelihood import HeardRss
from radiopose.tracker.config import filter_config
from radiopose.tracker.protocol import Device
from radiopose.units import angle_diff_deg

if TYPE_CHECKING:
    from radiopose.tracker.filter import FilterMethod

RESEED_M = 1.0
"""A re-solve whose pose of the current packet is this far (metres) from the
filter's re-seeds the particles."""

RESEED_DEG = 30.0
"""… or whose azimuth differs by this much (degrees)."""

RESOLVE_LAG_S = 1.0
"""The re-solve's smoothing lag, seconds (batch ``locate``'s default; its
arbiter re-emits every packet whatever the lag)."""

RESEED_SHARE = 0.5
"""Share of the particles a re-seed replaces."""

RESEED_PRIOR = 0.2
"""Prior probability that the re-solve holds the device where it and the
filter disagree: the re-seeded particles' mass before the evidence window
weighs them against the filter's own (:meth:`ParticleFilter.reseed
<radiopose.filtering.particle.ParticleFilter.reseed>`)."""

VELOCITY_SPAN_S = 0.1
"""The re-seed's velocity and turn rate: the re-solved track's over this span, seconds."""


@dataclass
class LiveResolve:
    """One track's re-solve state (kept in ``FilterState.resolve``; picklable).

    Attributes
    ----------
    start_s
        The track's first packet time, seconds.
    records
        ``(t_s, heard, packet_id)`` of the track's packets up to its last
        re-solve time (then cleared; with the periodic re-solve, those of its
        window).
    done
        How many of the re-solve times have passed.
    overrides
        Re-solved estimates by ``(packet_id, t_s)``, used when the smoother
        emits that packet (then removed).
    last_s
        The periodic re-solve's last time, seconds (NaN before it; also in a
        state pickled before session 26, which had no such attribute).
    solver
        The start's re-solves' :class:`Solver` over ``records`` (not pickled;
        ``None`` outside the schedule).
    """

    start_s: float
    records: list[tuple[float, HeardRss, str]] = field(default_factory=list)
    done: int = 0
    overrides: dict[object, FilterEstimate] = field(default_factory=dict)
    last_s: float = math.nan
    solver: Solver | None = field(default=None, repr=False, compare=False)

    def __getstate__(self) -> dict[str, object]:
        # the solver (the re-solve's forward state, with the site's model) is
        # not checkpointed: a restored track steps its records again, with the
        # same results (Solver)
        return {**self.__dict__, "solver": None}

    def __setstate__(self, state: dict[str, object]) -> None:
        # a state pickled before session 26 has neither last_s nor solver
        self.__dict__.update({"last_s": math.nan, "solver": None, **state})


class Solver:
    """The offline passes of batch ``locate`` over a growing prefix of one
    device's packets, without stepping the prefix again (:func:`resolve_track`
    re-steps it).

    :meth:`solve` steps the records not yet stepped through the forward pass
    and runs the whole-file passes on a copy of its state, so the next call
    goes on from where this one stopped: the results equal a fresh
    :func:`resolve_track` over the same records (the steps are the same calls
    on the same state), at the cost of one forward pass over the track in all
    instead of one per re-solve (the forward steps are about half a
    re-solve's time). The settings: the device's filter settings with the
    offset selection, the reversed pass and the arbiter on (the live server's
    settings may say off: they are batch ``locate``'s switches), and no forked
    child.
    """

    def __init__(self, device: Device) -> None:
        from radiopose.tracker.filter import FILTER

        fcfg = replace(
            filter_config(device.config),
            offline_offset_selection=True,
            offline_reverse_pass=True,
            offline_refine=True,
            offline_workers=1,
            live_resolve_times_s=(),
            live_resolve_every_s=0.0,
        )
        self.device = Device(
            device.site,
            device.transmitter,
            device.key,
            device.space,
            device.scorer,
            replace(device.config, filter=fcfg),
            RESOLVE_LAG_S,
            {},
            offline=True,
        )
        self.method: FilterMethod = FILTER
        self.method.prepare(self.device)
        self.state: FilterState = self.method.new_state(self.device)
        self.n_stepped = 0
        self.last_key: object = None

    def solve(self, records: list[tuple[float, HeardRss, str]]) -> dict[object, FilterEstimate]:
        """``{(packet_id, t_s): estimate}`` over ``records``, of which the first
        :attr:`n_stepped` must be the records of the previous calls.

        Raises
        ------
        ValueError
            ``records`` does not extend the previous calls' records.
        """
        n = self.n_stepped
        if len(records) < n or (n and (records[n - 1][2], records[n - 1][0]) != self.last_key):
            raise ValueError("a Solver's records must extend its previous calls' records")
        for t_s, heard, packet_id in records[n:]:
            self.method.step(self.device, self.state, heard, t_s, packet_id)
        self.n_stepped = len(records)
        if records:
            self.last_key = (records[-1][2], records[-1][0])
        state = copy.deepcopy(self.state)  # the whole-file passes consume their state
        return dict(self.method.flush_estimates(self.device, state))


def resolve_track(
    device: Device, records: list[tuple[float, HeardRss, str]]
) -> dict[object, FilterEstimate]:
    """The offline passes of batch ``locate`` over ``records`` (one device's
    packets in time order), run serially, as ``{(packet_id, t_s): estimate}``
    (:class:`Solver`'s settings; a fresh one)."""
    return Solver(device).solve(records)


def live_resolve_step(
    device: Device,
    state: FilterState,
    t_s: float,
    heard: HeardRss,
    packet_id: str,
    est: FilterEstimate | None,
    starts: bool,
    smoothed: list[tuple[object, FilterEstimate]],
) -> list[tuple[object, FilterEstimate]]:
    """The live filter's step after its particle filter's (module docstring):
    ``smoothed`` (the estimates the smoother emits at this packet) with the
    re-solved ones in their place; re-solves and re-seeds when due. ``starts``:
    this packet began a new track (the old one's estimates are in ``smoothed``)."""
    from radiopose.tracker.filter import live_overridden

    smoothed = live_overridden(state, smoothed)  # (the previous track's too)
    if starts:
        state.resolve = LiveResolve(t_s) if est is not None else None
    rs: LiveResolve | None = state.resolve
    if rs is None or est is None:
        return smoothed
    cfg = device.engine.config  # the filter's FilterConfig (filter_config's)
    times = cfg.live_resolve_times_s
    every_s = cfg.live_resolve_every_s
    if 0 < rs.done < len(times) and not rs.records:
        # a state whose schedule ended under shorter times (a checkpoint of an
        # older default, or times edited since): its records were cleared, so it
        # is not restarted from this packet
        rs.done = len(times)
    periodic = rs.done >= len(times)
    if periodic:
        if not every_s > 0:
            return smoothed
        # periodic: the last live_resolve_window_s of the track, every every_s
        rs.records.append((t_s, heard, packet_id))
        last_s = rs.last_s
        if math.isnan(last_s):  # (a state whose schedule ended before last_s existed)
            last_s = rs.start_s + (times[-1] if times else 0.0)
        if t_s - last_s < every_s:
            return smoothed
        rs.last_s = t_s
        lo = t_s - cfg.live_resolve_window_s
        rs.records = [r for r in rs.records if r[0] >= lo]
        records = rs.records
    else:
        rs.records.append((t_s, heard, packet_id))
        if t_s - rs.start_s < times[rs.done]:
            return smoothed
        while rs.done < len(times) and t_s - rs.start_s >= times[rs.done]:
            rs.done += 1
        records = rs.records  # (a solve keeps no reference to it)
        if rs.done >= len(times):
            rs.last_s = t_s
            if not every_s > 0:
                rs.records = []
    solver = rs.solver
    if rs.done >= len(times):
        rs.solver = None  # the schedule's last re-solve: its forward state is not needed after
    gate = cfg.live_resolve_max_sigma_db
    if gate is not None and math.sqrt(state.sigma2_db2) > gate:
        return smoothed  # too noisy for a third of a second to beat the filter
    if periodic:  # a window, not a prefix: a fresh solve
        solved = resolve_track(device, records)
    else:
        solver = solver or Solver(device)
        solved = solver.solve(records)
        if rs.done < len(times):
            rs.solver = solver
    rs.overrides.update(solved)
    smoothed = live_overridden(state, smoothed)
    # the re-solve's estimates of packets the smoother has emitted (every packet at
    # least the lag before this one) are never used: dropped, so a long track with
    # the periodic re-solve does not accumulate them
    lag_s = device.engine.lag_s
    for key in [k for k in rs.overrides if k[1] < t_s - lag_s]:  # type: ignore[index]
        del rs.overrides[key]
    now = solved.get((packet_id, t_s))
    if now is not None and _far(now, est):
        pf: ParticleFilter = device.engine
        velocity, rate = _motion(solved)
        pf.reseed(state, t_s, now, velocity, rate, RESEED_SHARE, RESEED_PRIOR)
    return smoothed


def _far(a: FilterEstimate, b: FilterEstimate) -> bool:
    d_m = math.hypot(a.position_m[0] - b.position_m[0], a.position_m[1] - b.position_m[1])
    d_deg = abs(float(angle_diff_deg(a.orientation_deg[0], b.orientation_deg[0])))
    return d_m > RESEED_M or d_deg > RESEED_DEG


def _motion(solved: dict[object, FilterEstimate]) -> tuple[tuple[float, float], float]:
    """Velocity (m/s) and turn rate (°/s) of the re-solved track over its last
    :data:`VELOCITY_SPAN_S` (zero when it is shorter)."""
    timed = sorted(
        ((k[1], e) for k, e in solved.items() if isinstance(k, tuple)),  # (packet_id, t_s)
        key=lambda te: te[0],
    )
    if len(timed) < 2:
        return (0.0, 0.0), 0.0
    t1, e1 = timed[-1]
    t0, e0 = next(((t, e) for t, e in reversed(timed) if t1 - t >= VELOCITY_SPAN_S), timed[0])
    dt = t1 - t0
    if dt <= 0:
        return (0.0, 0.0), 0.0
    vx = (e1.position_m[0] - e0.position_m[0]) / dt
    vy = (e1.position_m[1] - e0.position_m[1]) / dt
    turn = float(angle_diff_deg(e1.orientation_deg[0], e0.orientation_deg[0]))
    return (vx, vy), turn / dt


__all__ = [
    "RESEED_DEG",
    "RESEED_M",
    "LiveResolve",
    "Solver",
    "live_resolve_step",
    "resolve_track",
]
