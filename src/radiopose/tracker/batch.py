"""The batch run: a whole packets table through one method (:func:`locate`).

Offline, a lagged method (``filter``) smooths with ``TrackerConfig.smoothing_lag_s``
(the fixed-lag smoother sees up to that much of the future of each packet);
``None`` runs it causally, as the live server does with lag 0.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from radiopose.errors import InputError
from radiopose.estimates import Estimates, PoseEstimate
from radiopose.likelihood import Scorer
from radiopose.likelihood.candidates import receiver_indices
from radiopose.packets import PacketObservation, Packets, check_observation, group_packets
from radiopose.site import Site
from radiopose.tracker.config import TrackerConfig
from radiopose.tracker.protocol import Method
from radiopose.tracker.reasons import PENDING
from radiopose.tracker.stream import Tracker

SKIP_NEVER_EMITTED = "no estimate after the smoothing lag"


@dataclass(frozen=True)
class RunSummary:
    """What a batch run did.

    Attributes
    ----------
    method
        The method run.
    packets_in
        Packets read (distinct transmitter + packet id).
    estimates_out
        Estimates written.
    skipped
        ``(reason, count)`` pairs, most frequent first.
    elapsed_s
        Wall time, seconds.
    """

    method: str
    packets_in: int
    estimates_out: int
    skipped: tuple[tuple[str, int], ...] = field(default=())
    elapsed_s: float = 0.0

    @property
    def coverage(self) -> float:
        """Estimates ÷ packets (0 for no packets)."""
        return self.estimates_out / self.packets_in if self.packets_in else 0.0

    def lines(self) -> list[str]:
        """Human-readable summary lines."""
        out = [
            f"method {self.method}: {self.packets_in} packets in, {self.estimates_out} estimates "
            f"out (coverage {100 * self.coverage:.1f} %) in {self.elapsed_s:.1f} s"
        ]
        out += [f"  skipped {n}: {reason}" for reason, n in self.skipped]
        return out


@dataclass(frozen=True, eq=False)
class LocateResult:
    """Estimates of a batch run and its summary."""

    estimates: Estimates
    summary: RunSummary


def _check_packets(site: Site, packets: Packets) -> list[PacketObservation]:
    if len(packets) == 0:
        raise InputError(
            "no packets (the file has a header but no rows)", path=packets.path, line=2
        )
    obs = group_packets(packets)
    last: dict[str, tuple[float, str]] = {}
    for o in obs:
        check_observation(o, packets.path)
        receiver_indices(o, site.receiver_ids, packets.path)
        key = o.transmitter.lower()
        prev = last.get(key)
        if prev is not None and o.timestamp_s < prev[0]:
            raise InputError(
                f"timestamp {o.timestamp_s:.9g} s of packet {o.packet_id!r} is earlier than the "
                f"previous packet {prev[1]!r} of {o.transmitter} ({prev[0]:.9g} s); packets of "
                "a transmitter must be in time order",
                path=packets.path,
                line=o.line,
                column="timestamp_s",
            )
        last[key] = (o.timestamp_s, o.packet_id)
    enrolled = {d.transmitter.lower() for d in site.devices}
    if not any(o.transmitter.lower() in enrolled for o in obs):
        raise InputError(
            f"no packet is from an enrolled transmitter (first: {obs[0].transmitter!r}; "
            f"devices.csv has {', '.join(d.transmitter for d in site.devices) or 'none'})",
            path=packets.path,
            column="transmitter",
        )
    return obs


def locate(
    site: Site,
    packets: Packets,
    method: str | Method = "full",
    config: TrackerConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    scorers: Mapping[str, Scorer] | None = None,
) -> LocateResult:
    """Run a method over a packets table.

    Parameters
    ----------
    site
        The site.
    packets
        Synchronised packets (``packets.csv`` rows).
    method
        A name of :data:`radiopose.tracker.METHODS` (or a method object).
    config
        Pipeline parameters (paper defaults); a lagged method smooths with
        ``config.smoothing_lag_s``.
    progress
        Called as ``progress(done, total)`` after each packet.
    scorers
        Optional prebuilt scorers by transmitter (see :class:`Tracker`).

    Returns
    -------
    The estimates (one per packet with a valid estimate) and a run summary.

    Raises
    ------
    InputError
        Empty table, columns of different lengths, a timestamp or RSS that is
        not a finite number in range, a receiver not in the site, a receiver
        twice in one packet, time going backwards within a transmitter, or no
        enrolled transmitter at all. Packets of unknown transmitters and packets heard by too few
        receivers are skipped and counted in the summary.
    """
    t0 = time.perf_counter()
    obs = _check_packets(site, packets)
    cfg = config or TrackerConfig()
    tracker = Tracker(site, method, cfg, scorers, lag_s=cfg.smoothing_lag_s, offline=True)
    tracker.look_ahead(obs)  # a method may start on the whole file (the filter's reversed pass)
    found: dict[tuple[str, str], PoseEstimate] = {}
    reasons: list[str | None] = []
    for i, o in enumerate(obs):
        est, reason = tracker.update(o)
        if est is not None:
            found[(est.transmitter.lower(), est.packet_id)] = est
        for d in tracker.take_delayed():
            found[(d.transmitter.lower(), d.packet_id)] = d
        reasons.append(reason)
        if progress is not None:
            progress(i + 1, len(obs))
    for d in tracker.flush():
        found[(d.transmitter.lower(), d.packet_id)] = d
    poses: list[PoseEstimate] = []
    skipped: Counter[str] = Counter()
    for o, reason in zip(obs, reasons, strict=True):
        est = found.get((o.transmitter.lower(), o.packet_id))
        if est is not None:
            poses.append(est)
        else:
            skipped[SKIP_NEVER_EMITTED if reason == PENDING else reason or "unknown"] += 1
    summary = RunSummary(
        tracker.method,
        len(obs),
        len(poses),
        tuple(skipped.most_common()),
        time.perf_counter() - t0,
    )
    return LocateResult(Estimates.from_poses(poses), summary)
