"""Receiver captures in: pcap / pcapng / CSV -> per-frame records.

Each receiver's capture becomes a :class:`FrameRecords` table, one row per
usable 802.11 frame: ``receiver_id``, ``timestamp_ns`` (int64 nanoseconds of
the receiver's own clock), ``frame_sha256`` (hex), ``transmitter`` (addr2,
``"aa:bb:cc:dd:ee:ff"``), ``rss_dbm`` (radiotap antenna signal, see
:mod:`radiopose.capture.radiotap`) and the per-antenna signals.

Record layer
------------
File, section and interface headers are parsed with dpkt's header classes
(``dpkt.pcap.FileHdr``, ``dpkt.pcapng.SectionHeaderBlock``,
``InterfaceDescriptionBlock`` and its options). The per-record loop is our
own: the record headers use the same layouts (``dpkt.pcap.PktHdr``, the
pcapng EPB/PB header) through precompiled ``struct`` formats. Neither
library's record reader meets the requirements (measured with dpkt 1.9.8 and
scapy 2.8.0, details in ``docs/capture.md``): ``dpkt.pcap.Reader`` yields
float/Decimal timestamps and no original length, ``dpkt.pcapng.Reader`` reads
only the first interface; scapy's ``RawPcapNgReader`` keeps the interfaces of
a previous section, ignores ``if_tsoffset``, does not report the interface id
and ends silently on a truncated or corrupt block. Timestamps are exact
integers: pcap µs or ns files, and pcapng with any number of sections and
interfaces, each with its own ``if_tsresol`` (powers of 10 or 2) and
``if_tsoffset``; a pcapng timestamp outside the int64 nanosecond range is
skipped as ``bad_timestamp``.

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
years 1677–2262), ``truncated_record`` (file cut short inside a record: the
frames before it are kept).
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import dpkt
import numpy as np
from numpy.typing import NDArray

from radiopose.capture.radiotap import (
    FLAG_BAD_FCS,
    FLAG_DATA_PAD,
    FLAG_FCS_AT_END,
    RadiotapError,
    fast_decode,
)
from radiopose.errors import InputError
from radiopose.tables import Column, read_table
from radiopose.units import MAX_ABS_TIME_S, seconds_to_ns

__all__ = [
    "CSV_CAPTURE_COLUMNS",
    "LINKTYPE_IEEE802_11_RADIOTAP",
    "PLAUSIBLE_RSS_DBM",
    "SKIP_REASONS",
    "Capture",
    "FrameRecords",
    "ReceiverStats",
    "hashed_bytes",
    "iter_raw_records",
    "read_capture",
    "read_capture_csv",
    "read_pcap",
    "receiver_id_from_path",
]

LINKTYPE_IEEE802_11 = 105
LINKTYPE_IEEE802_11_RADIOTAP = 127
_LINKTYPE_NAMES = {
    1: "Ethernet",
    105: "802.11 without radiotap",
    119: "802.11 with Prism header",
    163: "802.11 with AVS header",
    192: "PPI",
}

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

# A record larger than this is a corrupt length field, not a frame (libpcap's limit).
_MAX_RECORD_BYTES = 262_144

# Range of timestamp_ns (int64); pcapng ticks, resolution and offset can exceed it.
_NS_MIN = -(2**63)
_NS_MAX = 2**63 - 1

_PCAP_MAGICS = {
    dpkt.pcap.TCPDUMP_MAGIC,
    dpkt.pcap.TCPDUMP_MAGIC_NANO,
    dpkt.pcap.MODPCAP_MAGIC,
    dpkt.pcap.PMUDPCT_MAGIC,
    dpkt.pcap.PMUDPCT_MAGIC_NANO,
    dpkt.pcap.PACPDOM_MAGIC,
}
_PCAPNG_SHB = dpkt.pcapng.PCAPNG_BT_SHB
_PCAPNG_BOM_BE = b"\x1a\x2b\x3c\x4d"
_PCAPNG_BOM_LE = b"\x4d\x3c\x2b\x1a"
# dpkt's section header and interface description block classes, by struct byte order
_PCAPNG_SHB_CLASS = {
    "<": dpkt.pcapng.SectionHeaderBlockLE,
    ">": dpkt.pcapng.SectionHeaderBlock,
}
_PCAPNG_IDB_CLASS = {
    "<": dpkt.pcapng.InterfaceDescriptionBlockLE,
    ">": dpkt.pcapng.InterfaceDescriptionBlock,
}

# Control frame subtypes that carry no transmitter address (addr2).
_CONTROL_WITHOUT_TA = frozenset((0, 1, 3, 6, 7, 12, 13))

_HEX64 = re.compile(r"^[0-9a-fA-F]{64}$")
_MAC = re.compile(r"^[0-9a-fA-F]{2}([:-][0-9a-fA-F]{2}){5}$")
MAX_TRANSMITTER_ID_CHARS = 64


def transmitter_id_problem(value: str) -> str | None:
    """Why ``value`` is not a transmitter id, or ``None`` if it is one.

    The contract: any string without commas or whitespace (a MAC address for
    real devices, a name such as ``phone`` in simulations); here also printable
    and 1–64 characters.
    """
    if not 0 < len(value) <= MAX_TRANSMITTER_ID_CHARS:
        return f"a transmitter id has 1-{MAX_TRANSMITTER_ID_CHARS} characters, got {len(value)}"
    if "," in value or any(c.isspace() for c in value) or not value.isprintable():
        return f"not a transmitter id (no commas, whitespace or control characters): {value[:40]!r}"
    return None


def canonical_transmitter(value: str) -> str:
    """The form transmitters are matched and stored in (case-insensitive ids): a MAC
    address lower case with ``:`` separators (``AA-BB-…`` → ``aa:bb:…``), any other
    id lower case."""
    return value.lower().replace("-", ":") if _MAC.match(value) else value.lower()


# --------------------------------------------------------------------------
# value objects


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
        SHA-256 of the hashed bytes (see module docstring), lowercase hex.
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
                raise ValueError(f"FrameRecords.{name} must have shape ({n},)")
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
    """A read capture: its frames and per-receiver reading statistics."""

    frames: FrameRecords
    stats: tuple[ReceiverStats, ...]


# --------------------------------------------------------------------------
# record layer


def receiver_id_from_path(path: str | os.PathLike[str]) -> str:
    """Default receiver id of a capture: the file name without its extension(s)."""
    name = Path(path).name
    for ext in (".pcapng", ".pcap", ".cap", ".csv"):
        if name.lower().endswith(ext) and len(name) > len(ext):
            name = name[: -len(ext)]
    return name


def _ticks_to_ns(tsresol: int) -> tuple[int, int, int]:
    """(multiplier, divisor, shift) with ``ns = ((ticks * m) >> shift) // d``."""
    exp = tsresol & 0x7F
    if tsresol & 0x80:  # negative power of 2
        return 1_000_000_000, 1, exp
    if exp <= 9:
        return 10 ** (9 - exp), 1, 0
    return 1, 10 ** (exp - 9), 0


