"""Packet synchronisation: the same frame at several receivers -> one packet.

Receivers hear the same transmission at (almost) the same instant, and hash
the same bytes (:mod:`radiopose.capture.records`). Their clocks, however, are
only loosely synchronised: a constant offset plus a drift of a few ppm, which
over hours moves the receivers apart by far more than any sensible matching
tolerance. Synchronisation therefore has two steps.

1. **Clock estimation** (:func:`estimate_clocks`). Against a reference
   receiver (default: the first that kept any frame), each receiver's clock
   follows::

       t_rx = t_ref + offset + drift·(t_ref - epoch)

   Pairs come from *unambiguous* matches: hashes seen exactly once in the
   reference capture and exactly once in the receiver's. Some of these are
   still coincidences far apart in time (identical frames sent hours apart),
   so the line is found robustly: every single pair (offset only) and every
   pair of pairs at least ``min_drift_span_s`` apart (offset and drift, within
   ``max_drift_ppm``) proposes a model, scored with the truncated loss
   ``Σ min(|residual|, tolerance)`` (MSAC); the best is refined by least
   squares on its inliers (``|residual| <= tolerance``) until the inlier set is
   stable. ``epoch`` is the median reference time of the inliers, where the
   offset is best determined.

2. **Matching** (:func:`match_packets`; its streaming twin
   :class:`~radiopose.capture.streaming.StreamingMatcher`). Each
   frame's time is mapped to the reference clock. Frames with the same hash
   are chained while consecutive (mapped) times are at most ``tolerance``
   apart; each chain is a candidate packet. It is a packet only if no receiver
   appears twice in it (identical retransmissions or duplicates within the
   tolerance are ambiguous) and it spans at most ``tolerance`` (a chain
   stretched by intermediate frames is ambiguous); otherwise it is dropped and
   counted. A hash that recurs far apart in time forms several chains, each
   judged on its own. A receiver that missed the frame simply has no row.
   A frame's hash covers its transmitter address (addr2), so frames with one
   hash that name different transmitters are inconsistent input: the batch
   matcher refuses them (:class:`TransmitterConflictError`, which
   :func:`synchronise` reports at the capture file and line); the streaming
   matcher, which must not stop, drops such a chain and counts it.

Packets are numbered in order of (time of their last frame, hash); a
packet's time is the mean of its frames' reference-clock times, its rows are
in receiver order. The streaming matcher closes a chain once no frame still
to come can join it and emits exactly what the batch matcher does.

The module stays one piece (~820 lines, a third of it docstrings): the
clock fit, the batch matcher and the report share one set of value objects
and one statement of the matching rules; the streaming matcher, the one part
used apart (by the live server), lives in :mod:`radiopose.capture.streaming`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from radiopose.capture.records import Capture, FrameRecords, ReceiverStats
from radiopose.errors import InputError, check_setting_types
from radiopose.packets import Packets

if TYPE_CHECKING:
    from radiopose.capture.streaming import StreamingMatcher as StreamingMatcher  # lazily, below

__all__ = [
    "ClockModel",
    "HashCounts",
    "MatchCounts",
    "SyncConfig",
    "SyncReport",
    "TransmitterConflictError",
    "estimate_clocks",
    "match_packets",
    "synchronise",
]

_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class SyncConfig:
    """Synchronisation settings.

    Attributes
    ----------
    tolerance_s
        Matching tolerance after clock correction, seconds (also the inlier
        threshold of clock estimation).
    reference
        Reference receiver id; ``None`` = the first receiver that kept any frame.
    max_drift_ppm
        Largest clock drift considered, ppm.
    min_pairs
        Fewest agreeing unambiguous pairs for a clock estimate; with fewer the
        receiver's clock is assumed to equal the reference's (method ``none``).
    min_drift_span_s
        Shortest time span of pairs over which a drift is estimated, seconds;
        shorter spans give an offset only.
    max_candidates
        Pairs sampled (evenly in time) to propose clock models.
    max_lag_s
        Streaming only: a chain is closed once the most advanced receiver is
        this far past it even if another receiver lags (its late frames are
        then dropped and counted), seconds. Bounds the matcher's memory.
    """

    tolerance_s: float = 0.005
    reference: str | None = None
    max_drift_ppm: float = 500.0
    min_pairs: int = 2
    min_drift_span_s: float = 5.0
    max_candidates: int = 150
    max_lag_s: float = 30.0

    def __post_init__(self) -> None:
        check_setting_types(self, "sync")
        for name, ok, allowed in (
            ("tolerance_s", seconds_in_range(self.tolerance_s, MAX_TOLERANCE_S), "(0, 60] s"),
            ("max_lag_s", seconds_in_range(self.max_lag_s, MAX_LAG_S), "(0, 86400] s"),
            ("max_drift_ppm", 0 <= self.max_drift_ppm <= 1e6, "[0, 1e6] ppm"),
            ("min_pairs", 1 <= self.min_pairs <= 1_000_000, "[1, 1000000]"),
            ("min_drift_span_s", self.min_drift_span_s >= 0, ">= 0 s"),
            ("max_candidates", 1 <= self.max_candidates <= 1_000_000, "[1, 1000000]"),
        ):
            if not ok:
                raise InputError(
                    f"sync setting {name} = {getattr(self, name)!r} is out of range "
                    f"(allowed: {allowed})"
                )


MAX_TOLERANCE_S = 60.0
"""Largest matching tolerance, seconds (:class:`SyncConfig`, :func:`match_packets`,
the streaming matcher)."""
MAX_LAG_S = 86_400.0
"""Largest streaming lag, seconds (``max_lag_s``)."""


def seconds_in_range(value: object, high_s: float, allow_inf: bool = False) -> bool:
    """Whether ``value`` is a number of seconds in ``(0, high_s]`` (or ``inf``
    when ``allow_inf``: no limit); a bool is not a number here. The one test
    of the sync settings' tolerance and lag, wherever they are given."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return False
    return 0 < value <= high_s or (allow_inf and value == float("inf"))


