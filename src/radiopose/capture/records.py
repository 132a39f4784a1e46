"""Receiver captures in: pcap / pcapng / CSV -> per-frame records.

Each receiver's capture becomes a :class:`FrameRecords` table, one row per
usable 802.11 frame: ``receiver_id``, ``timestamp_ns`` (int64 nanoseconds of
the receiver's own clock), ``frame_sha256`` (hex), ``transmitter`` (addr2,
``"aa:bb:cc:dd:ee:ff"``), ``rss_dbm`` (radiotap antenna signal, see
:mod:`radiopose.capture.radiotap`) and the per-antenna signals.

The work is split along the pipeline: :mod:`~radiopose.capture.pcapfile`
iterates pcap/pcapng records, :mod:`~radiopose.capture.dot11` decodes 802.11
frames into records (what is hashed, what is skipped),
:mod:`~radiopose.capture.csvform` reads the CSV capture form, and
:mod:`~radiopose.capture.frames` holds the value objects. This module picks a
reader by content (:func:`read_capture`) and re-exports the public names.

Skipped frames are counted per reason in :data:`SKIP_REASONS` order; the
reasons are listed in :mod:`radiopose.capture.dot11`.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

from radiopose.capture.csvform import CSV_CAPTURE_COLUMNS, read_capture_csv
from radiopose.capture.dot11 import hashed_bytes, read_pcap
from radiopose.capture.frames import (
    MAX_TRANSMITTER_ID_CHARS,
    PLAUSIBLE_RSS_DBM,
    SKIP_REASONS,
    Capture,
    FrameRecords,
    ReceiverStats,
    canonical_transmitter,
    receiver_id_from_path,
    transmitter_id_problem,
)
from radiopose.capture.pcapfile import (
    LINKTYPE_IEEE802_11,
    LINKTYPE_IEEE802_11_RADIOTAP,
    is_pcap_start,
    iter_raw_records,
)
from radiopose.errors import InputError, unreadable

__all__ = [
    "CSV_CAPTURE_COLUMNS",
    "LINKTYPE_IEEE802_11",
    "LINKTYPE_IEEE802_11_RADIOTAP",
    "MAX_TRANSMITTER_ID_CHARS",
    "PLAUSIBLE_RSS_DBM",
    "SKIP_REASONS",
    "Capture",
    "FrameRecords",
    "ReceiverStats",
    "canonical_transmitter",
    "hashed_bytes",
    "iter_raw_records",
    "read_capture",
    "read_capture_csv",
    "read_pcap",
    "receiver_id_from_path",
    "transmitter_id_problem",
]


def read_capture(
    path: str | os.PathLike[str],
    receiver_id: str | None = None,
    *,
    progress: Callable[[int], None] | None = None,
) -> Capture:
    """Read a capture of any supported form, told apart by content.

    pcap / pcapng are recognised by their magic number, anything else is read
    as the CSV capture form (whose receiver ids come from its own column, so
    ``receiver_id`` must be ``None`` for it).

    Raises
    ------
    InputError
        See :func:`read_pcap` and :func:`read_capture_csv`.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise unreadable(p, exc, "a capture file") from None
    if not head:
        raise InputError("empty file, expected a pcap, pcapng or CSV capture", path=p)
    if is_pcap_start(head):
        return read_pcap(p, receiver_id, progress=progress)
    if not _looks_like_text(p):
        raise InputError(
            f"not a pcap, pcapng or CSV capture (starts with bytes {head.hex()})", path=p
        )
    if receiver_id is not None:
        raise InputError(
            "receiver ids of a CSV capture come from its receiver_id column; "
            "--receiver applies to pcap/pcapng files only",
            path=p,
        )
    return read_capture_csv(p)


def _looks_like_text(path: Path) -> bool:
    with open(path, "rb") as fh:
        sample = fh.read(4096)
    if b"\0" in sample:
        return False
    try:
        io.TextIOWrapper(io.BytesIO(sample), encoding="utf-8").read()
    except UnicodeDecodeError as exc:
        return exc.start > len(sample) - 4  # a character cut by the sample's end
    return True
