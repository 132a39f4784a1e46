"""Radiotap header decoder: bytes in, signal strength and frame flags out.

A radiotap header (https://www.radiotap.org) precedes every 802.11 frame a
monitor-mode interface captures (link type 127). It starts with
``it_version`` (u8, always 0), ``it_pad`` (u8), ``it_len`` (u16 LE, the whole
header length) and one or more 32-bit little-endian *present* bitmaps: bit 31
of a bitmap says another bitmap follows. The fields named by the set bits
follow the bitmaps in bit order, each aligned to its natural alignment
*relative to the start of the header*.

Namespaces (bits 29-31 of every bitmap):

* bit 29 — the next bitmap starts the radiotap namespace again (bit numbering
  restarts at 0). Linux uses this for per-antenna fields: the first namespace
  carries the combined signal, each following one an ``antenna`` index and that
  antenna's signal.
* bit 30 — the next bitmap belongs to a vendor namespace. Its field (align 2,
  6 bytes: OUI, sub-namespace, ``skip_length`` u16) sits in the data; the
  vendor's ``skip_length`` bytes that follow are skipped unread.
* bit 31 alone — the next bitmap continues the *same* namespace with bits
  32-63 (no namespace switch).

A bit in the radiotap namespace that this decoder does not know (including
every bit >= 32, none of which is defined) has an unknown size, so decoding
stops there, exactly as the Linux and tcpdump parsers do; the fields before it
are kept and :attr:`Radiotap.complete` is false.

Which signal is used
--------------------
:attr:`Radiotap.signal_dbm` is the *combined* dBm antenna signal (bit 5) of the
first radiotap namespace when present. Otherwise it is the strongest of the
per-antenna values. All per-antenna values (bit 5 in later radiotap
namespaces, paired with the bit-11 antenna index of the same namespace) are
kept in :attr:`Radiotap.antenna_signals_dbm`. The dB (not dBm) signal of bit 12
is relative to an arbitrary reference and is never used as RSS.

FCS
---
Flags (bit 1) ``0x10`` means the frame ends with its 4-byte FCS; ``0x40``
flags a frame that failed the FCS check; ``0x20`` means padding was inserted
between the 802.11 header and the payload. RX flags (bit 14) ``0x0002`` flags
a bad PLCP CRC, which is treated like a bad FCS.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

__all__ = [
    "FIELD_ALIGN_SIZE",
    "Radiotap",
    "RadiotapError",
    "decode_radiotap",
    "fast_decode",
]

# bit -> (alignment, size) in bytes of every field defined in the radiotap
# namespace (radiotap.org "defined fields"; Linux net/wireless/radiotap.c).
FIELD_ALIGN_SIZE: dict[int, tuple[int, int]] = {
    0: (8, 8),  # TSFT, u64 microseconds
    1: (1, 1),  # Flags
    2: (1, 1),  # Rate, 500 kb/s
    3: (2, 4),  # Channel: u16 MHz, u16 flags
    4: (2, 2),  # FHSS
    5: (1, 1),  # dBm antenna signal, s8
    6: (1, 1),  # dBm antenna noise, s8
    7: (2, 2),  # Lock quality
    8: (2, 2),  # TX attenuation
    9: (2, 2),  # dB TX attenuation
    10: (1, 1),  # dBm TX power
    11: (1, 1),  # Antenna index
    12: (1, 1),  # dB antenna signal (arbitrary reference)
    13: (1, 1),  # dB antenna noise
    14: (2, 2),  # RX flags
    15: (2, 2),  # TX flags
    16: (1, 1),  # RTS retries
    17: (1, 1),  # data retries
    18: (4, 8),  # XChannel
    19: (1, 3),  # MCS
    20: (4, 8),  # A-MPDU status
    21: (2, 12),  # VHT
    22: (8, 12),  # timestamp
    23: (2, 12),  # HE
    24: (2, 12),  # HE-MU
    25: (2, 6),  # HE-MU-other-user
    26: (1, 1),  # 0-length-PSDU
    27: (2, 4),  # L-SIG
}
_TLV_BIT = 28  # TLV list to the end of the header: nothing fixed follows
_RADIOTAP_NS_BIT = 29
_VENDOR_NS_BIT = 30
_EXT_BIT = 31

FLAG_FCS_AT_END = 0x10
FLAG_DATA_PAD = 0x20
FLAG_BAD_FCS = 0x40
RX_FLAG_BAD_PLCP = 0x0002

# Fields the decoder extracts; the others are only stepped over.
_WANTED = frozenset((0, 1, 3, 5, 6, 11, 14))

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")


class RadiotapError(ValueError):
    """A malformed radiotap header (bad version, lengths past the end...)."""


@dataclass(frozen=True, slots=True)
class Radiotap:
    """What radiopose needs from one radiotap header.

    Attributes
    ----------
    length
        ``it_len``: header length in bytes; the 802.11 frame starts here.
    signal_dbm
        RSS used by radiopose in dBm (see the module docstring), or ``None``.
    antenna_signals_dbm
        ``(antenna, dBm)`` for each per-antenna signal (radiotap namespaces
        after the first); antenna is ``-1`` when its namespace has no index.
    noise_dbm
        dBm antenna noise of the first namespace, or ``None``.
    flags
        The Flags field, or ``None`` when absent.
    channel_mhz
        Channel centre frequency in MHz, or ``None``.
    tsft_us
        The MAC timestamp (TSFT) in microseconds, or ``None``.
    complete
        False if decoding stopped at a field of unknown size.
    bad_plcp
        RX flags report a bad PLCP CRC.
    """

    length: int
    signal_dbm: int | None
    antenna_signals_dbm: tuple[tuple[int, int], ...] = ()
    noise_dbm: int | None = None
    flags: int | None = None
    channel_mhz: int | None = None
    tsft_us: int | None = None
    complete: bool = True
    bad_plcp: bool = False

    @property
    def fcs_present(self) -> bool | None:
        """True/False from the Flags field; ``None`` if the header has no Flags."""
        return None if self.flags is None else bool(self.flags & FLAG_FCS_AT_END)

    @property
    def bad_fcs(self) -> bool:
        """The capturing driver flagged the frame as failing its FCS / PLCP CRC."""
        return bool(self.flags is not None and self.flags & FLAG_BAD_FCS) or self.bad_plcp

    @property
    def data_pad(self) -> bool:
        """Padding sits between the 802.11 header and the payload (Flags 0x20)."""
        return bool(self.flags is not None and self.flags & FLAG_DATA_PAD)


# A layout: the offsets of the wanted fields, as ((bit, namespace index, offset), ...),
# plus whether decoding walked the whole header. It depends only on the present
# bitmaps unless a vendor namespace (whose skip_length lives in the data) occurs.
_Layout = tuple[tuple[tuple[int, int, int], ...], bool]
_LAYOUT_CACHE: dict[bytes, _Layout] = {}
_LAYOUT_CACHE_MAX = 4096


def _read_bitmaps(buf: bytes, length: int) -> list[int]:
    words = []
    pos = 4
    while True:
        if pos + 4 > length:
            raise RadiotapError("present bitmaps run past the header length")
        word = _U32.unpack_from(buf, pos)[0]
        words.append(word)
        pos += 4
        if not word & (1 << _EXT_BIT):
            return words


def _walk(buf: bytes, length: int, words: list[int]) -> tuple[_Layout, bool]:
    """Walk the fields; return the layout and whether it used vendor data."""
    pos = 4 + 4 * len(words)
    out: list[tuple[int, int, int]] = []
    ns_index = 0  # count of radiotap namespaces seen (0 = first)
    in_radiotap = True
    base = 0  # bit number of bit 0 of the current word (0, 32, ... within a namespace)
    used_vendor = False
    complete = True
    stopped = False
    for word in words:
        for bit in range(29):
            if not word & (1 << bit):
                continue
            if not in_radiotap:
                continue  # vendor fields: skipped as a block via skip_length
            if stopped:
                break
            field = base + bit
            if field == _TLV_BIT:
                stopped = True  # TLVs to the end of the header, nothing fixed after
                break
            spec = FIELD_ALIGN_SIZE.get(field)
            if spec is None:
                # Unknown size: nothing after this can be located.
                complete = False
                stopped = True
                break
            align, size = spec
            pos += -pos % align
            if pos + size > length:
                raise RadiotapError(f"field {field} runs past the header length")
            if field in _WANTED:
                out.append((field, ns_index, pos))
            pos += size
        if stopped:
            break
        if word & (1 << _VENDOR_NS_BIT):
            # The vendor namespace field itself: OUI[3], sub_ns, skip_length.
            pos += -pos % 2
            if pos + 6 > length:
                raise RadiotapError("vendor namespace field runs past the header length")
            skip = _U16.unpack_from(buf, pos + 4)[0]
            pos += 6 + skip
            if pos > length:
                raise RadiotapError("vendor namespace data runs past the header length")
            used_vendor = True
            in_radiotap = False
            base = 0
        elif word & (1 << _RADIOTAP_NS_BIT):
            in_radiotap = True
            ns_index += 1
            base = 0
        else:
            base += 32  # same namespace continues with bits 32-63
    return (tuple(out), complete), used_vendor


def _layout_for(buf: bytes, length: int) -> _Layout:
    words = _read_bitmaps(buf, length)
    key = buf[2 : 4 + 4 * len(words)]  # it_len + bitmaps
    cached = _LAYOUT_CACHE.get(key)
    if cached is not None:
        return cached
    layout, used_vendor = _walk(buf, length, words)
    if not used_vendor and len(_LAYOUT_CACHE) < _LAYOUT_CACHE_MAX:
        _LAYOUT_CACHE[key] = layout
    return layout


def _s8(b: int) -> int:
    return b - 256 if b > 127 else b


FastRadiotap = tuple[int, int | None, tuple[tuple[int, int], ...], int | None, bool]


def fast_decode(buf: bytes) -> FastRadiotap:
    """Hot-path twin of :func:`decode_radiotap`.

    Returns
    -------
    tuple
        ``(length, signal_dbm, antenna_signals_dbm, flags, bad_plcp)`` with the
        meanings of the :class:`Radiotap` attributes of the same names.
    """
    f = _extract(buf)
    return f[0], f[1], f[2], f[4], f[8]


def decode_radiotap(buf: bytes) -> Radiotap:
    """Decode the radiotap header at the start of ``buf``.

    Parameters
    ----------
    buf
        A captured record of link type 127: radiotap header then 802.11 frame.

    Returns
    -------
    Radiotap
        Signal (dBm), per-antenna signals, flags, channel and header length.

    Raises
    ------
    RadiotapError
        Version not 0, ``it_len`` shorter than 8 or longer than ``buf``, or a
        bitmap/field that runs past ``it_len``.
    """
    length, signal, antennas, noise, flags, channel, tsft, complete, bad_plcp = _extract(buf)
    return Radiotap(
        length=length,
        signal_dbm=signal,
        antenna_signals_dbm=antennas,
        noise_dbm=noise,
        flags=flags,
        channel_mhz=channel,
        tsft_us=tsft,
        complete=complete,
        bad_plcp=bad_plcp,
    )


def _extract(buf: bytes) -> tuple:
    n = len(buf)
    if n < 8:
        raise RadiotapError(f"record of {n} bytes is shorter than a radiotap header")
    if buf[0] != 0:
        raise RadiotapError(f"unsupported radiotap version {buf[0]}")
    length = _U16.unpack_from(buf, 2)[0]
    if length < 8:
        raise RadiotapError(f"radiotap length {length} is shorter than 8")
    if length > n:
        raise RadiotapError(f"radiotap length {length} exceeds the record ({n} bytes)")
    fields, complete = _layout_for(buf, length)

    signal = noise = flags = channel = tsft = None
    bad_plcp = False
    per_ns: dict[int, list[int | None]] = {}  # ns index -> [antenna, dBm]
    for field, ns, pos in fields:
        if field == 5:
            if ns == 0:
                signal = _s8(buf[pos])
            else:
                per_ns.setdefault(ns, [None, None])[1] = _s8(buf[pos])
        elif field == 11:
            if ns > 0:
                per_ns.setdefault(ns, [None, None])[0] = buf[pos]
        elif ns:
            continue
        elif field == 1:
            flags = buf[pos]
        elif field == 6:
            noise = _s8(buf[pos])
        elif field == 3:
            channel = _U16.unpack_from(buf, pos)[0]
        elif field == 14:
            bad_plcp = bool(_U16.unpack_from(buf, pos)[0] & RX_FLAG_BAD_PLCP)
        else:  # field 0
            tsft = _U64.unpack_from(buf, pos)[0]
    antennas: tuple[tuple[int, int], ...] = ()
    if per_ns:
        antennas = tuple(
            (-1 if ant is None else ant, dbm) for ant, dbm in per_ns.values() if dbm is not None
        )
        if signal is None and antennas:
            signal = max(dbm for _, dbm in antennas)
    return length, signal, antennas, noise, flags, channel, tsft, complete, bad_plcp