@dataclass(frozen=True)
class ClockModel:
    """A receiver clock against the reference clock.

    ``t_rx = t_ref + offset + drift_ppm·1e-6·(t_ref - epoch)``, all in
    nanoseconds internally.

    Attributes
    ----------
    receiver_id
        The receiver.
    offset_ns
        Receiver clock minus reference clock at ``epoch_ns``, ns.
    drift_ppm
        Rate of the receiver clock relative to the reference, minus one, ppm.
    epoch_ns
        Reference-clock time at which ``offset_ns`` holds, ns.
    pairs
        Unambiguous pairs with the reference that were available.
    inliers
        Pairs consistent with the model.
    residual_rms_s
        RMS residual of the inliers, seconds.
    method
        ``"reference"``, ``"offset+drift"``, ``"offset"`` or ``"none"``.
    """

    receiver_id: str
    offset_ns: int = 0
    drift_ppm: float = 0.0
    epoch_ns: int = 0
    pairs: int = 0
    inliers: int = 0
    residual_rms_s: float = 0.0
    method: str = "reference"

    @property
    def offset_s(self) -> float:
        """Offset in seconds."""
        return self.offset_ns / _NS_PER_S

    @property
    def epoch_s(self) -> float:
        """Epoch in seconds (reference clock)."""
        return self.epoch_ns / _NS_PER_S

    def to_reference_ns(self, timestamp_ns: NDArray[np.int64]) -> NDArray[np.int64]:
        """Map receiver-clock times to the reference clock, int64 ns.

        Inverts the model: ``t_ref = t_rx - offset - drift/(1+drift)·(t_rx - offset - epoch)``,
        the small correction computed in float64 and rounded to the nanosecond.
        """
        t = np.asarray(timestamp_ns, dtype=np.int64) - np.int64(self.offset_ns)
        if self.drift_ppm == 0.0:
            return t
        k = self.drift_ppm * 1e-6
        since = (t - np.int64(self.epoch_ns)).astype(np.float64)
        return t - np.rint(since * (k / (1.0 + k))).astype(np.int64)


