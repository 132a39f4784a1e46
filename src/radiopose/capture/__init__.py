"""Capture ingest and packet synchronisation.

Stage between the receivers and the tracker: monitor-mode captures (pcap /
pcapng with radiotap, or the CSV capture form) become per-frame records
(:mod:`~radiopose.capture.records`, with the radiotap decoder in
:mod:`~radiopose.capture.radiotap`); frames of several receivers are matched
into packets after estimating each receiver's clock offset and drift
(:mod:`~radiopose.capture.sync`, batch or streaming). :mod:`~radiopose.capture.writer`
writes simulated per-receiver pcaps. See ``docs/capture.md``.
"""

from radiopose.capture.radiotap import Radiotap, RadiotapError, decode_radiotap
from radiopose.capture.records import (
    PLAUSIBLE_RSS_DBM,
    SKIP_REASONS,
    Capture,
    FrameRecords,
    ReceiverStats,
    read_capture,
    read_capture_csv,
    read_pcap,
)
from radiopose.capture.streaming import StreamingMatcher
from radiopose.capture.sync import (
    ClockModel,
    MatchCounts,
    SyncConfig,
    SyncReport,
    estimate_clocks,
    match_packets,
    synchronise,
)
from radiopose.capture.writer import PcapSimulation, read_pcap_truth, write_receiver_pcaps

__all__ = [
    "PLAUSIBLE_RSS_DBM",
    "SKIP_REASONS",
    "Capture",
    "ClockModel",
    "FrameRecords",
    "MatchCounts",
    "PcapSimulation",
    "Radiotap",
    "RadiotapError",
    "ReceiverStats",
    "StreamingMatcher",
    "SyncConfig",
    "SyncReport",
    "decode_radiotap",
    "estimate_clocks",
    "match_packets",
    "read_capture",
    "read_capture_csv",
    "read_pcap",
    "read_pcap_truth",
    "synchronise",
    "write_receiver_pcaps",
]
