"""802.11 frame decoding: a radiotap pcap/pcapng capture -> :class:`FrameRecords`.

What is hashed
--------------
``frame_sha256`` is the SHA-256 of the 802.11 MAC frame exactly as
transmitted, from the frame-control field up to but **excluding the FCS**:
the radiotap header is removed; the trailing 4-byte FCS is removed when the
radiotap Flags say it is present (0x10) — or, when the header has no Flags
field, when the last four bytes are the CRC-32 of the rest; driver padding
between the header and the payload of data frames (Flags 0x20) is removed.
Every receiver thus hashes the same bytes whatever its driver keeps.

Skipped frames (counted per reason in :data:`SKIP_REASONS` order, each frame
under its first reason): ``snapped`` (captured length < frame length),
``bad_radiotap``, ``bad_fcs`` (flagged by the driver), ``fcs_mismatch`` (FCS
present but wrong), ``no_signal``, ``implausible_rss`` (outside
:data:`PLAUSIBLE_RSS_DBM`), ``short_frame``, ``unsupported_frame`` (802.11
protocol version not 0, extension frames), ``no_transmitter`` (ACK, CTS,
...), ``wrong_link_type`` (pcapng interface that is not radiotap),
``no_timestamp`` (pcapng simple packet blocks), ``bad_timestamp`` (pcapng
timestamp plus ``if_tsoffset`` outside the int64 nanosecond range, about
years 1677–2262; a pcap record whose sub-second field is not below one
second), ``truncated_record`` (file cut short inside a record: the
frames before it are kept).
"""

from __future__ import annotations

import hashlib
import os
import zlib
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

from radiopose.capture.frames import (
    PLAUSIBLE_RSS_DBM,
    SKIP_REASONS,
    Capture,
    FrameRecords,
    ReceiverStats,
    receiver_id_from_path,
)
from radiopose.capture.pcapfile import (
    _LINKTYPE_NAMES,
    LINKTYPE_IEEE802_11_RADIOTAP,
    iter_raw_records,
)
from radiopose.capture.radiotap import (
    FLAG_BAD_FCS,
    FLAG_DATA_PAD,
    FLAG_FCS_AT_END,
    RadiotapError,
    fast_decode,
)
from radiopose.errors import InputError, unreadable
from radiopose.ids import receiver_id_problem

__all__ = ["hashed_bytes", "read_pcap"]

# Control frame subtypes that carry no transmitter address (addr2).
_CONTROL_WITHOUT_TA = frozenset((0, 1, 3, 6, 7, 12, 13))


def _mac_header_length(frame: bytes) -> int:
    """802.11 MAC header length in bytes of a data frame (for pad removal)."""
    fc1 = frame[1]
    n = 30 if (fc1 & 0x03) == 0x03 else 24  # ToDS and FromDS: addr4
    if frame[0] & 0x80:  # QoS subtypes
        n += 2
        if fc1 & 0x80:  # +HTC
            n += 4
    return n


def hashed_bytes(frame: bytes, flags: int | None) -> bytes | None:
    """The bytes of an 802.11 frame that radiopose hashes (see module docstring).

    Parameters
    ----------
    frame
        The 802.11 frame after the radiotap header, FCS possibly included.
    flags
        The radiotap Flags field, or ``None`` if the header has none.

    Returns
    -------
    bytes or None
        The frame without FCS and without data padding; ``None`` if an FCS
        announced by the flags does not match the frame.
    """
    if flags is None:
        if len(frame) > 4 and zlib.crc32(frame[:-4]) == int.from_bytes(frame[-4:], "little"):
            frame = frame[:-4]
    else:
        if flags & FLAG_FCS_AT_END:
            if len(frame) < 4 or zlib.crc32(frame[:-4]) != int.from_bytes(frame[-4:], "little"):
                return None
            frame = frame[:-4]
        if flags & FLAG_DATA_PAD and len(frame) >= 2 and (frame[0] >> 2) & 3 == 2:
            hlen = _mac_header_length(frame)
            pad = -hlen % 4
            if pad and len(frame) >= hlen + pad:
                frame = frame[:hlen] + frame[hlen + pad :]
    return frame


_LO_DBM, _HI_DBM = PLAUSIBLE_RSS_DBM


