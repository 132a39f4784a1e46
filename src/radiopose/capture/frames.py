"""Per-frame records of receiver captures: the value objects every reader returns.

:class:`FrameRecords` (one row per usable 802.11 frame), :class:`ReceiverStats`
(what reading one receiver's capture gave, skipped frames counted per reason in
:data:`SKIP_REASONS` order), :class:`Capture` (both), the plausible RSS range and
the transmitter-id rules shared by the pcap reader, the CSV reader and the
server. The readers are :mod:`radiopose.capture.dot11` (pcap/pcapng) and
:mod:`radiopose.capture.csvform`; :mod:`radiopose.capture.records` picks one.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from radiopose.errors import InputError
from radiopose.ids import MAX_TRANSMITTER_ID_CHARS, transmitter_id_problem

__all__ = [
    "MAX_TRANSMITTER_ID_CHARS",
    "PLAUSIBLE_RSS_DBM",
    "SKIP_REASONS",
    "Capture",
    "FrameRecords",
    "ReceiverStats",
    "canonical_transmitter",
    "receiver_id_from_path",
    "transmitter_id_problem",
]

#: Inclusive range of RSS values accepted as physical, dBm.
PLAUSIBLE_RSS_DBM: tuple[float, float] = (-120.0, 0.0)

SKIP_REASONS: tuple[str, ...] = (
    "snapped",
    "bad_radiotap",
    "bad_fcs",
    "fcs_mismatch",
    "no_signal",
    "implausible_rss",
    "short_frame",
    "unsupported_frame",
    "no_transmitter",
    "wrong_link_type",
    "no_timestamp",
    "bad_timestamp",
    "truncated_record",
)

_MAC = re.compile(r"^[0-9a-fA-F]{2}([:-][0-9a-fA-F]{2}){5}$")


def canonical_transmitter(value: str) -> str:
    """The form transmitters are matched and stored in (case-insensitive ids): a MAC
    address lower case with ``:`` separators (``AA-BB-…`` → ``aa:bb:…``), any other
    id lower case."""
    return value.lower().replace("-", ":") if _MAC.match(value) else value.lower()


@dataclass(frozen=True, eq=False)
class FrameRecords:
    """Usable frames of one or more receivers, all arrays ``(n,)``.

    Attributes
    ----------
    receiver_id
        Receiver of each frame (object array of str).
    timestamp_ns
        Reception time on that receiver's clock, int64 nanoseconds.
    frame_sha256
        SHA-256 of the hashed bytes (see :mod:`radiopose.capture.dot11`), lowercase hex.
    transmitter
        addr2 as ``"aa:bb:cc:dd:ee:ff"``.
    rss_dbm
        RSS in dBm (float64).
    antenna_rss_dbm
        Per-antenna ``((antenna, dBm), ...)`` of each frame (empty tuple if none).
    """

    receiver_id: NDArray[np.object_]
    timestamp_ns: NDArray[np.int64]
    frame_sha256: NDArray[np.object_]
    transmitter: NDArray[np.object_]
    rss_dbm: NDArray[np.float64]
    antenna_rss_dbm: NDArray[np.object_] | None = None

    def __post_init__(self) -> None:
        n = self.timestamp_ns.shape[0]
        for name in ("receiver_id", "frame_sha256", "transmitter", "rss_dbm"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"FrameRecords.{name} must have shape ({n},)")
        bad = np.flatnonzero(~np.isfinite(self.rss_dbm))
        if bad.size:  # the readers refuse these; a table built in Python too
            k = int(bad[0])
            raise InputError(
                f"FrameRecords row {k} (from 0): RSS {self.rss_dbm[k]} dBm of receiver "
                f"{self.receiver_id[k]!r} is not a finite number"
            )
        if self.antenna_rss_dbm is None:
            empty = np.empty(n, dtype=object)
            empty[:] = [()] * n
            object.__setattr__(self, "antenna_rss_dbm", empty)

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    @classmethod
    def empty(cls) -> FrameRecords:
        """A table with no rows."""
        obj = np.empty(0, dtype=object)
        return cls(obj, np.empty(0, np.int64), obj.copy(), obj.copy(), np.empty(0))

    @classmethod
    def concat(cls, parts: Sequence[FrameRecords]) -> FrameRecords:
        """Rows of all ``parts`` in order."""
        if not parts:
            return cls.empty()
        return cls(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in (
                    "receiver_id",
                    "timestamp_ns",
                    "frame_sha256",
                    "transmitter",
                    "rss_dbm",
                    "antenna_rss_dbm",
                )
            )
        )

    def take(self, index: NDArray[np.intp] | NDArray[np.bool_] | slice) -> FrameRecords:
        """The rows selected by an index array, boolean mask or slice."""
        return FrameRecords(
            self.receiver_id[index],
            self.timestamp_ns[index],
            self.frame_sha256[index],
            self.transmitter[index],
            self.rss_dbm[index],
            self.antenna_rss_dbm[index],  # type: ignore[index]
        )

    def time_ordered(self) -> FrameRecords:
        """Rows sorted by ``timestamp_ns`` (stable: file order among equal times)."""
        order = np.argsort(self.timestamp_ns, kind="stable")
        return self.take(order)


@dataclass(frozen=True)
class ReceiverStats:
    """What reading one receiver's capture gave.

    Attributes
    ----------
    receiver_id
        The receiver.
    source
        The capture file.
    frames_read
        Records (pcap) or rows (CSV) read.
    frames_kept
        Frames turned into records.
    skipped
        ``reason -> count`` for every reason in :data:`SKIP_REASONS` that occurred.
    """

    receiver_id: str
    source: str
    frames_read: int
    frames_kept: int
    skipped: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Capture:
    """A read capture: its frames and per-receiver reading statistics.

    ``lines`` is the 1-based file line of each frame (``(n,)`` int64) where the
    form has lines (the CSV capture form), for errors that name a frame;
    ``None`` for pcap/pcapng, whose frames are named by receiver and time.
    """

    frames: FrameRecords
    stats: tuple[ReceiverStats, ...]
    lines: NDArray[np.int64] | None = None


def receiver_id_from_path(path: str | os.PathLike[str]) -> str:
    """Default receiver id of a capture: the file name without its extension(s)."""
    name = Path(path).name
    for ext in (".pcapng", ".pcap", ".cap", ".csv"):
        if name.lower().endswith(ext) and len(name) > len(ext):
            name = name[: -len(ext)]
    return name
