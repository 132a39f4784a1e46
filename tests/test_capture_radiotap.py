"""Radiotap decoder: tcpdump's decode of real captures, layouts, fuzzing."""

from __future__ import annotations

import contextlib
import re
import struct
from pathlib import Path

import dpkt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.capture.radiotap import (
    FIELD_ALIGN_SIZE,
    Radiotap,
    RadiotapError,
    decode_radiotap,
)
from radiopose.capture.writer import pack_radiotap, probe_request, radiotap_header

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"
needs_data = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"real captures not found at {DATA} (see shared/data/README.md)"
)


def _records(path: Path) -> list[bytes]:
    with open(path, "rb") as fh:
        return [buf for _ts, buf in dpkt.pcap.Reader(fh)]


# Older tcpdump prints the dBm antenna signal as "-22dB signal", newer as "-34dBm signal".
_SIGNAL = re.compile(r"(-?\d+)dBm? signal")


@needs_data
@pytest.mark.parametrize("name", ["tcpdump_ieee802.11_exthdr", "tcpdump_ieee802.11_meshid"])
def test_signal_equals_tcpdump_on_every_frame(name: str) -> None:
    records = _records(DATA / f"{name}.pcap")
    lines = (DATA / f"{name}.out").read_text().splitlines()
    assert len(records) == len(lines)
    with_signal = 0
    for k, (buf, line) in enumerate(zip(records, lines, strict=True)):
        m = _SIGNAL.search(line)
        got = decode_radiotap(buf).signal_dbm
        if m is None:
            assert got is None, f"frame {k + 1}: tcpdump shows no signal, we read {got}"
        else:
            with_signal += 1
            assert got == int(m.group(1)), f"frame {k + 1}: {line}"
    assert with_signal >= 3


@needs_data
def test_second_present_word_without_namespace_switch_stops_at_unknown_bits() -> None:
    # exthdr: word 0 has bit 31 but neither 29 nor 30, so word 1 holds bits 32-63
    # of the radiotap namespace; none is defined, so decoding stops there.
    rt = decode_radiotap(_records(DATA / "tcpdump_ieee802.11_exthdr.pcap")[0])
    assert rt.signal_dbm == -22
    assert rt.noise_dbm == -86
    assert rt.channel_mhz == 2412
    assert rt.tsft_us == 10016360
    assert rt.fcs_present is True
    assert not rt.complete


@needs_data
def test_per_antenna_signals_kept_and_combined_used() -> None:
    rts = [decode_radiotap(b) for b in _records(DATA / "tcpdump_ieee802.11_meshid.pcap")]
    assert [r.signal_dbm for r in rts] == [-34, -38, -34]
    assert [r.antenna_signals_dbm for r in rts] == [
        ((0, -39), (1, -34)),
        ((0, -38), (1, -44)),
        ((0, -40), (1, -34)),
    ]
    assert all(r.complete for r in rts)
    # the combined value is at least each antenna's
    assert all(r.signal_dbm >= max(v for _, v in r.antenna_signals_dbm) for r in rts)


def test_alignment_tsft_after_padding() -> None:
    # Two present words end at byte 12; the 8-byte TSFT must start at 16, not 12.
    hdr = pack_radiotap(
        [{0: struct.pack("<Q", 123456789), 1: b"\x10", 5: b"\xc4"}, {5: b"\xc0", 11: b"\x01"}]
    )
    assert struct.unpack_from("<Q", hdr, 16)[0] == 123456789
    assert len(hdr) == 16 + 8 + 1 + 1 + 1 + 1
    rt = decode_radiotap(hdr + b"\x40\x00")
    assert rt.tsft_us == 123456789
    assert rt.signal_dbm == -60
    assert rt.antenna_signals_dbm == ((1, -64),)
    assert rt.flags == 0x10


def test_alignment_channel_after_rate() -> None:
    hdr = pack_radiotap([{2: b"\x02", 3: struct.pack("<HH", 5180, 0x140), 5: b"\xb0"}])
    rt = decode_radiotap(hdr)
    assert rt.channel_mhz == 5180
    assert rt.signal_dbm == -80


def test_vendor_namespace_is_skipped() -> None:
    hdr = pack_radiotap(
        [
            {1: b"\x00", 5: struct.pack("<b", -51)},
            (b"\x00\x11\x22", 3, b"\xaa" * 13, 0x7),
            {5: struct.pack("<b", -55), 11: b"\x01"},
        ]
    )
    rt = decode_radiotap(hdr)
    assert rt.signal_dbm == -51
    assert rt.antenna_signals_dbm == ((1, -55),)
    assert rt.complete


def test_without_combined_signal_the_strongest_antenna_is_used() -> None:
    hdr = pack_radiotap([{1: b"\x00"}, {5: b"\xc0", 11: b"\x00"}, {5: b"\xc8", 11: b"\x01"}])
    rt = decode_radiotap(hdr)
    assert rt.signal_dbm == -56
    assert rt.antenna_signals_dbm == ((0, -64), (1, -56))


def test_db_signal_is_not_dbm() -> None:
    hdr = pack_radiotap([{12: b"\x28", 13: b"\x05"}])
    assert decode_radiotap(hdr).signal_dbm is None