def read_pcap(
    path: str | os.PathLike[str],
    receiver_id: str | None = None,
    *,
    progress: Callable[[int], None] | None = None,
) -> Capture:
    """Read one receiver's pcap/pcapng capture of radiotap + 802.11 frames.

    Parameters
    ----------
    path
        The capture file.
    receiver_id
        Receiver of every frame; default :func:`receiver_id_from_path`.
    progress
        Called now and then with the number of bytes consumed so far.

    Returns
    -------
    Capture
        Frames in file order and one :class:`ReceiverStats`.

    Raises
    ------
    InputError
        Missing/empty/garbage file, wrong link type, corrupt record structure.
    """
    p = Path(path)
    rid = receiver_id_from_path(p) if receiver_id is None else receiver_id
    problem = receiver_id_problem(rid)
    if problem is not None:
        how = "the file name is" if receiver_id is None else "given"
        raise InputError(
            f"receiver id {rid[:40]!r} ({how}): {problem}; name the receiver with "
            "--receiver ID=FILE",
            path=p,
        )
    try:
        fh = open(p, "rb", buffering=1 << 20)  # noqa: SIM115
    except OSError as exc:
        raise unreadable(p, exc, "a capture file") from None
    with fh:
        return _decode_stream(fh, p, rid, progress)


def _decode_stream(
    fh: BinaryIO, path: Path, rid: str, progress: Callable[[int], None] | None
) -> Capture:
    skipped: Counter[str] = Counter()
    ts_list: list[int] = []
    hash_list: list[str] = []
    tx_list: list[str] = []
    rss_list: list[int] = []
    ant_list: list[tuple] = []
    mac_cache: dict[bytes, str] = {}
    sha256 = hashlib.sha256
    n_read = 0
    n_radiotap = 0
    other_links: set[int] = set()
    for ts_ns, link, data, length in iter_raw_records(fh, path):
        n_read += 1
        if progress is not None and not n_read & 0xFFF:
            progress(fh.tell())
        if link != LINKTYPE_IEEE802_11_RADIOTAP:
            if link == -1:
                skipped["truncated_record"] += 1
            elif link == -2:
                skipped["no_timestamp"] += 1
            elif link == -3:
                skipped["bad_timestamp"] += 1
            else:
                skipped["wrong_link_type"] += 1
                other_links.add(link)
            continue
        n_radiotap += 1
        if length > len(data):
            skipped["snapped"] += 1
            continue
        try:
            rt_len, signal, antennas, flags, bad_plcp = fast_decode(data)
        except RadiotapError:
            skipped["bad_radiotap"] += 1
            continue
        if bad_plcp or (flags is not None and flags & FLAG_BAD_FCS):
            skipped["bad_fcs"] += 1
            continue
        frame = hashed_bytes(data[rt_len:], flags)
        if frame is None:
            skipped["fcs_mismatch"] += 1
            continue
        if signal is None:
            skipped["no_signal"] += 1
            continue
        if not _LO_DBM <= signal <= _HI_DBM:
            skipped["implausible_rss"] += 1
            continue
        if len(frame) < 10:
            skipped["short_frame"] += 1
            continue
        fc0 = frame[0]
        ftype = (fc0 >> 2) & 3
        if fc0 & 3 or ftype == 3:
            skipped["unsupported_frame"] += 1
            continue
        if ftype == 1 and (fc0 >> 4) in _CONTROL_WITHOUT_TA:
            skipped["no_transmitter"] += 1
            continue
        if len(frame) < 16:
            skipped["short_frame"] += 1
            continue
        addr2 = frame[10:16]
        mac = mac_cache.get(addr2)
        if mac is None:
            mac = mac_cache[addr2] = addr2.hex(":")
        ts_list.append(ts_ns)
        hash_list.append(sha256(frame).hexdigest())
        tx_list.append(mac)
        rss_list.append(signal)
        ant_list.append(antennas)
    if progress is not None:
        progress(fh.tell())
    if n_read and not n_radiotap and other_links:
        links = ", ".join(
            f"{lt} ({_LINKTYPE_NAMES.get(lt, 'unsupported')})" for lt in sorted(other_links)
        )
        raise InputError(
            f"no radiotap interface (link types: {links}); radiopose needs link type "
            f"{LINKTYPE_IEEE802_11_RADIOTAP}",
            path=path,
        )
    n = len(ts_list)
    ant = np.empty(n, dtype=object)
    ant[:] = ant_list
    frames = FrameRecords(
        np.full(n, rid, dtype=object),
        np.asarray(ts_list, dtype=np.int64).reshape(n),
        np.asarray(hash_list, dtype=object).reshape(n),
        np.asarray(tx_list, dtype=object).reshape(n),
        np.asarray(rss_list, dtype=np.float64).reshape(n),
        ant,
    )
    stats = ReceiverStats(rid, str(path), n_read, n, dict(sorted(skipped.items(), key=_reason)))
    return Capture(frames, (stats,))


def _reason(item: tuple[str, int]) -> int:
    return SKIP_REASONS.index(item[0])
