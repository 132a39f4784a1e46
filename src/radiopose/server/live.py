"""Live processing: stored frame reports -> synchronised packets -> pose estimates.

The pipeline reads the append-only ``batches`` table in id order (the order
the server stored them) and carries all of its state in one picklable
:class:`PipelineState`:

1. **calibration** — frames are buffered until the reference receiver (the
   first site receiver that reported) spans ``calibration_s`` of its clock
   (or the buffer is full, or reports pause); then each receiver's clock
   offset and drift are estimated (:func:`radiopose.capture.estimate_clocks`);
2. **matching** — the buffered and every later frame go through the bounded
   incremental matcher (:class:`radiopose.capture.StreamingMatcher`, clock
   corrected; chains close when every receiver has moved past them or after
   ``max_lag_s``); when no report arrives for ``idle_flush_s`` after the
   pipeline has processed the last one, the open chains are closed so the
   last packets are not held back;
3. **tracking** — each packet of a transmitter this partition owns goes to
   the streaming :class:`radiopose.tracker.Tracker` running the method of
   :data:`radiopose.tracker.METHODS` named by ``LiveConfig.method`` (one state
   per transmitter, of the method's own type). A lagged method (``filter``)
   runs with the fixed lag ``LiveConfig.live_lag_s`` (at most 0.25 s): a
   packet's estimate is stored once a packet at least that much later has
   been processed, or at the idle flush — so every packet the filter answers
   gets its estimate, trailing the packet by at most the lag (plus the gap to
   the next packet of that transmitter).

Each step's packets and estimates are stored in the same transaction as the
new state (a checkpoint keyed by partition), so after a crash the pipeline
resumes from the last checkpoint and re-derives exactly the outputs that were
not committed: nothing twice, nothing lost. Packet ids are the pipeline's
own running counter, so they stay unique across re-calibrations.

Partitions: with ``partitions = N`` each of N server processes runs the
matcher over all frames (cheap and deterministic, so all agree on packet
ids) but tracks and stores only transmitters with
``sha256(address) mod N == partition``. Nothing here is process-global.
"""

from __future__ import annotations

import hashlib
import logging
import math
import pickle
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from radiopose.capture.records import FrameRecords
from radiopose.capture.streaming import StreamingMatcher
from radiopose.capture.sync import ClockModel, SyncConfig, estimate_clocks
from radiopose.packets import PacketObservation, Packets, group_packets
from radiopose.server.db import Database, StoredBatch
from radiopose.server.sitestore import build_site

if TYPE_CHECKING:  # the tracker (and scikit-learn) load with the first site, not at import
    from radiopose.estimates import PoseEstimate
    from radiopose.server.worker import LiveWorker as LiveWorker  # lazily re-exported below
    from radiopose.site import Site
    from radiopose.tracker import Tracker, TrackerConfig

log = logging.getLogger("radiopose.server.live")

_NS = 1_000_000_000
MAX_LIVE_LAG_S = 0.25
"""The longest fixed lag the live server accepts for a lagged method, seconds."""


@dataclass(frozen=True)
class LiveConfig:
    """Settings of the live pipeline.

    Attributes
    ----------
    method
        Tracker method, a name of :data:`radiopose.tracker.METHODS` (``None``:
        the site's default, :func:`radiopose.tracker.default_live_method`:
        ``full`` at a 2-D site, ``filter`` at a 3-D one).
    tracker
        Tracker parameters (``None``: the tracker's defaults, kernel included).
    live_lag_s
        Fixed lag of a lagged method (``filter``'s smoother), seconds, in
        ``[0, MAX_LIVE_LAG_S]``; 0 runs it causally. Other methods ignore it.
    lagged_commit_s
        With a lagged method, output is committed at most this often, seconds;
        other methods commit every step with output.
    lagged_checkpoint_s
        With a lagged method, the checkpoint (which then carries each device's
        smoother lineage: about 0.6 MB a ``filter`` device at 10 packets/s) is
        written at most this often, seconds; the output committed in between
        is re-derived after a crash and, being stored already, kept once
        (the database inserts outputs idempotently).
    tolerance_s
        Matching tolerance on the reference clock, seconds.
    max_lag_s
        A packet is closed at the latest when the most advanced receiver is
        this far past it (bounds memory and the wait for a silent receiver), s.
    calibration_s
        Reference-receiver clock span buffered before estimating clocks, s.
    calibration_max_frames
        Buffer at most this many frames before estimating clocks.
    catchup_after_s, catchup_lag_s, catchup_wait_s
        Reports that pause for more than ``catchup_after_s`` (by their arrival
        times: a server outage or restart, a network cut) are followed by a
        catch-up: the agents deliver their spools each at its own pace, so until
        every receiver that reported before the pause is again within
        ``max_lag_s`` of the most advanced one (or ``catchup_wait_s`` of arrivals
        have passed: one that does not come back is not waited for), packets close
        at the latest ``catchup_lag_s`` behind it instead of ``max_lag_s``.
    clock_refresh_s, clock_window_s
        After the calibration, the receivers' clocks are estimated again every
        ``clock_refresh_s`` seconds of reference-clock time from the frames of
        the last ``clock_window_s`` seconds (a clock drifts, NTP slews it, a
        receiver joins late or reboots), and as soon as a receiver without a
        clock model has ``calibration_s`` of frames. A step of a clock is not
        followed: a backward one costs that receiver's frames until the next
        re-estimate, a forward one beyond ``max_lag_s`` makes the others'
        frames late (the matcher's horizon moves with the most advanced
        receiver).
    idle_flush_s
        Close open packets (and end calibration) after this long without a
        new batch, wall seconds, counted from the end of the step that
        processed the last one.
    checkpoint_s
        A step without new packets writes its checkpoint at most this often,
        seconds (a step with packets always does, with them).
    batches_per_step
        Batches read per step.
    poll_s
        Wait between polls of the database when idle, seconds.
    partition, partitions
        This worker's partition of the transmitters (see module docstring).
    """

    method: str | None = None
    tracker: TrackerConfig | None = None
    live_lag_s: float = MAX_LIVE_LAG_S
    tolerance_s: float = 0.005
    max_lag_s: float = 5.0
    calibration_s: float = 3.0
    calibration_max_frames: int = 20_000
    clock_refresh_s: float = 10.0
    clock_window_s: float = 30.0
    catchup_after_s: float = 5.0
    catchup_lag_s: float = 120.0
    catchup_wait_s: float = 60.0
    idle_flush_s: float = 5.0
    checkpoint_s: float = 1.0
    lagged_commit_s: float = 0.25
    lagged_checkpoint_s: float = 5.0
    batches_per_step: int = 200
    poll_s: float = 0.05
    partition: int = 0
    partitions: int = 1

    def __post_init__(self) -> None:
        for name in ("catchup_after_s", "catchup_lag_s", "catchup_wait_s"):
            if not 0.0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.catchup_lag_s < self.max_lag_s:
            raise ValueError(
                f"catchup_lag_s ({self.catchup_lag_s!r}) must be >= max_lag_s ({self.max_lag_s!r})"
            )
        if not (0.0 < self.clock_refresh_s < math.inf and 0.0 < self.clock_window_s < math.inf):
            raise ValueError(
                f"clock_refresh_s and clock_window_s must be > 0, got {self.clock_refresh_s!r} "
                f"and {self.clock_window_s!r}"
            )
        for name in ("lagged_commit_s", "lagged_checkpoint_s"):
            if not 0.0 <= getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.live_lag_s <= MAX_LIVE_LAG_S:
            raise ValueError(
                f"live_lag_s must lie in [0, {MAX_LIVE_LAG_S}] s, got {self.live_lag_s!r}"
            )

    def method_for(self, site: Site) -> str:
        """The method's name at ``site``: :attr:`method`, else the site's
        default (:func:`radiopose.tracker.default_live_method`)."""
        if self.method is not None:
            return self.method
        from radiopose.tracker import default_live_method

        return default_live_method(site)

    @property
    def partition_key(self) -> str:
        return f"{self.partition}/{self.partitions}"

    def owns(self, transmitter: str) -> bool:
        """Whether this partition tracks ``transmitter``."""
        if self.partitions == 1:
            return True
        digest = hashlib.sha256(transmitter.lower().encode()).digest()
        return int.from_bytes(digest[:8], "big") % self.partitions == self.partition