def test_tlv_bit_ends_fixed_fields() -> None:
    word = (1 << 5) | (1 << 28)
    hdr = struct.pack("<BBHI", 0, 0, 16, word) + b"\xc4" + b"\0" * 7
    rt = decode_radiotap(hdr)
    assert rt.signal_dbm == -60


def test_flags_properties() -> None:
    rt = decode_radiotap(pack_radiotap([{1: bytes([0x10 | 0x40 | 0x20]), 5: b"\xc4"}]))
    assert rt.fcs_present and rt.bad_fcs and rt.data_pad
    rt = decode_radiotap(pack_radiotap([{5: b"\xc4", 14: struct.pack("<H", 2)}]))
    assert rt.bad_fcs and rt.fcs_present is None


@pytest.mark.parametrize(
    ("buf", "message"),
    [
        (b"\x00\x00\x08", "shorter than a radiotap header"),
        (b"\x01\x00\x08\x00\x00\x00\x00\x00", "version"),
        (b"\x00\x00\x04\x00\x00\x00\x00\x00", "shorter than 8"),
        (b"\x00\x00\x40\x00\x00\x00\x00\x00", "exceeds the record"),
        (b"\x00\x00\x08\x00\x00\x00\x00\x80", "bitmaps run past"),
        (b"\x00\x00\x08\x00\x01\x00\x00\x00", "runs past the header"),
    ],
)
def test_malformed_headers_raise(buf: bytes, message: str) -> None:
    with pytest.raises(RadiotapError, match=message):
        decode_radiotap(buf)


def test_writer_header_round_trip() -> None:
    hdr = radiotap_header(-61, fcs=True, tsft_us=99, antenna_signals_dbm=(-63, -66))
    rt = decode_radiotap(hdr)
    assert rt == Radiotap(
        length=len(hdr),
        signal_dbm=-61,
        antenna_signals_dbm=((0, -63), (1, -66)),
        flags=0x10,
        channel_mhz=2437,
        tsft_us=99,
    )
    # dpkt, an independent decoder, reads the same header and a real probe request
    frame = probe_request("02:00:00:00:00:01", 5, b"x")
    dp = dpkt.radiotap.Radiotap(radiotap_header(-61, tsft_us=99) + frame)
    assert dp.ant_sig.db == -61
    assert dp.channel.freq == 2437
    assert dp.data.subtype == dpkt.ieee80211.M_PROBE_REQ
    assert dp.data.mgmt.src == bytes.fromhex("020000000001")


# --------------------------------------------------------------------------
# property tests

_KNOWN_BITS = sorted(FIELD_ALIGN_SIZE)


@st.composite
def _namespace(draw: st.DrawFn) -> dict[int, bytes]:
    bits = draw(st.sets(st.sampled_from(_KNOWN_BITS), max_size=10))
    return {
        b: draw(st.binary(min_size=FIELD_ALIGN_SIZE[b][1], max_size=FIELD_ALIGN_SIZE[b][1]))
        for b in bits
    }


@st.composite
def _layouts(draw: st.DrawFn) -> list:
    spaces: list = [draw(_namespace())]
    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            spaces.append(
                (
                    draw(st.binary(min_size=3, max_size=3)),
                    draw(st.integers(0, 255)),
                    draw(st.binary(max_size=20)),
                    draw(st.integers(0, 2**29 - 1)),
                )
            )
        spaces.append(draw(_namespace()))
    return spaces


def _s8(b: bytes) -> int:
    return struct.unpack("<b", b)[0]


@settings(max_examples=200, deadline=None)
@given(_layouts(), st.binary(max_size=30))
def test_decoder_recovers_packed_fields(spaces: list, payload: bytes) -> None:
    rt = decode_radiotap(pack_radiotap(spaces) + payload)
    first = spaces[0]
    antennas = []
    for ns in spaces[1:]:
        if isinstance(ns, dict) and 5 in ns:
            antennas.append((ns[11][0] if 11 in ns else -1, _s8(ns[5])))
    expected_signal = (
        _s8(first[5]) if 5 in first else (max(v for _, v in antennas) if antennas else None)
    )
    assert rt.signal_dbm == expected_signal
    assert rt.antenna_signals_dbm == tuple(antennas)
    assert rt.flags == (first[1][0] if 1 in first else None)
    assert rt.complete


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=120))
def test_decoder_never_crashes_on_garbage(buf: bytes) -> None:
    try:
        rt = decode_radiotap(buf)
    except RadiotapError:
        return
    assert 8 <= rt.length <= len(buf)
    assert rt.signal_dbm is None or -128 <= rt.signal_dbm <= 127


@settings(max_examples=200, deadline=None)
@given(_layouts(), st.data())
def test_decoder_never_crashes_on_corrupted_headers(spaces: list, data: st.DataObject) -> None:
    buf = bytearray(pack_radiotap(spaces))
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(buf) - 1))
        buf[pos] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(buf)))
    with contextlib.suppress(RadiotapError):
        decode_radiotap(bytes(buf[:cut]) if data.draw(st.booleans()) else bytes(buf))
