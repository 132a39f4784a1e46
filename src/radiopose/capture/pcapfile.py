"""pcap / pcapng record iteration: file -> ``(timestamp_ns, linktype, data, orig_len)``.

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

"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from typing import BinaryIO

import dpkt

from radiopose.errors import InputError

__all__ = [
    "LINKTYPE_IEEE802_11",
    "LINKTYPE_IEEE802_11_RADIOTAP",
    "is_pcap_start",
    "iter_raw_records",
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
        if frac * frac_ns >= 1_000_000_000:  # a fraction of a second that is not
            yield -3, -3, b"", -3  # the bad-timestamp marker: skipped and counted
            continue
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
    timestamp in nanoseconds does not fit in int64, or a pcap record whose
    sub-second field is a second or more, as ``(-3, -3, b"", -3)``.

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


def is_pcap_start(head: bytes) -> bool:
    """Whether the first four bytes of a file are a pcapng or pcap magic number."""
    return head[:4] == b"\x0a\x0d\x0d\x0a" or (
        int.from_bytes(head[:4].ljust(4, b"\0"), "big") in _PCAP_MAGICS
    )