@dataclass(frozen=True)
class MatchCounts:
    """What matching did with the frames.

    Attributes
    ----------
    frames
        Frames considered.
    packets
        Packets formed.
    packets_by_receivers
        ``number of receivers -> packets`` heard by that many receivers.
    ambiguous_duplicate
        Chains dropped because a receiver has the hash twice within the tolerance.
    ambiguous_spread
        Chains dropped because they span more than the tolerance.
    ambiguous_frames
        Frames in dropped chains.
    late_frames
        Streaming: frames older than what was already closed (dropped).
    ambiguous_transmitter
        Streaming: chains dropped because their frames name different
        transmitters for one hash (inconsistent reports: a frame's hash covers
        its transmitter; the batch matcher refuses them, :class:`TransmitterConflictError`).
        Their frames are counted in ``ambiguous_frames``.
    """

    frames: int = 0
    packets: int = 0
    packets_by_receivers: dict[int, int] = field(default_factory=dict)
    ambiguous_duplicate: int = 0
    ambiguous_spread: int = 0
    ambiguous_frames: int = 0
    late_frames: int = 0
    ambiguous_transmitter: int = 0


class TransmitterConflictError(InputError):
    """Two frames with the same ``frame_sha256`` name different transmitters.

    A frame's hash covers its transmitter address (addr2, see
    :mod:`radiopose.capture.dot11`), so such frames cannot be one frame and
    neither transmitter can be trusted: inconsistent input, never a packet.
    Raised by :func:`match_packets` with ``rows = (first, other)``: indices
    into the frames given of the first frame of that hash and the first frame
    that contradicts it (input order); :func:`synchronise` reports them at
    their capture files and lines.
    """

    def __init__(self, message: str, rows: tuple[int, int]) -> None:
        super().__init__(message, column="transmitter")
        self.rows = rows


@dataclass(frozen=True)
class HashCounts:
    """What became of the frame hashes (batch matching only).

    Attributes
    ----------
    repeated
        Hashes that formed more than one chain (the same bytes far apart in time).
    shared
        Hashes heard by two or more receivers, at any times.
    shared_matched
        Of those, hashes in at least one packet heard by two or more receivers.
    shared_ambiguous
        Of the rest, hashes whose copies at two or more receivers met within the
        tolerance only in dropped (ambiguous) chains.
    shared_apart
        Of the rest, hashes whose copies at different receivers are never
        within the tolerance after clock correction: the same bytes sent at
        different times (e.g. a repeated probe request), not one packet.
    """

    repeated: int = 0
    shared: int = 0
    shared_matched: int = 0
    shared_ambiguous: int = 0
    shared_apart: int = 0