def _iter_pcap(fh: BinaryIO, path: str, head: bytes) -> Iterator[tuple[int, int, bytes, int]]:
    if len(head) < 24:
        raise InputError("truncated pcap file header", path=path)
    hdr = dpkt.pcap.FileHdr(head)
    magic = hdr.magic
    if magic in (dpkt.pcap.PMUDPCT_MAGIC, dpkt.pcap.PMUDPCT_MAGIC_NANO, dpkt.pcap.PACPDOM_MAGIC):
        hdr = dpkt.pcap.LEFileHdr(head)
    rec_cls = dpkt.pcap.MAGIC_TO_PKT_HDR[magic]
    nano = magic in (dpkt.pcap.TCPDUMP_MAGIC_NANO, dpkt.pcap.PMUDPCT_MAGIC_NANO)
    linktype = hdr.linktype & 0xFFFF  # upper bits: FCS length flags / reserved
    if linktype != LINKTYPE_IEEE802_11_RADIOTAP:
        what = _LINKTYPE_NAMES.get(linktype, "unsupported")
        raise InputError(
            f"link type {linktype} ({what}); radiopose needs 802.11 with radiotap "
            f"(link type {LINKTYPE_IEEE802_11_RADIOTAP}) for the signal strength",
            path=path,
        )
    rec = struct.Struct(rec_cls.__hdr_fmt__)
    size = rec.size
    frac_ns = 1 if nano else 1000
    read = fh.read
    offset = 24
    while True:
        h = read(size)
        if not h:
            return
        if len(h) < size:
            yield -1, -1, b"", -1  # truncated record marker
            return
        sec, frac, caplen, length = rec.unpack(h)[:4]
        if caplen > _MAX_RECORD_BYTES:
            raise InputError(
                f"corrupt pcap record at byte {offset}: captured length {caplen}", path=path
            )
        data = read(caplen)
        if len(data) < caplen:
            yield -1, -1, b"", -1
            return
        offset += size + caplen
        yield sec * 1_000_000_000 + frac * frac_ns, linktype, data, length