@dataclass
class ClockWindow:
    """The schedule of the receivers' clock re-estimates (:class:`LivePipeline`).

    Attributes
    ----------
    first_batch
        Id of the first stored batch whose frames the next re-estimate reads.
    newest_ns
        Newest reference-clock time seen since the calibration, ns.
    due_ns
        Reference-clock time of the next re-estimate, ns.
    unclocked_since_ns
        Per receiver without a clock model, the reference time of its first
        frame since the last re-estimate, ns (one is tried as soon as it has
        ``calibration_s`` of frames).
    starts
        The first batches of the last :data:`LONG_LOOK_REFRESHES` re-estimates'
        windows: where the long look for a receiver without a model starts.
    long_due_ns
        Reference-clock time from which the next long look may run, ns.
    """

    first_batch: int
    newest_ns: int
    due_ns: int
    unclocked_since_ns: dict[str, int] = field(default_factory=dict)
    starts: deque[int] = field(default_factory=lambda: deque(maxlen=LONG_LOOK_REFRESHES))
    long_due_ns: int = 0


LONG_LOOK_REFRESHES = 30
"""A receiver still without a clock model after a re-estimate is tried again on
the frames it shares with the reference since the start of the 30th-last
window (about 5 minutes at a steady 10 s refresh; longer where traffic comes in
bursts, which is where it is needed: probe requests every 20–60 s share a few
frames per burst, fewer than a 30 s window's 5 pairs)."""