@dataclass(frozen=True)
class SyncReport:
    """Everything ``radiopose sync`` reports.

    Attributes
    ----------
    reference
        Reference receiver.
    tolerance_s
        Matching tolerance, seconds.
    receivers
        Reading statistics per receiver (frames read, kept, skipped by reason).
    clocks
        Clock estimate per receiver (reference first).
    counts
        Matching counts.
    hashes
        What became of the frame hashes (shared between receivers or not).
    """

    reference: str
    tolerance_s: float
    receivers: tuple[ReceiverStats, ...]
    clocks: tuple[ClockModel, ...]
    counts: MatchCounts
    hashes: HashCounts = field(default_factory=HashCounts)

    def lines(self) -> list[str]:
        """A human-readable summary, one item per line."""
        out = ["frames per receiver:"]
        for s in self.receivers:
            skip = ", ".join(f"{k} {v}" for k, v in s.skipped.items()) or "none"
            out.append(
                f"  {s.receiver_id}: read {s.frames_read}, kept {s.frames_kept}, skipped: {skip}"
            )
        out.append(f"clocks against reference {self.reference}:")
        for c in self.clocks:
            if c.method == "reference":
                out.append(f"  {c.receiver_id}: reference")
                continue
            if c.method == "none":
                out.append(
                    f"  {c.receiver_id}: not estimated ({c.inliers} agreeing of {c.pairs} "
                    "unambiguous pairs); assumed equal to the reference clock"
                )
                continue
            out.append(
                f"  {c.receiver_id}: offset {c.offset_s:+.6f} s, drift {c.drift_ppm:+.3f} ppm "
                f"at epoch {c.epoch_s:.3f} s ({c.method}; {c.inliers}/{c.pairs} pairs, "
                f"rms {c.residual_rms_s * 1e6:.0f} us)"
            )
        k = self.counts
        by = ", ".join(f"{n} receivers: {m}" for n, m in sorted(k.packets_by_receivers.items()))
        out.append(
            f"packets: {k.packets} (tolerance {self.tolerance_s * 1e3:g} ms)"
            + (f"; {by}" if by else "")
        )
        out.append(
            f"ambiguous: {k.ambiguous_duplicate} duplicated at a receiver, "
            f"{k.ambiguous_spread} spread over more than the tolerance "
            f"({k.ambiguous_frames} frames dropped); "
            f"hashes recurring far apart: {self.hashes.repeated}"
        )
        h = self.hashes
        out.append(
            f"hashes heard by 2+ receivers: {h.shared}; in a packet of 2+ receivers: "
            f"{h.shared_matched}; only in ambiguous chains: {h.shared_ambiguous}; "
            f"never within the tolerance (the same bytes sent at other times, or a clock "
            f"error beyond the tolerance): {h.shared_apart}"
        )
        if k.late_frames:
            out.append(f"late frames dropped: {k.late_frames}")
        if k.ambiguous_transmitter:
            out.append(
                f"chains dropped for naming different transmitters: {k.ambiguous_transmitter}"
            )
        return out


# --------------------------------------------------------------------------
# clock estimation


def _once(hashes: NDArray[np.object_]) -> tuple[NDArray[np.object_], NDArray[np.intp]]:
    """Hashes occurring exactly once, and their positions."""
    if hashes.size == 0:
        return hashes, np.empty(0, np.intp)
    uniq, first, counts = np.unique(hashes, return_index=True, return_counts=True)
    keep = counts == 1
    return uniq[keep], first[keep]


def _line_fit(
    x: NDArray[np.float64], d: NDArray[np.float64], with_slope: bool
) -> tuple[float, float]:
    if with_slope:
        xm = float(np.mean(x))
        dm = float(np.mean(d))
        dx = x - xm
        b = float(np.dot(dx, d - dm) / np.dot(dx, dx))
        return dm - b * xm, b
    return float(np.median(d)), 0.0