def _iter_pcapng(fh: BinaryIO, path: str, head: bytes) -> Iterator[tuple[int, int, bytes, int]]:
    read = fh.read
    offset = 0
    buf = head
    endian = "<"
    # per interface: (linktype, multiplier, divisor, shift, offset_ns)
    interfaces: list[tuple[int, int, int, int, int]] = []
    epb = struct.Struct("<IIIII")
    pb = struct.Struct("<HHIIII")
    while True:
        if len(buf) < 8:
            buf += read(8 - len(buf))
        if not buf:
            return
        if len(buf) < 8:
            yield -1, -1, b"", -1
            return
        btype_raw = buf[:4]
        if btype_raw == b"\x0a\x0d\x0d\x0a":  # section header: learn the byte order
            more = read(4)
            bom = more[:4]
            if bom == _PCAPNG_BOM_LE:
                endian = "<"
            elif bom == _PCAPNG_BOM_BE:
                endian = ">"
            elif len(more) < 4:
                yield -1, -1, b"", -1
                return
            else:
                raise InputError(
                    f"corrupt pcapng section header at byte {offset}: bad byte-order magic",
                    path=path,
                )
            buf += more
            epb = struct.Struct(endian + "IIIII")
            pb = struct.Struct(endian + "HHIIII")
            interfaces = []
        btype, blen = struct.unpack(endian + "II", buf[:8])
        if blen < 12 or blen % 4:
            raise InputError(f"corrupt pcapng block at byte {offset}: length {blen}", path=path)
        if blen > _MAX_RECORD_BYTES + 1024:  # also for a section header: it is read whole
            raise InputError(f"corrupt pcapng block at byte {offset}: length {blen}", path=path)
        rest = read(blen - len(buf))
        block = buf + rest
        if len(block) < blen:
            yield -1, -1, b"", -1
            return
        if block[-4:] != block[4:8]:
            raise InputError(
                f"corrupt pcapng block at byte {offset}: trailing length differs", path=path
            )
        if btype == _PCAPNG_SHB:
            try:
                shb = _PCAPNG_SHB_CLASS[endian](block)
            except (dpkt.UnpackError, struct.error, ValueError) as exc:
                raise InputError(
                    f"corrupt pcapng section header at byte {offset}: {exc}", path=path
                ) from None
            if shb.v_major != 1:
                raise InputError(f"unsupported pcapng version {shb.v_major}", path=path)
        elif btype == dpkt.pcapng.PCAPNG_BT_IDB:
            try:
                idb = _PCAPNG_IDB_CLASS[endian](block)
                tsresol, tsoffset = 6, 0
                for opt in idb.opts:
                    if opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL and len(opt.data) >= 1:
                        tsresol = opt.data[0]
                    elif opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET and len(opt.data) >= 8:
                        tsoffset = struct.unpack(endian + "q", opt.data[:8])[0]
            except (dpkt.UnpackError, struct.error, ValueError, IndexError) as exc:
                raise InputError(
                    f"corrupt pcapng interface block at byte {offset}: {exc}", path=path
                ) from None
            mul, div, shift = _ticks_to_ns(tsresol)
            interfaces.append((idb.linktype, mul, div, shift, tsoffset * 1_000_000_000))
        elif btype == dpkt.pcapng.PCAPNG_BT_EPB or btype == dpkt.pcapng.PCAPNG_BT_PB:
            if btype == dpkt.pcapng.PCAPNG_BT_EPB:
                if blen < 32:
                    raise InputError(f"corrupt pcapng packet block at byte {offset}", path=path)
                iface, hi, lo, caplen, length = epb.unpack_from(block, 8)
            else:
                if blen < 32:
                    raise InputError(f"corrupt pcapng packet block at byte {offset}", path=path)
                iface, _drops, hi, lo, caplen, length = pb.unpack_from(block, 8)
            if caplen > blen - 32:
                raise InputError(
                    f"corrupt pcapng packet block at byte {offset}: captured length {caplen}",
                    path=path,
                )
            if iface >= len(interfaces):
                raise InputError(
                    f"pcapng packet at byte {offset} refers to interface {iface}, "
                    f"only {len(interfaces)} declared",
                    path=path,
                )
            link, mul, div, shift, off_ns = interfaces[iface]
            ticks = (hi << 32) | lo
            ts_ns = (((ticks * mul) >> shift) // div) + off_ns
            if _NS_MIN <= ts_ns <= _NS_MAX or link != LINKTYPE_IEEE802_11_RADIOTAP:
                yield ts_ns, link, block[28 : 28 + caplen], length
            else:  # wrong_link_type comes first among the skip reasons
                yield -3, -3, b"", -3  # timestamp outside int64 ns marker
        elif btype == dpkt.pcapng.PCAPNG_BT_SPB:
            yield -2, -2, b"", -2  # no timestamp marker
        offset += blen
        buf = b""


def iter_raw_records(
    fh: BinaryIO, path: str | os.PathLike[str]
) -> Iterator[tuple[int, int, bytes, int]]:
    """Records of a pcap or pcapng stream: ``(timestamp_ns, linktype, data, orig_len)``.

    A record cut short by the end of the file is yielded once as
    ``(-1, -1, b"", -1)`` and ends the iteration; a pcapng simple packet block
    (no timestamp) as ``(-2, -2, b"", -2)``; a radiotap pcapng packet whose
    timestamp in nanoseconds does not fit in int64 as ``(-3, -3, b"", -3)``.

    Raises
    ------
    InputError
        Empty file, unknown format, truncated file header, corrupt block.
    """
    p = str(path)
    head = fh.read(8)
    if not head:
        raise InputError("empty file, expected a pcap or pcapng capture", path=p)
    if head[:4] == b"\x0a\x0d\x0d\x0a":
        return _iter_pcapng(fh, p, head)
    head += fh.read(16)
    magic_be = int.from_bytes(head[:4].ljust(4, b"\0"), "big")
    if magic_be in _PCAP_MAGICS:
        return _iter_pcap(fh, p, head)
    raise InputError(f"not a pcap or pcapng capture (starts with bytes {head[:4].hex()})", path=p)


# --------------------------------------------------------------------------
# frame decoding


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
    try:
        fh = open(p, "rb", buffering=1 << 20)  # noqa: SIM115
    except FileNotFoundError:
        raise InputError("file not found", path=p) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a capture file", path=p) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=p) from None
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


# --------------------------------------------------------------------------
# CSV capture form

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
    return Capture(frames, tuple(stats))


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
    except FileNotFoundError:
        raise InputError("file not found", path=p) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a capture file", path=p) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=p) from None
    if not head:
        raise InputError("empty file, expected a pcap, pcapng or CSV capture", path=p)
    if head == b"\x0a\x0d\x0d\x0a" or int.from_bytes(head.ljust(4, b"\0"), "big") in _PCAP_MAGICS:
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
