"""The streaming tracker: one packet in, its estimate (or why not) out.

:class:`Tracker` keeps one state per transmitter and hands each packet to the
method's step (:mod:`radiopose.tracker.protocol`); the method comes from the
registry (:data:`radiopose.tracker.METHODS`). A lagged method (``filter``
with ``lag_s``) answers a packet with ``PENDING`` and emits its estimate
later: :meth:`Tracker.take_delayed` returns those, :meth:`Tracker.flush` emits
every one still held back.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

from radiopose.errors import InputError, MethodError, RadioposeError
from radiopose.estimates import PoseEstimate
from radiopose.filtering.config import MAX_LAG_S, lag_in_range
from radiopose.likelihood import CandidateSpace, HeardRss, Scorer, candidate_space, make_scorer
from radiopose.packets import PacketObservation, check_observation
from radiopose.site import Site
from radiopose.tracker.config import TrackerConfig
from radiopose.tracker.filter import reads_site_scorer
from radiopose.tracker.protocol import Delayed, Device, LooksAhead, Method, Outcome
from radiopose.tracker.reasons import SKIP_DUPLICATE, SKIP_UNKNOWN_TRANSMITTER
from radiopose.tracker.registry import get_method


class Tracker:
    """Streaming tracker: one packet in, zero or one pose out.

    Parameters
    ----------
    site
        The site.
    method
        A name of :data:`radiopose.tracker.METHODS` (or a method object).
    config
        Pipeline parameters.
    scorers
        Optional prebuilt scorers by transmitter (lower case); otherwise built
        on first use with ``config.kernel`` for methods that need one.
    lag_s
        Fixed lag for lagged methods, seconds (``None``: causal; ignored by
        the others).
    offline
        The whole file is at hand (batch :func:`~radiopose.tracker.locate`;
        ``Device.offline``): the methods may run several passes at
        :meth:`flush`, which then re-emits every packet's estimate.

    Notes
    -----
    ``states`` holds one state per transmitter (lower-case address), of the
    method's ``state_type``; a stored state of another type (a checkpoint of
    another method) is replaced by a fresh one.
    """

    def __init__(
        self,
        site: Site,
        method: str | Method = "full",
        config: TrackerConfig | None = None,
        scorers: Mapping[str, Scorer] | None = None,
        lag_s: float | None = None,
        offline: bool = False,
    ) -> None:
        self.impl: Method = get_method(method) if isinstance(method, str) else method
        if lag_s is not None and not lag_in_range(lag_s):
            raise InputError(f"lag_s = {lag_s!r} must be in [0, {MAX_LAG_S:g}] s (or None)")
        self.site = site
        self.method = self.impl.name
        # a method from outside the package (a plugin): its failures are named as its
        self._plugin = not type(self.impl).__module__.startswith("radiopose.")
        self.config = config or TrackerConfig()
        self.lag_s = lag_s if self.impl.lagged else None
        self.states: dict[str, Any] = {}
        self._scorers = {k.lower(): v for k, v in (scorers or {}).items()}
        # per (pattern, transmit power): the first device's candidate space and
        # scorer, whose arrays and tables the others with the same pair share
        self._site_scorers: dict[tuple[str, float], tuple[CandidateSpace, Scorer | None]] = {}
        self._devices: dict[str, Device] = {}
        self._shared: dict[str, Any] = {}
        self._delayed: list[PoseEstimate] = []
        self._last_s: dict[str, float] = {}  # last packet time per device (for release)
        # per device, the latest packet time and the ids of its packets at that time:
        # a packet seen again is a duplicate (an earlier one is out of order)
        self._latest: dict[str, tuple[float, set[str]]] = {}
        self.offline = offline  # batch locate: the whole file (issue 15, offset selection)

    def device(self, transmitter: str) -> Device:
        """The method's context for ``transmitter`` (its site, candidate space,
        scorer and prepared engine), built on first use as its first packet
        would build it (tools that drive a method's parts directly use it too:
        the live re-solve's bound in ``scripts/live_lag_accuracy.py``)."""
        key = transmitter.lower()
        dev = self._devices.get(key)
        if dev is None:
            scorer = self._scorers.get(key)
            if scorer is not None:
                space = scorer.space
            else:
                space, scorer = self._site_scorer(transmitter)
            dev = Device(
                self.site,
                space.transmitter,
                key,
                space,
                scorer,
                self.config,
                self.lag_s,
                self._shared,
                offline=self.offline,
            )
            self.impl.prepare(dev)
            self._devices[key] = dev
        return dev

    def _site_scorer(self, transmitter: str) -> tuple[CandidateSpace, Scorer | None]:
        """``transmitter``'s candidate space and scorer (``None`` if the method
        reads none). Devices enrolled with the same pattern and transmit power
        share the first one's arrays: its space with their own name, and its
        compiled scorer's tables (:meth:`ShiftScorer.with_parallel
        <radiopose.likelihood.compiled.ShiftScorer.with_parallel>`: a twin with
        its own search hints, so the devices' searches do not slow each other).
        The estimates are those of a scorer built per device; a site with many
        phones of one model keeps one set of tables (6 MB on the paper's grid)."""
        enrolled = self.site.device(transmitter)  # (InputError if not enrolled)
        shared = (enrolled.pattern, float(enrolled.tx_power_dbm))
        first = self._site_scorers.get(shared)
        if first is None:
            space = candidate_space(self.site, transmitter)
            scorer = None
            if reads_site_scorer(self.impl, self.site):
                scorer = make_scorer(self.config.kernel, space)
            self._site_scorers[shared] = (space, scorer)
            return space, scorer
        base_space, base = first
        space = replace(base_space, transmitter=enrolled.transmitter)
        if base is None:
            return space, None
        from radiopose.likelihood.compiled import ShiftScorer

        if not isinstance(base, ShiftScorer):  # another scorer kind: its own, as before
            return space, make_scorer(self.config.kernel, space)
        scorer = base.with_parallel(base.parallel)
        scorer.space = space
        return space, scorer

    def has_device(self, transmitter: str) -> bool:
        """Whether ``transmitter``'s device is prepared (it has sent a packet to
        this tracker, or :meth:`device` was called)."""
        return transmitter.lower() in self._devices

    def is_enrolled(self, transmitter: str) -> bool:
        key = transmitter.lower()
        return any(d.transmitter.lower() == key for d in self.site.devices)

    def update(self, packet: PacketObservation) -> tuple[PoseEstimate | None, str | None]:
        """Process one packet; return ``(estimate, None)`` or ``(None, reason)``.

        With a lagged method the reason is ``PENDING`` and the estimate comes
        later from :meth:`take_delayed` (or :meth:`flush`).

        A packet given again (the same transmitter and packet id as one at the
        latest time of its transmitter) is skipped as ``SKIP_DUPLICATE``, so
        its evidence counts once; one earlier than the latest is the method's
        out-of-order skip.

        Raises
        ------
        InputError
            The packet names a receiver that is not in the site, or one of
            its values is not what ``packets.csv`` allows
            (:func:`~radiopose.packets.check_observation`).
        """
        check_observation(packet)
        if not self.is_enrolled(packet.transmitter):
            return None, SKIP_UNKNOWN_TRANSMITTER
        dev = self.device(packet.transmitter)
        heard = dev.space.heard(packet)
        t = float(packet.timestamp_s)
        latest = self._latest.get(dev.key)
        if latest is None or t > latest[0]:
            self._latest[dev.key] = (t, {packet.packet_id})
        elif t == latest[0]:
            if packet.packet_id in latest[1]:
                return None, SKIP_DUPLICATE
            latest[1].add(packet.packet_id)
        with self._named_failures(f"packet {packet.packet_id!r} of {dev.transmitter!r}", t):
            state = self.states.get(dev.key)
            if not isinstance(state, self.impl.state_type):
                state = self.impl.new_state(dev)
            step = self.impl.step(dev, state, heard, t, packet.packet_id)
            self.states[dev.key] = step.state
            self._last_s[dev.key] = max(t, self._last_s.get(dev.key, t))
            self._delayed += (
                self._pose(dev, d.timestamp_s, d.packet_id, d.outcome) for d in step.earlier
            )
            out = step.outcome
            if not out.ok:
                return None, out.reason
            return self._pose(dev, t, packet.packet_id, out), None

    @contextmanager
    def _named_failures(self, where: str, t_s: float | None = None) -> Iterator[None]:
        """A plugin method's exception in the block as a :class:`MethodError`
        naming the method and ``where`` (the built-in methods' own bugs keep
        their traceback: the command line reports them as internal errors)."""
        try:
            yield
        except RadioposeError:
            raise
        except Exception as exc:
            if not self._plugin:
                raise
            at = "" if t_s is None else f" (t = {t_s:.6f} s)"
            why = (str(exc).strip().splitlines() or [""])[0][:200]
            raise MethodError(
                f"method {self.method!r} failed at {where}{at}: {type(exc).__name__}: {why}"
            ) from exc

    def look_ahead(self, packets: Sequence[PacketObservation]) -> None:
        """Offline (batch :func:`~radiopose.tracker.locate`, before the first
        :meth:`update`): hand a method that can use them
        (:class:`~radiopose.tracker.protocol.LooksAhead`) every packet of each
        enrolled device, in the order of the devices' first packets. Prepares
        those devices and their states as their first update would. The
        estimates do not depend on it."""
        if not isinstance(self.impl, LooksAhead):
            return
        by_device: dict[str, list[tuple[float, HeardRss, str]]] = {}
        for packet in packets:
            if not self.is_enrolled(packet.transmitter):
                continue
            dev = self.device(packet.transmitter)
            by_device.setdefault(dev.key, []).append(
                (float(packet.timestamp_s), dev.space.heard(packet), packet.packet_id)
            )
        for key, rows in by_device.items():
            dev = self._devices[key]
            state = self.states.get(key)
            if not isinstance(state, self.impl.state_type):
                state = self.states[key] = self.impl.new_state(dev)
            self.impl.look_ahead(dev, state, rows)

    def take_delayed(self) -> list[PoseEstimate]:
        """Estimates of earlier packets emitted since the last call (lagged methods)."""
        out, self._delayed = self._delayed, []
        return out

    def release(
        self, now_s: float, on_error: Callable[[str, Exception], None] | None = None
    ) -> list[PoseEstimate]:
        """Flush the devices whose last packet is at least the lag before ``now_s``
        (seconds, the packets' clock), with the estimates not yet taken.

        A silent device's last estimates then wait no longer than the lag
        after the latest packet of any device; a device still sending is
        untouched (its own packets release its estimates). ``on_error``: as
        in :meth:`flush`.
        """
        if self.lag_s is None:
            return self.take_delayed()
        quiet = [k for k, t in self._last_s.items() if t <= now_s - self.lag_s]
        for key in quiet:
            del self._last_s[key]
        return self.flush(quiet, on_error)

    def flush(
        self,
        keys: list[str] | None = None,
        on_error: Callable[[str, Exception], None] | None = None,
    ) -> list[PoseEstimate]:
        """Emit every estimate still held back (end of data, idle) for the devices
        ``keys`` (lower-case transmitters; ``None``: all), with those not yet taken.

        ``on_error(transmitter, exc)``, if given, is told of a device whose
        method failed in its flush; that device is dropped (:meth:`drop`) and
        the others are flushed. Without it the exception propagates."""
        for key in list(self._devices) if keys is None else keys:
            dev = self._devices[key]
            state = self.states.get(key)
            if not isinstance(state, self.impl.state_type):
                continue
            try:
                with self._named_failures(f"the flush of {dev.transmitter!r}"):
                    self._delayed += (
                        self._pose(dev, d.timestamp_s, d.packet_id, d.outcome)
                        for d in self.impl.flush(dev, state)
                    )
            except Exception as exc:
                if on_error is None:
                    raise
                self.drop(dev.transmitter)
                on_error(dev.transmitter, exc)
        return self.take_delayed()

    def drop(self, transmitter: str) -> None:
        """Forget ``transmitter``'s state (its next packet starts a new track)
        and its estimates still held back (the live server, after its method
        failed on one of the device's packets)."""
        key = transmitter.lower()
        self.states.pop(key, None)
        self._last_s.pop(key, None)
        self._latest.pop(key, None)

    def _pose(self, dev: Device, t_s: float, packet_id: str, out: Outcome) -> PoseEstimate:
        """The estimate of an answered outcome, checked against the contract: a
        finite position (x, y, z m) and orientation (azimuth, pitch, roll deg;
        ``None`` from a method that does not estimate orientation reads (0, 0,
        0), the contract's value), uncertainties ``None``/NaN or finite ≥ 0.

        Raises
        ------
        MethodError
            The method gave anything else (naming it and the packet).
        """
        where = f"packet {packet_id!r} of {dev.transmitter!r}"
        ori = out.orientation_deg
        if ori is None and not self.impl.estimates_orientation:
            ori = (0.0, 0.0, 0.0)
        try:
            xyz = tuple(float(v) for v in out.position_m)  # type: ignore[union-attr]
            abc = tuple(float(v) for v in ori)  # type: ignore[union-attr]
            pos_std = math.nan if out.position_std_m is None else float(out.position_std_m)
            az_std = math.nan if out.azimuth_std_deg is None else float(out.azimuth_std_deg)
        except (TypeError, ValueError):
            xyz = abc = ()
            pos_std = az_std = math.nan
        if len(xyz) != 3 or len(abc) != 3:
            raise MethodError(
                f"method {self.method!r} answered {where} without a position (x, y, z) and an "
                f"orientation (azimuth, pitch, roll): {out.position_m!r}, {out.orientation_deg!r}"
            )
        if not all(math.isfinite(v) for v in (*xyz, *abc)):
            raise MethodError(
                f"method {self.method!r} gave {where} a non-finite pose {xyz + abc!r}"
            )
        if any(v < 0 or v == math.inf for v in (pos_std, az_std)):
            raise MethodError(
                f"method {self.method!r} gave {where} an uncertainty that is not >= 0 and "
                f"finite: position_std_m {pos_std!r}, azimuth_std_deg {az_std!r}"
            )
        return PoseEstimate(
            t_s,
            dev.transmitter,
            packet_id,
            xyz,
            abc,
            self.method,
            pos_std,
            az_std,
        )


__all__ = ["Delayed", "Tracker"]