def _fit_clock(
    t_ref_ns: NDArray[np.int64], t_rx_ns: NDArray[np.int64], config: SyncConfig
) -> tuple[int, float, int, int, float, str]:
    """Robust line through (t_ref, t_rx - t_ref); see the module docstring.

    Returns ``(offset_ns, drift_ppm, epoch_ns, inliers, rms_s, method)``.
    """
    m = t_ref_ns.shape[0]
    if m == 0:
        return 0, 0.0, 0, 0, 0.0, "none"
    order = np.argsort(t_ref_ns, kind="stable")
    t_ref_ns = t_ref_ns[order]
    t_rx_ns = t_rx_ns[order]
    x0 = int(t_ref_ns[0])
    x = (t_ref_ns - x0).astype(np.float64) / _NS_PER_S
    d = (t_rx_ns - t_ref_ns).astype(np.float64) / _NS_PER_S
    tol = config.tolerance_s
    max_b = config.max_drift_ppm * 1e-6

    # Candidate models from an even subsample: singles (offset) and pairs (line).
    cand = np.unique(np.linspace(0, m - 1, min(m, config.max_candidates)).astype(np.intp))
    xc, dc = x[cand], d[cand]
    i, j = np.triu_indices(cand.size, k=1)
    span = xc[j] - xc[i]
    ok = span >= config.min_drift_span_s
    i, j, span = i[ok], j[ok], span[ok]
    b_pair = (dc[j] - dc[i]) / span
    ok = np.abs(b_pair) <= max_b
    b_all = np.concatenate([np.zeros(cand.size), b_pair[ok]])
    a_all = np.concatenate([dc, dc[i[ok]] - b_pair[ok] * xc[i[ok]]])
    ev = np.unique(np.linspace(0, m - 1, min(m, 2000)).astype(np.intp))
    xe, de = x[ev], d[ev]
    loss = np.empty(a_all.size)
    step = max(1, 4_000_000 // max(ev.size, 1))
    for s in range(0, a_all.size, step):
        r = de[None, :] - a_all[s : s + step, None] - b_all[s : s + step, None] * xe[None, :]
        loss[s : s + step] = np.minimum(np.abs(r), tol).sum(axis=1)
    best = int(np.argmin(loss))  # first minimum: deterministic
    a, b = float(a_all[best]), float(b_all[best])

    inl = np.abs(d - a - b * x) <= tol
    for _ in range(20):
        n_in = int(np.count_nonzero(inl))
        if n_in == 0:
            break
        xs = x[inl]
        with_slope = n_in >= 3 and float(xs[-1] - xs[0]) >= config.min_drift_span_s
        a, b = _line_fit(xs, d[inl], with_slope)
        if abs(b) > max_b:
            a, b = _line_fit(xs, d[inl], False)
        new = np.abs(d - a - b * x) <= tol
        if np.array_equal(new, inl):
            break
        inl = new
    n_in = int(np.count_nonzero(inl))
    if n_in < config.min_pairs:
        return 0, 0.0, 0, n_in, 0.0, "none"
    epoch_x = float(np.median(x[inl]))
    offset_s = a + b * epoch_x
    resid = d[inl] - a - b * x[inl]
    rms = float(np.sqrt(np.mean(resid**2)))
    method = "offset+drift" if b != 0.0 else "offset"
    epoch_ns = x0 + round(epoch_x * _NS_PER_S)
    return round(offset_s * _NS_PER_S), b * 1e6, epoch_ns, n_in, rms, method


def estimate_clocks(
    frames: FrameRecords, receivers: Sequence[str], config: SyncConfig | None = None
) -> dict[str, ClockModel]:
    """Estimate every receiver's clock against the reference receiver.

    Parameters
    ----------
    frames
        Frames of all receivers (any order).
    receivers
        Receiver ids; the reference is ``config.reference`` or the first.
    config
        Settings (tolerance, drift bounds).

    Returns
    -------
    dict
        ``receiver_id -> ClockModel``, in ``receivers`` order.
    """
    cfg = config or SyncConfig()
    if not receivers:
        raise InputError("estimate_clocks: no receivers given")
    ref = cfg.reference if cfg.reference is not None else receivers[0]
    if ref not in receivers:
        raise InputError(f"reference receiver {ref!r} is not one of {', '.join(receivers)}")
    by_rx = {r: np.flatnonzero(frames.receiver_id == r) for r in receivers}
    ref_rows = by_rx[ref]
    ref_once, ref_pos = _once(frames.frame_sha256[ref_rows])
    out: dict[str, ClockModel] = {}
    for r in receivers:
        if r == ref:
            out[r] = ClockModel(r)
            continue
        rows = by_rx[r]
        once, pos = _once(frames.frame_sha256[rows])
        _, ia, ib = np.intersect1d(ref_once, once, assume_unique=True, return_indices=True)
        t_ref = frames.timestamp_ns[ref_rows[ref_pos[ia]]]
        t_rx = frames.timestamp_ns[rows[pos[ib]]]
        off, drift, epoch, n_in, rms, method = _fit_clock(t_ref, t_rx, cfg)
        out[r] = ClockModel(r, off, drift, epoch, int(ia.size), n_in, rms, method)
    return out


# --------------------------------------------------------------------------
# batch matching


def _reference_times(
    frames: FrameRecords, rx_index: NDArray[np.intp], clocks: Sequence[ClockModel]
) -> NDArray[np.int64]:
    tau = np.empty(len(frames), dtype=np.int64)
    for k, clock in enumerate(clocks):
        m = rx_index == k
        tau[m] = clock.to_reference_ns(frames.timestamp_ns[m])
    return tau


def _rx_index(frames: FrameRecords, receivers: Sequence[str]) -> NDArray[np.intp]:
    lookup = {r: k for k, r in enumerate(receivers)}
    try:
        return np.fromiter((lookup[r] for r in frames.receiver_id), np.intp, len(frames))
    except KeyError as exc:
        raise InputError(
            f"frame of unknown receiver {exc.args[0]!r} (receivers: {', '.join(receivers)})"
        ) from None


def _ns_to_s(t_ns: NDArray[np.int64]) -> NDArray[np.float64]:
    # one formula for batch and streaming, so both give bit-identical floats
    return t_ns.astype(np.float64) / _NS_PER_S


def _empty_packets() -> Packets:
    obj = np.empty(0, dtype=object)
    return Packets(obj, np.empty(0), obj.copy(), obj.copy(), np.empty(0))


def _clock_list(
    receivers: Sequence[str], clocks: Mapping[str, ClockModel] | None
) -> list[ClockModel]:
    clocks = clocks or {}
    return [clocks.get(r, ClockModel(r)) for r in receivers]


def match_packets(
    frames: FrameRecords,
    receivers: Sequence[str],
    clocks: Mapping[str, ClockModel] | None = None,
    *,
    tolerance_s: float = 0.005,
) -> tuple[Packets, MatchCounts, HashCounts]:
    """Match frames across receivers into packets (batch, vectorised).

    Parameters
    ----------
    frames
        Frames of all receivers, any order.
    receivers
        Receiver ids; packet rows follow this order.
    clocks
        ``receiver_id -> ClockModel``; missing receivers use the reference clock.
    tolerance_s
        Matching tolerance on the reference clock, seconds.

    Returns
    -------
    packets, counts, hashes
        The ``packets.csv`` rows, the counts and what became of the hashes.

    Raises
    ------
    TransmitterConflictError
        Frames with the same hash name different transmitters (at the first
        frame, in input order, that contradicts its hash's first frame).
    """
    if not seconds_in_range(tolerance_s, MAX_TOLERANCE_S):
        raise InputError(f"tolerance_s = {tolerance_s!r} must be in (0, {MAX_TOLERANCE_S:g}] s")
    n = len(frames)
    if n == 0:
        return _empty_packets(), MatchCounts(), HashCounts()
    tol = round(tolerance_s * _NS_PER_S)
    rx = _rx_index(frames, receivers)
    tau = _reference_times(frames, rx, _clock_list(receivers, clocks))
    _, first_of_hash, hcode = np.unique(frames.frame_sha256, return_index=True, return_inverse=True)
    hcode = hcode.reshape(-1)
    _check_transmitters(frames, first_of_hash[hcode])

    order = np.lexsort((rx, tau, hcode))
    h, t, r = hcode[order], tau[order], rx[order]
    new = np.ones(n, dtype=bool)
    new[1:] = (h[1:] != h[:-1]) | (t[1:] - t[:-1] > tol)
    gid = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], n) - 1
    size = ends - starts + 1
    first, last = t[starts], t[ends]
    ng = starts.size

    by_rx = np.lexsort((r, gid))
    g2, r2 = gid[by_rx], r[by_rx]
    same = (g2[1:] == g2[:-1]) & (r2[1:] == r2[:-1])
    dup = np.zeros(ng, dtype=bool)
    dup[g2[1:][same]] = True
    spread = (last - first) > tol
    valid = ~dup & ~spread

    ghash = h[starts]
    repeated = int(np.count_nonzero(np.bincount(ghash) > 1))
    hashes = _hash_counts(h, r, gid, ghash, valid, repeated)

    vg = np.flatnonzero(valid)
    pk_order = vg[np.lexsort((ghash[vg], last[vg]))]
    pk_number = np.full(ng, -1, dtype=np.int64)
    pk_number[pk_order] = np.arange(pk_order.size)
    mean_ns = first + np.add.reduceat(t - first[gid], starts) // size

    rows = by_rx[valid[g2]]  # positions in the sorted arrays, grouped, receiver order
    rows = rows[np.argsort(pk_number[gid[rows]], kind="stable")]
    src = order[rows]  # original frame indices
    g_rows = gid[rows]
    first_src = order[by_rx[np.r_[0, np.flatnonzero(g2[1:] != g2[:-1]) + 1]]]  # per group
    tx_of_group = frames.transmitter[first_src]
    packets = Packets(
        packet_id=np.asarray([str(v) for v in pk_number[g_rows]], dtype=object).reshape(-1),
        timestamp_s=_ns_to_s(mean_ns[g_rows]),
        transmitter=tx_of_group[g_rows],
        receiver_id=frames.receiver_id[src],
        rss_dbm=frames.rss_dbm[src].astype(np.float64),
    )
    by_count = np.bincount(size[vg]) if vg.size else np.zeros(1, np.int64)
    counts = MatchCounts(
        frames=n,
        packets=int(vg.size),
        packets_by_receivers={int(k): int(v) for k, v in enumerate(by_count) if v},
        ambiguous_duplicate=int(np.count_nonzero(dup)),
        ambiguous_spread=int(np.count_nonzero(spread & ~dup)),
        ambiguous_frames=int(size[~valid].sum()),
    )
    return packets, counts, hashes