@dataclass
class PipelineState:
    """Everything the pipeline remembers (pickled into the checkpoint).

    Attributes
    ----------
    cursor
        Id of the last batch processed.
    receivers
        Site receivers the matcher was built for, in site order.
    calibration
        Buffered frames ``(receiver_id, timestamp_ns, sha256, transmitter, rss_dbm)``
        while clocks are not yet estimated; ``None`` once matching runs.
    matcher
        The streaming matcher (``None`` while calibrating).
    clocks
        Clock models by receiver id.
    track_states
        Tracker state per transmitter (lower-case address), of the method's
        state type (a checkpoint of another method starts its devices afresh).
    next_packet_id
        Next packet id to assign.
    arrivals
        Per receiver, ``(reference-clock ns of the batch's last frame, server
        arrival time)`` of recent batches, for latency.
    counts
        Running counters (frames, packets, estimates, late frames, ...).
    alarm_detectors
        Spoofing detector per transmitter (``filter`` only,
        :class:`radiopose.server.alarms.AlarmMonitor`), so a restart resumes them.
    pending_obs
        The packets whose estimate the detector still waits for (a lagged
        method's), by ``(transmitter, packet_id)``, so that a restart feeds
        the detector the same packets as a run that never stopped.
    site_version
        The site version this state was derived under (-1: not recorded).
    method
        The engine whose states :attr:`track_states` holds: the method's name
        and whether the site was 3-D (``None``: not recorded), so that a lagged
        engine's held-back estimates are emitted when another takes over.
    last_received_s
        Arrival time of the last batch processed (server clock, s).
    catchup
        After a pause in the reports (:attr:`LiveConfig.catchup_after_s`): the
        arrival time of the first batch after it and the receivers waited for;
        ``None`` otherwise.
    clock_window
        Where the frames of the clocks' next re-estimate start and when it is
        due (:class:`ClockWindow`; the frames are read back from the database,
        so the checkpoint stays small and a restart re-estimates the same).
    calibration_batch
        Id of the first batch of the last calibration.
    """

    cursor: int = 0
    receivers: tuple[str, ...] = ()
    calibration: list[tuple[str, int, str, str, float]] | None = field(default_factory=list)
    matcher: StreamingMatcher | None = None
    clocks: dict[str, ClockModel] = field(default_factory=dict)
    track_states: dict[str, Any] = field(default_factory=dict)
    next_packet_id: int = 0
    arrivals: dict[str, deque[tuple[int, float]]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    last_batch_wall_s: float = 0.0
    flushed: bool = True
    alarm_detectors: dict[str, Any] = field(default_factory=dict)
    pending_obs: dict[tuple[str, str], PacketObservation] = field(default_factory=dict)
    site_version: int = -1
    method: tuple[str, bool] | None = None
    last_received_s: float | None = None
    catchup: tuple[float, tuple[str, ...]] | None = None
    clock_window: ClockWindow | None = None
    calibration_batch: int | None = None


def _batch_rows(
    b: StoredBatch, keep: Iterable[bool] | None = None
) -> list[tuple[str, int, str, str, float]]:
    """A stored batch's frames as ``(receiver, ns, sha256, transmitter, rss)``
    rows (those ``keep`` marks, if given)."""
    cols = zip(b.timestamp_ns, b.frame_sha256, b.transmitter, b.rss_dbm, strict=True)
    if keep is None:
        return [(b.receiver_id, int(t), h, tx, r) for t, h, tx, r in cols]
    return [
        (b.receiver_id, int(t), h, tx, r) for (t, h, tx, r), k in zip(cols, keep, strict=True) if k
    ]


def _reported_between(arrivals: Iterable[tuple[int, float]], lo_s: float, hi_s: float) -> bool:
    """Whether any ``(reference ns, arrival s)`` of a receiver arrived in ``[lo_s, hi_s]``."""
    return any(lo_s <= a <= hi_s for _, a in arrivals)


def _frames(rows: list[tuple[str, int, str, str, float]]) -> FrameRecords:
    n = len(rows)
    if n == 0:
        return FrameRecords.empty()
    rid, ts, sha, tx, rss = zip(*rows, strict=True)
    obj = lambda v: np.asarray(v, dtype=object).reshape(n)  # noqa: E731
    return FrameRecords(
        obj(rid), np.asarray(ts, np.int64), obj(sha), obj(tx), np.asarray(rss, np.float64)
    )


class LivePipeline:
    """One partition's live pipeline over a :class:`Database` (see module docstring).

    Parameters
    ----------
    db
        The database.
    config
        Settings.
    """

    def __init__(self, db: Database, config: LiveConfig | None = None) -> None:
        self.db = db
        self.config = config or LiveConfig()
        self.site: Site | None = None
        self.site_version = -1
        self.tracker: Tracker | None = None
        self.alarm_monitor: Any = None  # radiopose.server.alarms.AlarmMonitor (filter only)
        self.state = PipelineState()
        self.latencies_s: deque[float] = deque(maxlen=5_000)
        self._last_commit_s = 0.0
        self._last_checkpoint_s = 0.0
        self._resumed = False
        self._unsaved: list[dict[str, Any]] = []  # output of steps not yet committed
        self._committed_cursor = -1
        self._load()

    # ------------------------------------------------------------------ state
    def _load(self) -> None:
        """(Re)load the last checkpoint; a fresh state if there is none."""
        ck = self.db.load_checkpoint(self.config.partition_key)
        self.state = pickle.loads(ck[1]) if ck is not None else PipelineState()
        # (a checkpoint written before the fields were added has none)
        self.state.__dict__.setdefault("pending_obs", {})
        self.state.__dict__.setdefault("site_version", -1)
        self.state.__dict__.setdefault("last_received_s", None)
        self.state.__dict__.setdefault("catchup", None)
        self.state.__dict__.setdefault("clock_window", None)
        self.state.__dict__.setdefault("calibration_batch", None)
        if (w := self.state.clock_window) is not None:  # (one pickled before these fields)
            w.__dict__.setdefault("starts", deque([w.first_batch], maxlen=LONG_LOOK_REFRESHES))
            w.__dict__.setdefault("long_due_ns", 0)
        if not isinstance(self.state.__dict__.setdefault("method", None), tuple | None):
            self.state.method = None  # (a name alone: not the engine; unknown)
        self._resumed = ck is not None  # the first _refresh_site checks the site version
        self.site_version = -1
        self.tracker = None
        self._unsaved = []  # output not committed is re-derived from the checkpoint
        self._committed_cursor = self.state.cursor
        # after a restart, give the receivers time to resend before an idle flush
        self.state.last_batch_wall_s = time.time()

    def _refresh_site(self) -> list[dict[str, Any]]:
        """Rebuild site and tracker after a site change; return packets a flush emitted."""
        version = self.db.site_version()
        if version == self.site_version and self.site is not None:
            return []
        from radiopose.site import site_is_3d
        from radiopose.tracker import SKIP_ENGINE_UNRECORDED, SKIP_SITE_CHANGED, Tracker

        st = self.state
        if self.site is None and self._resumed and st.site_version != version:
            self._drop_ahead()
        self._resumed = False
        new_site = build_site(self.db.site_rows())
        method = self.config.method_for(new_site)
        engine = (method, site_is_3d(new_site))  # the 2-D and 3-D filter are two engines
        out: list[dict[str, Any]] = []
        if self.site is not None and self.tracker is not None:
            # A live edit: what the old site still holds is finished by the old tracker
            # first — the packets open against the old receivers, and the held-back
            # estimates of devices the edit removes — and committed below with the
            # edit's checkpoint.
            if new_site.receiver_ids != st.receivers and st.matcher is not None:
                out += self._handle(st.matcher.flush(), time.time())
                self._reset_matcher(new_site.receiver_ids)
            gone = [k for k in self._unenrolled(new_site) if self.tracker.has_device(k)]
            out += self._held_back_rows(self.tracker, gone, self._method_failed)
        if st.method is None and st.track_states and not self._states_fit(method):
            # a checkpoint from before engines were recorded, of another method: what
            # its engine holds back cannot be handed over (which engine and site it
            # was is not known); those packets get a skip reason instead of none
            self._mark_unestimated(SKIP_ENGINE_UNRECORDED)
            st.track_states.clear()
        if st.method is not None and tuple(st.method) != engine and st.track_states:
            # Another engine takes over: the old one's held-back estimates are emitted
            # by it on the site its states were derived under, when that is at hand
            # (a live edit; a restart with another --method on the same site);
            # otherwise (a restart whose checkpoint predates the edit) their packets
            # get a skip reason.
            if self.site is not None and self.site_version == st.site_version:
                out += self._hand_over(self.site)
            elif st.site_version == version:
                out += self._hand_over(new_site)
            else:
                self._mark_unestimated(SKIP_SITE_CHANGED)
            st.track_states.clear()
        st.method = engine
        if self.site is not None and (
            out or self._unsaved or st.cursor != self._committed_cursor
        ):  # a live edit: what the old site derived is checkpointed, the new applies from here
            st.site_version = version
            self._commit(self._unsaved + out, force_state=True)
            self._unsaved, out = [], []
        st.site_version = version
        self.site = new_site
        self.site_version = version
        self.tracker = Tracker(
            self.site, method, self.config.tracker, lag_s=self.config.live_lag_s or None
        )
        # (states of another method, after a site change turned 2-D into 3-D, or a
        # checkpoint of another --method, start their devices afresh)
        self.tracker.states = self.state.track_states
        self._forget_unenrolled()
        if method != "filter":
            # (a site change may change the default method, 3-D filter to 2-D full:
            # the old site's alarm monitor and its pending packets go with it)
            self.alarm_monitor = None
            self.state.pending_obs.clear()
        else:  # spoofing alarms beside the filter (issue 19)
            from radiopose.server.alarms import AlarmMonitor

            # the detectors live in the checkpointed state (a checkpoint written before
            # they were added has none: they start afresh)
            detectors = self.state.__dict__.setdefault("alarm_detectors", {})
            self.alarm_monitor = AlarmMonitor(self.site, detectors=detectors)
        receivers = self.site.receiver_ids
        if receivers != st.receivers:  # (a restart: closed by the new tracker)
            if st.matcher is not None:  # close what is open against the old receivers
                out += self._handle(st.matcher.flush(), time.time())
            self._reset_matcher(receivers)
        return out

    def _reset_matcher(self, receivers: tuple[str, ...]) -> None:
        """New receivers: recalibrate their clocks from the next frames."""
        st = self.state
        st.receivers = receivers
        st.matcher = None
        st.calibration = []
        st.clocks = {}
        st.clock_window = None  # (and the catch-up of the old receivers ends)
        st.catchup = None
        st.last_received_s = None
        log.info("receivers changed; recalibrating", extra={"receivers": list(receivers)})

    def _drop_ahead(self) -> None:
        """On resuming from a checkpoint derived under another site version (or
        an unrecorded one: a checkpoint from before versions were recorded):
        a site edit came after it and before the pipeline saw it (a crash in
        between). Output committed ahead of the checkpoint was derived under
        the old site, and re-deriving under the new one may number the packets
        differently: it is dropped and re-derived, as if it had not been
        committed (the edit takes effect at the checkpoint). The version is
        read in the same refresh that applies the site, so an edit between the
        restart and the first step is caught too."""
        dropped = self.db.drop_output_from(self.state.next_packet_id, self.config.owns)
        if dropped:
            log.warning(
                "the site changed after the last checkpoint: %d packets of output derived "
                "under the old site are re-derived",
                dropped,
            )

    def _hand_over(self, site: Site) -> list[dict[str, Any]]:
        """The estimates the previous engine (``state.method``: a method name
        and whether its site was 3-D) still holds back, emitted by it on
        ``site`` (the site its states were derived under), so that none of its
        packets stays without one. Returns their rows."""
        from radiopose.tracker import METHODS, Tracker

        st = self.state
        assert st.method is not None
        previous = st.method[0]
        impl = METHODS.get(previous)
        rows: list[dict[str, Any]] = []
        if impl is not None and impl.lagged:
            old = Tracker(site, previous, self.config.tracker, lag_s=self.config.live_lag_s or None)
            old.states = st.track_states
            keys = [k for k in st.track_states if old.is_enrolled(k)]
            for key in keys:
                old.device(key)
            rows = self._held_back_rows(old, keys, lambda tx, exc: log.error(
                "method %s could not hand over %s: %s", previous, tx, exc))  # fmt: skip
            log.info(
                "another engine takes over from %s: %d held-back estimates emitted",
                previous,
                len(rows),
            )
        return rows

    def _held_back_rows(
        self, tracker: Tracker, keys: list[str], on_error: Callable[[str, Exception], None]
    ) -> list[dict[str, Any]]:
        """The estimate rows of what ``tracker`` still holds back for the devices
        ``keys`` (prepared in it), emitted now (:meth:`Tracker.flush`), with the
        spoofing alarms they raise: the alarm monitor in place is still the one of
        the site they were derived under (a live edit replaces it after this)."""
        if not keys:
            return []
        now = time.time()
        flushed = tracker.flush(keys, on_error=on_error)
        return [row for e in flushed for row in self._estimate_rows(e, now)]

    def _unenrolled(self, site: Site) -> list[str]:
        """The devices with a tracking state that ``site`` does not enrol."""
        enrolled = {d.transmitter.lower() for d in site.devices}
        return [k for k in self.state.track_states if k.lower() not in enrolled]

    def _states_fit(self, method: str) -> bool:
        """Whether every stored tracking state is of ``method``'s state type (a
        checkpoint that did not record its engine: of this method, or not)."""
        from radiopose.tracker import METHODS

        impl = METHODS.get(method)
        return impl is not None and all(
            isinstance(s, impl.state_type) for s in self.state.track_states.values()
        )

    def _mark_unestimated(self, reason: str) -> None:
        """The previous engine's devices' packets that wait for an estimate it
        holds back, when it cannot emit them: the site it derived them under is
        gone (a restart whose checkpoint predates a site edit that changed the
        engine: :data:`~radiopose.tracker.SKIP_SITE_CHANGED`), or the checkpoint
        did not record which engine it was
        (:data:`~radiopose.tracker.SKIP_ENGINE_UNRECORDED`). They get ``reason``."""
        st = self.state
        n = self.db.mark_unestimated(list(st.track_states), st.next_packet_id, reason)
        if n:
            log.warning("%d packets waiting for a held-back estimate get the reason %r", n, reason)

    def _forget_unenrolled(self) -> None:
        """Drop the state, detector and pending packets of every device the site
        no longer enrols (an admin removed it): they would otherwise stay in
        every checkpoint for good."""
        assert self.site is not None
        enrolled = {d.transmitter.lower() for d in self.site.devices}
        st = self.state
        for key in self._unenrolled(self.site):
            del st.track_states[key]
        for key in [k for k in st.alarm_detectors if k.lower() not in enrolled]:
            del st.alarm_detectors[key]
        for gone in [k for k in st.pending_obs if k[0].lower() not in enrolled]:
            del st.pending_obs[gone]

    # ------------------------------------------------------------------ steps
    def step(self) -> int:
        """Process the batches available now; return how many were processed."""
        emitted = self._refresh_site()
        st = self.state
        batches = self.db.batches_after(st.cursor, self.config.batches_per_step)
        now = time.time()
        for b in batches:
            emitted += self._batch(b)
            st.cursor = b.id
            st.flushed = False
        if batches:
            # Reports pause only once the pipeline is done with the last ones: a
            # step slower than ``idle_flush_s`` (a cold compile, a loaded machine, a
            # worker thread holding the interpreter while the API waits) must not
            # close the chains whose frames arrived meanwhile.
            st.last_batch_wall_s = time.time()
        idle_s = now - st.last_batch_wall_s
        flushed = not batches and not st.flushed and idle_s >= self.config.idle_flush_s
        if flushed:
            emitted += self._idle_flush(now)
        # Output is committed with the state that produced it, or (a lagged method,
        # whose state is large) ahead of it; a crash re-derives what the last
        # checkpoint had not seen, and the database keeps what it stored already:
        # nothing twice, nothing lost. A lagged method's commits are spaced by
        # ``lagged_commit_s``, its checkpoints by ``lagged_checkpoint_s``.
        self._unsaved += emitted
        lagged = self.tracker is not None and self.tracker.lag_s is not None
        wait_s = self.config.lagged_commit_s if lagged else 0.0
        if (
            (self._unsaved and now - self._last_commit_s >= wait_s)
            or (
                st.cursor != self._committed_cursor
                and now - self._last_commit_s >= self.config.checkpoint_s
            )
            or flushed  # (even with no output: /health then shows the closed chains' counts)
        ):
            self._commit(self._unsaved)
            self._unsaved = []
        return len(batches)

    def _batch(self, b: StoredBatch) -> list[dict[str, Any]]:
        st = self.state
        c = st.counts
        c["frames"] = c.get("frames", 0) + len(b.timestamp_ns)
        if b.receiver_id not in st.receivers:
            c["frames_unknown_receiver"] = c.get("frames_unknown_receiver", 0) + len(b.timestamp_ns)
            return []
        rows = _batch_rows(b)
        last_ns = max(b.timestamp_ns) if rows else None
        if st.matcher is None:
            assert st.calibration is not None
            if not st.calibration:
                st.calibration_batch = b.id
            st.calibration.extend(rows)
            st.last_received_s = max(st.last_received_s or b.received_s, b.received_s)
            if last_ns is not None:
                st.arrivals.setdefault(b.receiver_id, deque(maxlen=20_000)).append(
                    (last_ns, b.received_s)  # receiver clock; converted at calibration
                )
            if self._calibration_ready():
                return self._calibrate(b.received_s)
            return []
        if last_ns is not None:
            ref = int(st.clocks[b.receiver_id].to_reference_ns(np.array([last_ns]))[0])
            st.arrivals.setdefault(b.receiver_id, deque(maxlen=20_000)).append((ref, b.received_s))
            self._track_clocks(b, ref)
            self._catch_up(b.received_s)
        out = self._handle(st.matcher.push(_frames(rows)), b.received_s)
        if st.catchup is not None:
            self._catch_up_done(b.received_s)
        return out

    def _catch_up(self, received_s: float) -> None:
        """Start a catch-up when this batch (one with frames) arrived more than
        ``catchup_after_s`` after the previous one (every decision here reads
        stored data and the checkpointed state, so a restart re-derives the same
        packets). After a quiet spell it ends as soon as the receivers that
        reported before it report again; one that does not is waited for up to
        ``catchup_wait_s`` of arrivals."""
        st = self.state
        cfg = self.config
        assert st.matcher is not None  # (called on the matching path only)
        previous_s = st.last_received_s
        st.last_received_s = received_s if previous_s is None else max(previous_s, received_s)
        if previous_s is None or st.catchup is not None:
            return
        if received_s - previous_s <= cfg.catchup_after_s:
            return
        # (whether this first batch is a spooled one or not: a receiver with nothing
        # spooled may come back first, and pushing it would move the horizon past the
        # others' spooled frames)
        # the receivers that reported in the last max_lag_s before the pause
        before = tuple(
            r
            for r in st.receivers
            if _reported_between(st.arrivals.get(r, ()), previous_s - cfg.max_lag_s, previous_s)
        )
        st.catchup = (received_s, before)
        st.matcher.set_max_lag(cfg.catchup_lag_s)
        log.info(
            "reports paused %.1f s: catching up (receivers %s)",
            received_s - previous_s,
            ", ".join(before),
        )

    def _catch_up_done(self, received_s: float) -> None:
        """End the catch-up once every receiver waited for has reported again and
        is within ``max_lag_s`` of the most advanced one, or ``catchup_wait_s``
        of arrivals have passed."""
        st = self.state
        cfg = self.config
        assert st.catchup is not None and st.matcher is not None
        since_s, waited = st.catchup
        behind = st.matcher.behind_ns()
        lag_ns = round(cfg.max_lag_s * _NS)
        caught_up = all(
            (dq := st.arrivals.get(r))
            and dq[-1][1] >= since_s  # it reported again
            and (behind.get(r) or 0) < lag_ns  # and is back within max_lag_s
            for r in waited
        )
        if caught_up or received_s - since_s > cfg.catchup_wait_s:
            st.catchup = None
            st.matcher.set_max_lag(cfg.max_lag_s)
            c = st.counts
            c["catch_ups"] = c.get("catch_ups", 0) + 1

    def _track_clocks(self, b: StoredBatch, hi: int) -> None:
        """Schedule the clocks' re-estimates by this batch's reference-clock times
        (``hi``: of its last frame, ns) and run one when due (:meth:`_refresh_clocks`)."""
        st = self.state
        cfg = self.config
        clock = st.clocks[b.receiver_id]
        w = st.clock_window
        modelled = clock.method != "none"
        if w is None:
            if not modelled:
                return  # (the schedule starts from a receiver whose times mean something)
            w = st.clock_window = ClockWindow(b.id, hi, hi + round(cfg.clock_refresh_s * _NS))
            w.starts.append(st.calibration_batch or b.id)  # the long look reaches back to it
        if modelled:  # a receiver without a model may run hours off: it sets no schedule
            w.newest_ns = max(w.newest_ns, hi)
        due = w.newest_ns >= w.due_ns
        if not modelled:  # a receiver without a model: as soon as it can have one
            lo = int(clock.to_reference_ns(np.array([min(b.timestamp_ns)]))[0])
            since = w.unclocked_since_ns.setdefault(b.receiver_id, lo)
            due = due or hi - since >= round(cfg.calibration_s * _NS)
        if due:
            self._refresh_clocks(b.id)

    def _refresh_clocks(self, upto_batch: int) -> None:
        """Estimate every receiver's clock again from the stored frames of the last
        ``clock_window_s`` up to batch ``upto_batch`` (this one; read back from the
        database, in the clock models of now) with
        :func:`~radiopose.capture.sync.estimate_clocks` against the same
        reference; a receiver without enough pairs keeps its model. The matcher
        applies the new models to the frames pushed from now on."""
        st = self.state
        cfg = self.config
        w = st.clock_window
        assert st.matcher is not None and w is not None
        w.due_ns = w.newest_ns + round(cfg.clock_refresh_s * _NS)
        w.unclocked_since_ns = {}  # (a receiver still without a model tries again)
        cutoff = w.newest_ns - round(cfg.clock_window_s * _NS)
        rows: list[tuple[str, int, str, str, float]] = []
        first = None
        stored = self.db.batches_after(w.first_batch - 1, upto_batch - w.first_batch + 1)
        for x in stored:
            if x.id > upto_batch or x.receiver_id not in st.clocks or not x.timestamp_ns:
                continue
            ts = np.asarray(x.timestamp_ns, np.int64)
            keep = st.clocks[x.receiver_id].to_reference_ns(ts) >= cutoff
            if keep.any():
                first = x.id if first is None else first
                rows += _batch_rows(x, keep)
        w.first_batch = upto_batch if first is None else first
        w.starts.append(w.first_batch)
        ref = next((r for r, m in st.clocks.items() if m.method == "reference"), None)
        frames = _frames(rows)
        heard = set(frames.receiver_id.tolist())
        if ref is None or ref not in heard:
            return  # the reference is silent: the models extrapolate until it is back
        # (50 candidate pairs, not sync's 150: 40 ms instead of 0.4 s on 30 s of 16
        # phones at 4 receivers; the model it refreshes is already close)
        sync_cfg = self._sync_config(ref, min_pairs=5, max_candidates=50)
        fresh = estimate_clocks(frames, [r for r in st.receivers if r in heard], sync_cfg)
        changed: dict[str, list[object]] = {}
        for r, m in fresh.items():
            if r == ref or m.method == "none":
                continue
            if st.clocks[r].method != m.method:
                changed[r] = [m.offset_s, m.drift_ppm, m.method]
            st.clocks[r] = m
        # receivers the window could not model (too few pairs: sparse traffic)
        # (heard in the long look's span, about LONG_LOOK_REFRESHES refresh periods:
        # a receiver that is off has nothing to look at)
        span_ns = LONG_LOOK_REFRESHES * round(cfg.clock_refresh_s * _NS)
        starved = [
            r
            for r in st.receivers
            if r != ref
            and (r not in fresh or fresh[r].method == "none")
            and (dq := st.arrivals.get(r))
            and dq[-1][0] >= w.newest_ns - span_ns
        ]
        if starved and w.newest_ns >= w.long_due_ns:  # (at most every 3 refresh periods)
            w.long_due_ns = w.newest_ns + 3 * round(cfg.clock_refresh_s * _NS)
            changed.update(self._long_look(ref, starved, upto_batch))
        st.matcher.set_clocks(st.clocks)
        c = st.counts
        c["clock_estimates"] = c.get("clock_estimates", 0) + 1
        if changed:
            log.info("clock models changed", extra={"clocks": changed})

    def _long_look(
        self, ref: str, unclocked: list[str], upto_batch: int
    ) -> dict[str, list[object]]:
        """Models for receivers the last window could not model (``unclocked``:
        too few pairs in it), from every frame they share with the reference
        since the long look's start (:data:`LONG_LOOK_REFRESHES`), with offline
        ``sync``'s 2 pairs as the least (a receiver without a model has its
        frames as packets of their own; one whose model is not refreshed drifts
        out of the tolerance). Returns the models made."""
        st = self.state
        w = st.clock_window
        assert w is not None
        keep = {ref, *unclocked}
        start = w.starts[0]
        rows = [
            row
            for x in self.db.batches_after(start - 1, upto_batch - start + 1, sorted(keep))
            if x.id <= upto_batch
            for row in _batch_rows(x)
        ]
        sync_cfg = self._sync_config(ref, max_candidates=50)
        heard = set(r[0] for r in rows)
        if ref not in heard:
            return {}
        fresh = estimate_clocks(
            _frames(rows), [r for r in (ref, *unclocked) if r in heard], sync_cfg
        )
        made: dict[str, list[object]] = {}
        for r in unclocked:
            m = fresh.get(r)
            if m is not None and m.method != "none":
                st.clocks[r] = m
                made[r] = [m.offset_s, m.drift_ppm, m.method]
        return made

    def _sync_config(self, reference: str, **overrides: int) -> SyncConfig:
        """Clock estimation against ``reference`` at this pipeline's tolerance and lag."""
        cfg = self.config
        return SyncConfig(
            tolerance_s=cfg.tolerance_s, reference=reference, max_lag_s=cfg.max_lag_s, **overrides
        )

    def _calibration_ready(self) -> bool:
        buf = self.state.calibration or []
        if len(buf) >= self.config.calibration_max_frames:
            return True
        ref = self._reference()
        if ref is None:
            return False
        times = [f[1] for f in buf if f[0] == ref]
        return (max(times) - min(times)) >= self.config.calibration_s * _NS

    def _reference(self) -> str | None:
        heard = {f[0] for f in self.state.calibration or []}
        return next((r for r in self.state.receivers if r in heard), None)

    def _calibrate(self, wall_s: float) -> list[dict[str, Any]]:
        """Estimate clocks from the buffer, start the matcher and push the buffer."""
        st = self.state
        buf = st.calibration or []
        ref = self._reference()
        heard = [r for r in st.receivers if any(f[0] == r for f in buf)]
        frames = _frames(buf)
        clocks: dict[str, ClockModel] = {}
        if ref is not None and len(frames):
            clocks = estimate_clocks(frames, heard, self._sync_config(ref))
        st.clocks = {r: clocks.get(r, ClockModel(r, method="none")) for r in st.receivers}
        if ref is not None:
            st.clocks[ref] = clocks.get(ref, ClockModel(ref))
        for rid, dq in st.arrivals.items():
            if rid in st.clocks and dq:
                ns = np.array([a[0] for a in dq], dtype=np.int64)
                ref_ns = st.clocks[rid].to_reference_ns(ns)
                st.arrivals[rid] = deque(
                    ((int(t), a[1]) for t, a in zip(ref_ns, dq, strict=True)), maxlen=20_000
                )
        st.matcher = StreamingMatcher(
            st.receivers,
            st.clocks,
            tolerance_s=self.config.tolerance_s,
            max_lag_s=self.config.max_lag_s,
        )
        st.calibration = None
        log.info(
            "clocks estimated",
            extra={
                "clocks": {r: [m.offset_s, m.drift_ppm, m.method] for r, m in st.clocks.items()}
            },
        )
        return self._handle(st.matcher.push(frames), wall_s)

    def _idle_flush(self, wall_s: float) -> list[dict[str, Any]]:
        st = self.state
        st.flushed = True
        if st.matcher is None:
            if not st.calibration:
                return []
            out = self._calibrate(wall_s)
        else:
            out = []
        assert st.matcher is not None
        out += self._handle(st.matcher.flush(), wall_s)
        if self.tracker is not None:  # a lagged method's held-back estimates
            # their latency counts from the last report's arrival, not from the flush
            # (they waited for it: counted from the flush they read as about 0)
            last = max((dq[-1][1] for dq in st.arrivals.values() if dq), default=wall_s)
            for e in self.tracker.flush(on_error=self._method_failed):
                out += self._estimate_rows(e, min(last, wall_s))
        return out

    def _method_failed(self, transmitter: str, exc: Exception) -> None:
        """The method raised on one of ``transmitter``'s packets (or in its
        flush): log it, count it; the tracker has dropped, or is told to drop,
        the device's state (its next packet starts afresh), so that one device
        cannot stall the partition by failing again at every retry."""
        assert self.tracker is not None
        self.tracker.drop(transmitter)
        c = self.state.counts
        c["method_failures"] = c.get("method_failures", 0) + 1
        from radiopose.errors import RadioposeError

        log.error(
            "method %s failed on transmitter %s; its track starts afresh: %s",
            self.tracker.method,
            transmitter,
            exc,
            exc_info=None if isinstance(exc, RadioposeError) else exc,
            extra={"transmitter": transmitter, "method": self.tracker.method},
        )

    # ------------------------------------------------------------------ packets
    def _handle(self, packets: Packets, wall_s: float) -> list[dict[str, Any]]:
        """Track the packets this partition owns; return packet and estimate rows."""
        if len(packets) == 0:
            return []
        st = self.state
        assert self.tracker is not None
        out: list[dict[str, Any]] = []
        tol_ns = round(self.config.tolerance_s * _NS)
        from radiopose.tracker import PENDING, SKIP_METHOD_FAILED

        for obs in group_packets(packets):
            pid = str(st.next_packet_id)
            st.next_packet_id += 1
            if not self.config.owns(obs.transmitter):
                continue
            obs = PacketObservation(
                pid, obs.timestamp_s, obs.transmitter, obs.receiver_ids, obs.rss_dbm
            )
            if self.alarm_monitor is not None:  # its estimate may come after the lag
                st.pending_obs[(obs.transmitter, pid)] = obs
            try:
                est, reason = self.tracker.update(obs)
            except Exception as exc:  # one device's failure must not stall the partition
                self._method_failed(obs.transmitter, exc)
                est, reason = None, SKIP_METHOD_FAILED
            t_ns = round(obs.timestamp_s * _NS)
            last_report = max(self._arrival(r, t_ns - tol_ns, wall_s) for r in obs.receiver_ids)
            c = st.counts
            c["packets"] = c.get("packets", 0) + 1
            out.append(
                {
                    "kind": "packet",
                    "packet_id": pid,
                    "transmitter": obs.transmitter,
                    "timestamp_s": obs.timestamp_s,
                    "receiver_ids": list(obs.receiver_ids),
                    "rss_dbm": [float(v) for v in obs.rss_dbm],
                    "reason": None if reason == PENDING else reason,  # its estimate follows
                }
            )
            if est is not None:
                out += self._estimate_rows(est, last_report)
            # a lagged method's estimates of earlier packets, ready with this one
            for e in self.tracker.take_delayed():
                out += self._estimate_rows(e, last_report)
        # ... and of devices silent for the lag while others send
        now_s = float(np.max(packets.timestamp_s))
        for e in self.tracker.release(now_s, self._method_failed):
            out += self._estimate_rows(e, wall_s)
        return out

    def _estimate_rows(self, est: PoseEstimate, last_report_s: float) -> list[dict[str, Any]]:
        """The estimate's row, and the spoofing alarm it raises (``filter`` only,
        :class:`radiopose.server.alarms.AlarmMonitor`)."""
        rows = [self._estimate_row(est, last_report_s)]
        if self.alarm_monitor is not None:
            pending = self.state.pending_obs
            obs = pending.pop((est.transmitter, est.packet_id), None)
            # packets that never got an estimate (e.g. an unenrolled device) age out
            for key in [k for k, o in pending.items() if o.timestamp_s < est.timestamp_s - 5.0]:
                del pending[key]
            if obs is not None:
                event = self.alarm_monitor.observe(obs, est.position_m, est.orientation_deg)
                if event is not None:
                    rows.append({"kind": "alarm", **event})
        return rows

    def _estimate_row(self, est: PoseEstimate, last_report_s: float) -> dict[str, Any]:
        """An estimate row; ``last_report_s`` is the arrival of the report that made it
        possible (for a lagged estimate, of the packet that released it)."""
        c = self.state.counts
        c["estimates"] = c.get("estimates", 0) + 1
        return {
            "kind": "estimate",
            "timestamp_s": est.timestamp_s,
            "transmitter": est.transmitter,
            "packet_id": est.packet_id,
            "x_m": est.position_m[0],
            "y_m": est.position_m[1],
            "z_m": est.position_m[2],
            "azimuth_deg": est.orientation_deg[0],
            "pitch_deg": est.orientation_deg[1],
            "roll_deg": est.orientation_deg[2],
            "method": est.method,
            "last_report_s": last_report_s,
            "position_std_m": _finite_or_none(est.position_std_m),
            "azimuth_std_deg": _finite_or_none(est.azimuth_std_deg),
        }

    def _arrival(self, receiver_id: str, t_ns: int, default: float) -> float:
        """Server arrival time of the first recent batch of a receiver reaching ``t_ns``."""
        dq = self.state.arrivals.get(receiver_id)
        if not dq:
            return default
        keep_from = t_ns - 2 * round(self.config.max_lag_s * _NS)
        while len(dq) > 1 and dq[0][0] < keep_from:
            dq.popleft()
        for tau_ns, arrived_s in dq:
            if tau_ns >= t_ns:
                return arrived_s
        return default

    def _commit(self, emitted: list[dict[str, Any]], force_state: bool = False) -> None:
        now = time.time()
        packets = [
            {k: v for k, v in e.items() if k != "kind"} for e in emitted if e["kind"] == "packet"
        ]
        estimates = [
            {**{k: v for k, v in e.items() if k != "kind"}, "estimated_s": now}
            for e in emitted
            if e["kind"] == "estimate"
        ]
        for e in estimates:
            self.latencies_s.append(now - e["last_report_s"])
        st = self.state
        matcher = st.matcher
        summary = {
            "phase": "calibrating" if matcher is None else "matching",
            "calibration_frames": len(st.calibration or []),
            "open_frames": 0 if matcher is None else matcher.open_frames,
            "late_frames": 0 if matcher is None else matcher.counts.late_frames,
            # chains dropped for naming two transmitters for one hash (inconsistent reports)
            "ambiguous_transmitter": 0 if matcher is None else matcher.counts.ambiguous_transmitter,
            # ... for a hash heard twice by one receiver, or spread over more than the
            # tolerance, and the frames of every dropped chain (as sync reports them)
            "ambiguous_duplicate": 0 if matcher is None else matcher.counts.ambiguous_duplicate,
            "ambiguous_spread": 0 if matcher is None else matcher.counts.ambiguous_spread,
            "ambiguous_frames": 0 if matcher is None else matcher.counts.ambiguous_frames,
            # after a pause in the reports, waiting for the agents' spools (LiveConfig)
            "catching_up": st.catchup is not None,
            "clocks": {
                r: {"offset_s": m.offset_s, "drift_ppm": m.drift_ppm, "method": m.method}
                for r, m in st.clocks.items()
            },
            "counts": dict(st.counts),
            "transmitters": len(st.track_states),
            "cursor": st.cursor,  # processed (the checkpoint's own cursor may trail it)
        }
        alarms = [
            {k: v for k, v in e.items() if k != "kind"} for e in emitted if e["kind"] == "alarm"
        ]
        # A lagged method's checkpoint is large (its smoother's lineage): written
        # only every lagged_checkpoint_s; the output in between is stored ahead of
        # it, re-derived after a crash and then kept once (idempotent inserts).
        lagged = self.tracker is not None and self.tracker.lag_s is not None
        with_state = (
            force_state
            or not lagged
            or now - self._last_checkpoint_s >= self.config.lagged_checkpoint_s
        )
        self.db.commit_step(
            self.config.partition_key,
            st.cursor,
            self._checkpoint() if with_state else None,
            summary,
            packets,
            estimates,
            alarms,
        )
        self._last_commit_s = now
        if with_state:
            self._last_checkpoint_s = now
            self._committed_cursor = st.cursor

    def _checkpoint(self) -> bytes:
        """The pickled state. A device whose method state does not pickle (a
        plugin's; docs/methods.md) is dropped as if its method had failed, so
        that the partition can still commit."""
        try:
            return pickle.dumps(self.state)
        except Exception:
            if self.tracker is None:
                raise
        from radiopose.errors import MethodError

        for key, state in list(self.state.track_states.items()):
            try:
                pickle.dumps(state)
            except Exception as exc:
                self._method_failed(
                    key,
                    MethodError(
                        f"method {self.tracker.method!r}: the state of {key!r} cannot be "
                        f"pickled for the checkpoint ({type(exc).__name__}: {exc})"
                    ),
                )
        return pickle.dumps(self.state)


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def __getattr__(name: str) -> object:
    # Old import path: the worker that runs the pipeline lives in its own module
    # (it imports this one, so it cannot be imported here eagerly).
    if name == "LiveWorker":
        from radiopose.server.worker import LiveWorker

        return LiveWorker
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
