"""What a tracking method is: the :class:`Method` protocol and the types it uses.

A method turns one transmitter's packets into pose estimates. The
:class:`~radiopose.tracker.stream.Tracker` owns everything around it (which
transmitter, which candidate space and scorer, the per-transmitter state
dictionary, out-of-band packets); the method owns its state type and its step.
Every front end (``locate``, the live server and its checkpoints, ``evaluate``,
the CLI, the demo) finds methods in one registry,
:data:`radiopose.tracker.METHODS`; ``docs/methods.md`` shows how to add one.

A method declares:

* ``evidence`` — what it reads of a packet (:class:`Evidence`): the scorer's
  top-k candidates, the scorer itself for dense or windowed scores, or only the
  raw RSS per heard receiver. The tracker builds a scorer only for methods
  that need one.
* ``estimates_orientation`` — whether its orientation columns are estimates
  (``lms`` writes 0, 0, 0; scoring and figures leave them out).
* ``acquires`` — whether ``TrackerConfig.acquisition_window_s`` pools packets
  (and suppresses their estimates) while no previous estimate constrains the
  track.
* ``lagged`` — whether it can hold a packet's estimate back for a fixed lag and
  emit it later (a smoother); then :meth:`Method.step` may return estimates of
  earlier packets and :meth:`Method.flush` emits the rest.
"""

from __future__ import annotations

from collections.abc import MutableMapping, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any, Protocol, runtime_checkable

from radiopose.likelihood import CandidateSpace, HeardRss, Scorer
from radiopose.site import Site
from radiopose.tracker.config import TrackerConfig
from radiopose.tracker.reasons import SKIP_OUT_OF_ORDER, SKIP_TOO_FEW_RECEIVERS


class Evidence(Enum):
    """What a method reads of each packet."""

    TOPK = "topk"
    """The scorer's top-k candidate poses (:meth:`Scorer.score_heard`)."""
    DENSE = "dense"
    """The scorer itself: dense or windowed scores over the candidate grid."""
    RSS = "rss"
    """The raw RSS of each heard receiver (:class:`~radiopose.likelihood.HeardRss`)."""


NEEDS_SCORER = frozenset({Evidence.TOPK, Evidence.DENSE})
"""Evidence that needs a scorer for the transmitter's candidate space."""


@dataclass(frozen=True)
class Outcome:
    """Result of one step for its packet: a pose, or the reason there is none.

    Attributes
    ----------
    position_m, orientation_deg
        ``(x, y, z)`` metres and ``(azimuth, pitch, roll)`` degrees, or ``None``.
    reason
        Why there is no pose (a ``SKIP_*`` string, or ``PENDING`` when a lagged
        method emits this packet's estimate later).
    position_std_m, azimuth_std_deg
        The estimate's uncertainty, metres and degrees (``None``: the method gives none).
    """

    position_m: tuple[float, float, float] | None = None
    orientation_deg: tuple[float, float, float] | None = None
    reason: str | None = None
    position_std_m: float | None = None
    azimuth_std_deg: float | None = None

    @property
    def ok(self) -> bool:
        return self.position_m is not None


@dataclass(frozen=True)
class Delayed:
    """An estimate a lagged method emits for an earlier packet of the same device."""

    timestamp_s: float
    packet_id: str
    outcome: Outcome


@dataclass(frozen=True)
class Step:
    """What :meth:`Method.step` returns.

    Attributes
    ----------
    state
        The device's state after the packet (a new object, or the same one
        mutated, as the method documents).
    outcome
        This packet's pose or the reason there is none now.
    earlier
        Estimates of earlier packets emitted by this step (lagged methods).
    """

    state: Any
    outcome: Outcome
    earlier: tuple[Delayed, ...] = ()