def _check_transmitters(frames: FrameRecords, first: NDArray[np.intp]) -> None:
    """Raise :class:`TransmitterConflictError` at the first frame (input order) whose
    transmitter differs from that of its hash's first frame ``first[k]``."""
    bad = np.flatnonzero(frames.transmitter != frames.transmitter[first])
    if bad.size == 0:
        return
    j = int(bad[0])
    i = int(first[j])

    def where(k: int) -> str:
        return f"at receiver {frames.receiver_id[k]} ({frames.timestamp_ns[k] / _NS_PER_S:.6f} s)"

    raise TransmitterConflictError(
        f"{frames.transmitter[j]!r} {where(j)}, but {frames.transmitter[i]!r} {where(i)}, "
        f"for the same frame_sha256 {str(frames.frame_sha256[j])[:12]}…; {_CONFLICT_WHY}",
        (i, j),
    )


_CONFLICT_WHY = "a frame's hash covers its transmitter address, so these cannot be one frame"


def _hash_counts(
    h: NDArray[np.intp],
    r: NDArray[np.intp],
    gid: NDArray[np.intp],
    ghash: NDArray[np.intp],
    valid: NDArray[np.bool_],
    repeated: int,
) -> HashCounts:
    """Account for every hash heard by 2+ receivers (sorted frame arrays of
    :func:`match_packets`: hash code, receiver index, chain id per frame)."""
    n_hash = int(h.max()) + 1
    # distinct receivers per hash, and per chain
    pairs = np.unique(np.stack([h, r]), axis=1)
    shared = np.bincount(pairs[0], minlength=n_hash) >= 2
    chain_pairs = np.unique(np.stack([gid, r]), axis=1)
    multi = np.bincount(chain_pairs[0], minlength=ghash.size) >= 2  # chain spans 2+ receivers
    matched = np.zeros(n_hash, dtype=bool)
    matched[ghash[valid & multi]] = True
    met = np.zeros(n_hash, dtype=bool)
    met[ghash[~valid & multi]] = True
    n_shared = int(np.count_nonzero(shared))
    n_matched = int(np.count_nonzero(shared & matched))
    n_ambiguous = int(np.count_nonzero(shared & ~matched & met))
    return HashCounts(
        repeated=repeated,
        shared=n_shared,
        shared_matched=n_matched,
        shared_ambiguous=n_ambiguous,
        shared_apart=n_shared - n_matched - n_ambiguous,
    )


