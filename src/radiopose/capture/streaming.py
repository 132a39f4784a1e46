"""Streaming packet matching for the live server: :class:`StreamingMatcher`.

The incremental twin of :func:`radiopose.capture.sync.match_packets` (the
matching rules are written out in :mod:`radiopose.capture.sync`): frames are
pushed as they arrive and a chain is closed once no frame still to come can
join it, so memory stays bounded and the emitted packets equal the batch
result. Used by :mod:`radiopose.server.live`.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping, Sequence

import numpy as np

from radiopose.capture.records import FrameRecords
from radiopose.capture.sync import (
    _NS_PER_S,
    MAX_LAG_S,
    MAX_TOLERANCE_S,
    ClockModel,
    MatchCounts,
    _clock_list,
    _empty_packets,
    _ns_to_s,
    _reference_times,
    _rx_index,
    seconds_in_range,
)
from radiopose.errors import InputError
from radiopose.packets import Packets

__all__ = ["StreamingMatcher"]


class _Chain:
    __slots__ = ("alive", "first", "frames", "last", "version")

    def __init__(self, frame: tuple[int, int, float, str]) -> None:
        self.frames = [frame]  # (tau_ns, receiver index, rss_dbm, transmitter)
        self.first = self.last = frame[0]
        self.version = 0
        self.alive = True


class StreamingMatcher:
    """Incremental twin of :func:`match_packets` with bounded memory.

    Push frames as they arrive (each receiver's frames in time order; chunks
    may mix receivers); every push returns the packets that can no longer
    change. A chain is closed once every receiver's clock-corrected time has
    passed its last frame by more than the tolerance, or the most advanced
    receiver has passed it by ``max_lag_s``; frames older than what is already
    closed are *late*: dropped and counted. With no late frames the emitted
    packets, ids included, equal the batch result. A chain whose frames name
    different transmitters for one hash (inconsistent reports, which the batch
    matcher refuses) is dropped and counted (``ambiguous_transmitter``): the
    live server must not stop on one receiver's bad report.

    Parameters
    ----------
    receivers
        Receiver ids (packet rows follow this order).
    clocks
        ``receiver_id -> ClockModel`` (e.g. from :func:`estimate_clocks` on a
        calibration period); missing receivers use the reference clock.
    tolerance_s
        Matching tolerance, seconds.
    max_lag_s
        See :class:`SyncConfig`, seconds.
    """

    _mixed_tx = 0  # class default: a checkpoint pickled before this count reads 0

    def __init__(
        self,
        receivers: Sequence[str],
        clocks: Mapping[str, ClockModel] | None = None,
        *,
        tolerance_s: float = 0.005,
        max_lag_s: float = 30.0,
    ) -> None:
        self.receivers = tuple(receivers)
        if not self.receivers or len(set(self.receivers)) != len(self.receivers):
            raise InputError(
                f"StreamingMatcher: receivers {list(self.receivers)!r} must be distinct and "
                "at least one (a receiver listed twice never advances its watermark)"
            )
        if not seconds_in_range(tolerance_s, MAX_TOLERANCE_S):
            raise InputError(
                f"StreamingMatcher: tolerance_s = {tolerance_s!r} must be a number in "
                f"(0, {MAX_TOLERANCE_S:g}] s"
            )
        self.set_max_lag(max_lag_s)
        self._clocks = _clock_list(self.receivers, clocks)
        self._tol = round(tolerance_s * _NS_PER_S)
        self._chains: dict[str, list[_Chain]] = {}
        self._heap: list[tuple[int, str, int, int, _Chain]] = []
        self._seq = 0
        self._watermark: list[int | None] = [None] * len(self.receivers)
        self._horizon: int | None = None  # frames with tau below it are late
        self._next_id = 0
        self._open = 0
        self._frames = 0
        self._late = 0
        self._by_count: dict[int, int] = {}
        self._dup = 0
        self._spread = 0
        self._amb_frames = 0
        self._mixed_tx = 0

    def set_max_lag(self, max_lag_s: float) -> None:
        """Close chains at the latest ``max_lag_s`` behind the most advanced
        receiver from the next push on (see ``max_lag_s`` of the constructor)."""
        if not seconds_in_range(max_lag_s, MAX_LAG_S, allow_inf=True):
            raise InputError(
                f"StreamingMatcher: max_lag_s = {max_lag_s!r} must be a number in "
                f"(0, {MAX_LAG_S:g}] s or inf (no limit)"
            )
        self._lag = round(max_lag_s * _NS_PER_S) if math.isfinite(max_lag_s) else None

    def behind_ns(self) -> dict[str, int | None]:
        """Per receiver, how far (reference-clock ns) its latest frame is behind the
        most advanced receiver's; ``None`` for a receiver not heard yet."""
        known = [w for w in self._watermark if w is not None]
        top = max(known) if known else 0
        return {
            r: None if w is None else top - w
            for r, w in zip(self.receivers, self._watermark, strict=True)
        }

    def set_clocks(self, clocks: Mapping[str, ClockModel]) -> None:
        """Use ``clocks`` for the frames pushed from now on (a re-estimate of the
        receivers' clocks; frames already pushed keep the times they were given).
        Missing receivers use the reference clock."""
        self._clocks = _clock_list(self.receivers, clocks)

    @property
    def open_frames(self) -> int:
        """Frames held in open chains (the matcher's memory)."""
        return self._open

    @property
    def counts(self) -> MatchCounts:
        """Counts so far."""
        return MatchCounts(
            frames=self._frames,
            packets=sum(self._by_count.values()),
            packets_by_receivers=dict(sorted(self._by_count.items())),
            ambiguous_duplicate=self._dup,
            ambiguous_spread=self._spread,
            ambiguous_frames=self._amb_frames,
            late_frames=self._late,
            ambiguous_transmitter=self._mixed_tx,
        )

    def push(self, frames: FrameRecords) -> Packets:
        """Add frames; return the packets closed by them."""
        if len(frames) == 0:
            return _empty_packets()
        rx = _rx_index(frames, self.receivers)
        tau = _reference_times(frames, rx, self._clocks)
        tol = self._tol
        wm = self._watermark
        horizon = self._horizon
        for k in range(len(frames)):
            self._frames += 1
            t = int(tau[k])
            if horizon is not None and t < horizon:
                self._late += 1
                continue
            r = int(rx[k])
            if wm[r] is None or t > wm[r]:  # type: ignore[operator]
                wm[r] = t
            h = frames.frame_sha256[k]
            frame = (t, r, float(frames.rss_dbm[k]), frames.transmitter[k])
            self._open += 1
            chains = self._chains.get(h)
            if chains is None:
                chain = _Chain(frame)
                self._chains[h] = [chain]
            else:
                near = [c for c in chains if c.first - tol <= t <= c.last + tol]
                if not near:
                    chain = _Chain(frame)
                    chains.append(chain)
                else:
                    chain = near[0]
                    chain.frames.append(frame)
                    for other in near[1:]:  # the frame bridges chains: merge
                        chain.frames.extend(other.frames)
                        other.alive = False
                        chains.remove(other)
                    chain.first = min(chain.first, t, *(o.first for o in near[1:]))
                    chain.last = max(chain.last, t, *(o.last for o in near[1:]))
                    chain.version += 1
            self._seq += 1
            heapq.heappush(self._heap, (chain.last + tol, h, self._seq, chain.version, chain))
        known = [w for w in wm if w is not None]
        if len(known) < len(wm):
            bound = None
        else:
            bound = min(known)
        if self._lag is not None and known:
            lag_bound = max(known) - self._lag
            bound = lag_bound if bound is None else max(bound, lag_bound)
        if bound is None:
            return _empty_packets()
        return self._close(bound)

    def flush(self) -> Packets:
        """Close every open chain (end of the stream) and return its packets."""
        known = [w for w in self._watermark if w is not None]
        if not known:
            return _empty_packets()
        return self._close(max(known) + 2 * self._tol + 1)

    def _close(self, bound: int) -> Packets:
        """Emit chains whose ``last + tol < bound``; frames below ``bound`` become late."""
        heap = self._heap
        ids: list[str] = []
        times_ns: list[int] = []
        txs: list[str] = []
        rxs: list[str] = []
        rss: list[float] = []
        while heap and heap[0][0] < bound:
            _key, h, _seq, version, chain = heapq.heappop(heap)
            if not chain.alive or version != chain.version:
                continue
            chain.alive = False
            chains = self._chains[h]
            chains.remove(chain)
            if not chains:
                del self._chains[h]
            fr = chain.frames
            n = len(fr)
            self._open -= n
            if any(f[3] != fr[0][3] for f in fr):  # one hash, two transmitters
                self._mixed_tx += 1
                self._amb_frames += n
                continue
            receivers = {f[1] for f in fr}
            if len(receivers) != n:
                self._dup += 1
                self._amb_frames += n
                continue
            if chain.last - chain.first > self._tol:
                self._spread += 1
                self._amb_frames += n
                continue
            fr.sort(key=lambda f: f[1])
            first = chain.first
            mean_ns = first + sum(f[0] - first for f in fr) // n
            pid = str(self._next_id)
            self._next_id += 1
            self._by_count[n] = self._by_count.get(n, 0) + 1
            tx = fr[0][3]
            for f in fr:
                ids.append(pid)
                times_ns.append(mean_ns)
                txs.append(tx)
                rxs.append(self.receivers[f[1]])
                rss.append(f[2])
        self._horizon = bound if self._horizon is None else max(self._horizon, bound)
        if not ids:
            return _empty_packets()
        return Packets(
            packet_id=np.asarray(ids, dtype=object),
            timestamp_s=_ns_to_s(np.asarray(times_ns, dtype=np.int64)),
            transmitter=np.asarray(txs, dtype=object),
            receiver_id=np.asarray(rxs, dtype=object),
            rss_dbm=np.asarray(rss, dtype=np.float64),
        )
