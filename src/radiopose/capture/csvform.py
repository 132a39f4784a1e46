"""The contract's CSV capture form -> :class:`~radiopose.capture.frames.Capture`.

Columns ``receiver_id, timestamp_s, frame_sha256, transmitter, rss_dbm`` (see
``spec/formats.md``); rows with an implausible RSS are skipped and counted like
pcap frames.
"""

from __future__ import annotations

import os
import re

import numpy as np

from radiopose.capture.frames import (
    PLAUSIBLE_RSS_DBM,
    Capture,
    FrameRecords,
    ReceiverStats,
    canonical_transmitter,
    transmitter_id_problem,
)
from radiopose.ids import check_receiver_ids
from radiopose.tables import Column, read_table
from radiopose.units import MAX_ABS_TIME_S, seconds_to_ns

__all__ = ["CSV_CAPTURE_COLUMNS", "read_capture_csv"]

_HEX64 = re.compile(r"^[0-9a-fA-F]{64}$")
_LO_DBM, _HI_DBM = PLAUSIBLE_RSS_DBM


CSV_CAPTURE_COLUMNS = (
    Column("receiver_id", "str"),
    Column("timestamp_s", low=0.0, high=MAX_ABS_TIME_S),  # int64 ns: up to year 2262
    Column("frame_sha256", "str"),
    Column("transmitter", "str"),
    Column("rss_dbm"),
)


def read_capture_csv(path: str | os.PathLike[str]) -> Capture:
    """Read the contract's CSV capture form.

    Columns ``receiver_id, timestamp_s, frame_sha256, transmitter, rss_dbm``;
    one file may hold several receivers. ``frame_sha256`` must be 64 hex
    digits and ``transmitter`` a transmitter id (the contract: no commas or
    whitespace; a MAC address is normalised to lowercase, ``:``-separated, any
    other id to lowercase, :func:`canonical_transmitter`). Rows with an
    implausible RSS are skipped and counted like pcap frames. Timestamps are
    rounded to the nearest nanosecond.

    Raises
    ------
    InputError
        Any table error (file, line, column), a bad hash or transmitter id.
    """
    t = read_table(path, CSV_CAPTURE_COLUMNS)
    check_receiver_ids(t)
    n = len(t)
    hashes = t["frame_sha256"]
    macs = t["transmitter"]
    for i in range(n):
        if not _HEX64.match(hashes[i]):
            raise t.error(i, "frame_sha256", f"not a SHA-256 hex digest: {hashes[i][:70]!r}")
        problem = transmitter_id_problem(macs[i])
        if problem:
            raise t.error(i, "transmitter", problem)
    rx = t["receiver_id"]
    rss = t["rss_dbm"]
    ok = (rss >= _LO_DBM) & (rss <= _HI_DBM)
    frames = FrameRecords(
        rx[ok],
        seconds_to_ns(t["timestamp_s"][ok]),
        np.asarray([h.lower() for h in hashes[ok]], dtype=object).reshape(-1),
        np.asarray([canonical_transmitter(m) for m in macs[ok]], dtype=object).reshape(-1),
        rss[ok].astype(np.float64),
    )
    stats = []
    for rid in dict.fromkeys(rx.tolist()):
        mine = rx == rid
        bad = int(np.count_nonzero(mine & ~ok))
        stats.append(
            ReceiverStats(
                rid,
                str(path),
                int(np.count_nonzero(mine)),
                int(np.count_nonzero(mine & ok)),
                {"implausible_rss": bad} if bad else {},
            )
        )
    return Capture(frames, tuple(stats), t.lines[ok])