# --------------------------------------------------------------------------
# the whole step


def synchronise(
    captures: Sequence[Capture], config: SyncConfig | None = None
) -> tuple[Packets, SyncReport]:
    """Captures of several receivers -> synchronised packets and a report.

    Parameters
    ----------
    captures
        One :class:`Capture` per file (a CSV capture may hold several receivers).
    config
        Settings.

    Returns
    -------
    packets, report
        The ``packets.csv`` rows and everything worth reporting.

    Raises
    ------
    InputError
        A receiver id in two captures, an unknown reference receiver, or frames
        with the same hash naming different transmitters (at the capture file
        and line, :class:`TransmitterConflictError`).
    """
    cfg = config or SyncConfig()
    stats: list[ReceiverStats] = []
    seen: dict[str, str] = {}
    for cap in captures:
        for s in cap.stats:
            if s.receiver_id in seen:
                raise InputError(
                    f"receiver id {s.receiver_id!r} appears in both {seen[s.receiver_id]} "
                    f"and {s.source}; name pcap receivers with --receiver ID=FILE, "
                    "or rename them in the CSV"
                )
            seen[s.receiver_id] = s.source
            stats.append(s)
    receivers = [s.receiver_id for s in stats]
    if not receivers:
        raise InputError(
            "the captures hold no frames of any receiver (a CSV capture without rows?)"
        )
    # Default reference: the first receiver that kept any frame (a capture
    # whose frames were all skipped cannot anchor the others' clocks).
    kept = [s.receiver_id for s in stats if s.frames_kept > 0]
    ref = cfg.reference if cfg.reference is not None else (kept or receivers)[0]
    if ref not in seen:
        raise InputError(f"unknown reference receiver {ref!r} (receivers: {', '.join(receivers)})")
    if cfg.reference != ref:
        cfg = SyncConfig(**{**cfg.__dict__, "reference": ref})
    frames = FrameRecords.concat([c.frames for c in captures])
    clocks = estimate_clocks(frames, receivers, cfg)
    try:
        packets, counts, hashes = match_packets(
            frames, receivers, clocks, tolerance_s=cfg.tolerance_s
        )
    except TransmitterConflictError as exc:
        raise _conflict_in_captures(captures, frames, exc.rows, seen) from None
    order = [ref] + [r for r in receivers if r != ref]
    report = SyncReport(
        reference=ref,
        tolerance_s=cfg.tolerance_s,
        receivers=tuple(stats),
        clocks=tuple(clocks[r] for r in order),
        counts=counts,
        hashes=hashes,
    )
    return packets, report


