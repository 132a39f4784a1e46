"""The ``lms`` baseline as a tracker method: log-distance least squares per packet.

Position only (:mod:`radiopose.baselines`); its orientation columns are 0, 0, 0
and are not estimates. It reads the raw RSS, needs no scorer and keeps the
paper methods' :class:`~radiopose.tracker.paper.TrackState` (only the times
and last position matter).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from radiopose.baselines import LmsLocator
from radiopose.likelihood import HeardRss
from radiopose.tracker.paper import TrackState, advance
from radiopose.tracker.protocol import Device, Evidence, Outcome, Step, guard


@dataclass(frozen=True)
class LmsMethod:
    """The paper's ``lms`` comparison method (see the module docstring)."""

    name: str = "lms"
    label: str = "log-distance least squares (position only)"
    evidence: frozenset[Evidence] = frozenset({Evidence.RSS})
    estimates_orientation: bool = False
    acquires: bool = False
    lagged: bool = False
    state_type: type = field(default=TrackState)

    def prepare(self, device: Device) -> None:
        """The site's log-distance fit, shared by the tracker's devices (built on first use)."""

    def new_state(self, device: Device) -> TrackState:
        return TrackState()

    def step(
        self, device: Device, state: TrackState, heard: HeardRss, t_s: float, packet_id: str
    ) -> Step:
        skip = guard(state, heard, t_s, device.config.min_receivers)
        if skip is not None:
            return skip
        locator = device.shared.get("lms")
        if locator is None:
            locator = device.shared["lms"] = LmsLocator.for_site(device.site)
        pos = locator.locate(heard.receiver_index, heard.rss_dbm, device.space.tx_power_dbm)
        out = Outcome(tuple(float(x) for x in pos), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
        return Step(advance(state, t_s, out), out)

    def flush(self, device: Device, state: TrackState) -> tuple[()]:
        return ()


LMS = LmsMethod()