@dataclass(eq=False)
class Device:
    """What a method is given for one transmitter.

    Attributes
    ----------
    site
        The site.
    transmitter
        The transmitter as ``devices.csv`` spells it.
    key
        Lower-case transmitter (the key of ``Tracker.states``).
    space
        The transmitter's candidate space.
    scorer
        Its scorer (``None`` for methods whose evidence needs none).
    config
        Tracker parameters.
    lag_s
        The fixed lag for lagged methods, seconds (``None``: causal).
    shared
        Resources shared by the devices of one tracker (e.g. a site fit), by name.
    engine
        The method's own per-device resources (:meth:`Method.prepare`).
    offline
        Whether the whole file is at hand (batch :func:`~radiopose.tracker.locate`):
        a method may then run several passes at :meth:`Method.flush` (the
        ``filter``'s offline offset selection); never in the live server.
    """

    site: Site
    transmitter: str
    key: str
    space: CandidateSpace
    scorer: Scorer | None
    config: TrackerConfig
    lag_s: float | None = None
    shared: MutableMapping[str, Any] = field(default_factory=dict)
    engine: Any = None
    offline: bool = False


@runtime_checkable
class Method(Protocol):
    """A tracking method (see the module docstring).

    Attributes
    ----------
    name
        Registry name (``--method``), lower case.
    label
        One line for listings.
    evidence
        What it reads of each packet.
    estimates_orientation
        Whether its orientation is an estimate.
    acquires
        Whether the acquisition window applies.
    lagged
        Whether it supports a fixed lag (:meth:`flush` then matters).
    state_type
        The type of its per-device state; a stored state of another type (a
        checkpoint written by another method) is replaced by :meth:`new_state`.
    """

    # read-only members (properties), so that frozen dataclasses satisfy the protocol
    @property
    def name(self) -> str: ...

    @property
    def label(self) -> str: ...

    @property
    def evidence(self) -> frozenset[Evidence]: ...

    @property
    def estimates_orientation(self) -> bool: ...

    @property
    def acquires(self) -> bool: ...

    @property
    def lagged(self) -> bool: ...

    @property
    def state_type(self) -> type: ...

    def prepare(self, device: Device) -> None:
        """Build the method's per-device resources into ``device.engine`` (once)."""
        ...

    def new_state(self, device: Device) -> Any:
        """A fresh per-device state."""
        ...

    def step(self, device: Device, state: Any, heard: HeardRss, t_s: float, packet_id: str) -> Step:
        """Process one packet of the device heard as ``heard`` at ``t_s`` seconds."""
        ...

    def flush(self, device: Device, state: Any) -> tuple[Delayed, ...]:
        """Emit every estimate held back (lagged methods; others return ``()``)."""
        ...


@runtime_checkable
class LooksAhead(Protocol):
    """A method that can use the whole file before its first step (offline).

    Batch :func:`~radiopose.tracker.locate` calls :meth:`look_ahead` once per
    device, before the device's first :meth:`Method.step`, with every packet of
    the device in time order (the ``filter`` starts its time-reversed pass
    there, beside the forward one). The method's outputs must not depend on
    whether it was called; the live server and the streaming ``Tracker``
    never call it.
    """

    def look_ahead(
        self, device: Device, state: Any, packets: Sequence[tuple[float, HeardRss, str]]
    ) -> None:
        """See the class docstring: ``packets`` are ``(t_s, heard, packet_id)``."""
        ...


def guard(state: Any, heard: HeardRss, t_s: float, min_receivers: int) -> Step | None:
    """The skips every :class:`~radiopose.tracker.paper.TrackState` method shares:
    a packet before the previous one (state unchanged) or heard by fewer than
    ``min_receivers`` (the time advances); ``None`` when the packet is usable."""
    if state.last_time_s is not None and t_s < state.last_time_s:
        return Step(state, Outcome(reason=SKIP_OUT_OF_ORDER))
    if heard.n_heard < min_receivers:
        return Step(replace(state, last_time_s=t_s), Outcome(reason=SKIP_TOO_FEW_RECEIVERS))
    return None


def needs_scorer(method: Method) -> bool:
    """Whether the method reads the scorer (top-k or dense scores)."""
    return bool(method.evidence & NEEDS_SCORER)