def _conflict_in_captures(
    captures: Sequence[Capture],
    frames: FrameRecords,
    rows: tuple[int, int],
    sources: Mapping[str, str],
) -> InputError:
    """The one-line error of a :class:`TransmitterConflictError` between frames
    ``rows`` of the captures' concatenated ``frames``: at the contradicting
    frame's file and line (CSV) naming the first frame's line (or, for a pcap,
    its receiver and time)."""
    starts = np.cumsum([0] + [len(c.frames) for c in captures])

    def place(k: int) -> tuple[str, int | None, str]:
        c = int(np.searchsorted(starts, k, side="right")) - 1
        lines = captures[c].lines
        line = None if lines is None else int(lines[k - starts[c]])
        t_s = frames.timestamp_ns[k] / _NS_PER_S
        return sources[str(frames.receiver_id[k])], line, f"{frames.receiver_id[k]} at {t_s:.6f} s"

    i, j = rows
    path_i, line_i, frame_i = place(i)
    path_j, line_j, frame_j = place(j)
    if line_i is None:  # a pcap frame
        other = f"{path_i} (the frame of receiver {frame_i})"
    else:
        other = f"line {line_i}" if path_i == path_j else f"{path_i}:{line_i}"
    this = "" if line_j is not None else f" (the frame of receiver {frame_j})"
    return InputError(
        f"{frames.transmitter[j]!r}{this}, but {other} has {frames.transmitter[i]!r} for the "
        f"same frame_sha256 {str(frames.frame_sha256[j])[:12]}…; {_CONFLICT_WHY}",
        path=path_j,
        line=line_j,
        column="transmitter",
    )


def __getattr__(name: str) -> object:
    # Old import path: the streaming matcher now lives in its own module
    # (it imports this one, so it cannot be imported here eagerly).
    if name == "StreamingMatcher":
        from radiopose.capture.streaming import StreamingMatcher

        return StreamingMatcher
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
