"""Capture reading: pcap/pcapng record layer, hashed bytes, skips, CSV form, bad input."""

from __future__ import annotations

import hashlib
import struct
import zlib
from fractions import Fraction
from pathlib import Path

import dpkt
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.capture.records import (
    PLAUSIBLE_RSS_DBM,
    SKIP_REASONS,
    canonical_transmitter,
    read_capture,
    read_capture_csv,
    read_pcap,
    receiver_id_from_path,
    transmitter_id_problem,
)
from radiopose.capture.writer import probe_request, radiotap_header, write_receiver_pcaps
from radiopose.errors import InputError

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"
needs_data = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"real captures not found at {DATA} (see shared/data/README.md)"
)
ESP32 = [
    DATA / f"probe-request-project_sc6-61_position_{k}_2024-03-17_anonymized.pcap" for k in (1, 2)
]
TX = "02:00:00:00:00:07"
# the hypothesis settings of this module's fuzz and property tests (fixed: no profile)
FUZZ = settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _pcap(path: Path, records: list[tuple[float, bytes]], *, nano: bool = True) -> Path:
    with open(path, "wb") as fh:
        w = dpkt.pcap.Writer(fh, snaplen=65535, linktype=127, nano=nano)
        for ts, buf in records:
            w.writepkt_time(buf, ts)
    return path


def _fcs(frame: bytes) -> bytes:
    return frame + struct.pack("<I", zlib.crc32(frame))


# --------------------------------------------------------------------------
# real captures


@needs_data
def test_esp32_captures_read_completely() -> None:
    for path, n in zip(ESP32, (2506, 4264), strict=True):
        cap = read_pcap(path, "rx")
        (s,) = cap.stats
        assert (s.frames_read, s.frames_kept, s.skipped) == (n, n, {})
        f = cap.frames
        assert len(f) == n
        assert np.all((f.rss_dbm >= -100) & (f.rss_dbm <= -20))
        assert all(len(h) == 64 for h in f.frame_sha256)
        assert all(len(t) == 17 and t.count(":") == 5 for t in f.transmitter)
        assert f.timestamp_ns.dtype == np.int64
    a, b = (set(read_pcap(p).frames.frame_sha256) for p in ESP32)
    assert len(a & b) == 154  # byte-identical frames in both captures (README)


@needs_data
def test_first_esp32_frame_values() -> None:
    f = read_pcap(ESP32[0]).frames
    assert int(f.timestamp_ns[0]) == 1710630082_592539000  # microsecond pcap, exact
    assert f.rss_dbm[0] == -89.0
    with open(ESP32[0], "rb") as fh:
        _ts, buf = next(iter(dpkt.pcap.Reader(fh)))
    assert f.frame_sha256[0] == hashlib.sha256(buf[14:]).hexdigest()  # no FCS kept
    assert f.transmitter[0] == buf[14 + 10 : 14 + 16].hex(":")


@needs_data
def test_tcpdump_capture_skips_are_counted() -> None:
    cap = read_pcap(DATA / "tcpdump_ieee802.11_exthdr.pcap")
    (s,) = cap.stats
    assert s.receiver_id == "tcpdump_ieee802.11_exthdr"
    assert s.frames_read == 26
    assert s.skipped == {"no_signal": 8, "no_transmitter": 8}  # TX reports, ACKs
    assert s.frames_kept == 10
    assert list(cap.frames.rss_dbm[:3]) == [-22.0, -19.0, -61.0]


# --------------------------------------------------------------------------
# hashed bytes


def test_fcs_is_excluded_from_the_hash_whatever_the_driver(tmp_path: Path) -> None:
    frame = probe_request(TX, 1, b"a")
    with_flags = radiotap_header(-50, fcs=True) + _fcs(frame)
    without = radiotap_header(-50, fcs=False) + frame
    # no Flags field at all, FCS present: recognised by its CRC
    bare = b"\x00\x00\x09\x00\x20\x00\x00\x00\xce" + _fcs(frame)
    bare_no_fcs = b"\x00\x00\x09\x00\x20\x00\x00\x00\xce" + frame
    p = _pcap(
        tmp_path / "a.pcap", [(1.0, with_flags), (2.0, without), (3.0, bare), (4.0, bare_no_fcs)]
    )
    f = read_pcap(p).frames
    assert len(f) == 4
    assert set(f.frame_sha256) == {hashlib.sha256(frame).hexdigest()}


def test_data_padding_is_removed(tmp_path: Path) -> None:
    # QoS data frame: 26-byte header, padded to 28 by the driver (Flags 0x20).
    hdr = b"\x88\x01\x00\x00" + bytes.fromhex("0a0b0c0d0e0f") + bytes.fromhex(TX.replace(":", ""))
    hdr += b"\xff" * 6 + b"\x10\x00" + b"\x00\x00"
    body = b"\xaa\xaa\x03\x00\x00\x00\x08\x00payload"
    plain = hdr + body
    padded = hdr + b"\x00\x00" + body
    rt_pad = b"\x00\x00\x0a\x00\x22\x00\x00\x00\x20\xc4"  # flags 0x20, signal -60
    rt_plain = b"\x00\x00\x0a\x00\x22\x00\x00\x00\x00\xc4"
    p = _pcap(tmp_path / "d.pcap", [(1.0, rt_pad + padded), (2.0, rt_plain + plain)])
    f = read_pcap(p).frames
    assert list(f.frame_sha256) == [hashlib.sha256(plain).hexdigest()] * 2
    assert list(f.transmitter) == [TX, TX]


def test_skip_reasons(tmp_path: Path) -> None:
    frame = probe_request(TX, 1, b"a")
    ack = b"\xd4\x00\x00\x00" + b"\x01" * 6
    flags_bad = b"\x00\x00\x0a\x00\x22\x00\x00\x00\x50\xc4"  # FCS present + bad FCS
    records = [
        (1.0, radiotap_header(-50) + frame),  # kept
        (2.0, flags_bad + _fcs(frame)),  # bad_fcs
        (3.0, radiotap_header(-50, fcs=True) + frame + b"\0\0\0\0"),  # fcs_mismatch
        (4.0, b"\x00\x00\x08\x00\x00\x00\x00\x00" + frame),  # no_signal
        (5.0, radiotap_header(5) + frame),  # implausible (> 0 dBm)
        (6.0, radiotap_header(-127) + frame),  # implausible (< -120 dBm)
        (7.0, radiotap_header(-50) + ack),  # no_transmitter
        (8.0, radiotap_header(-50) + frame[:12]),  # short_frame
        (9.0, b"\x00\x00\x40\x00" + frame),  # bad_radiotap
        (10.0, radiotap_header(-50) + b"\x4b" + frame[1:]),  # protocol version 3
    ]
    p = _pcap(tmp_path / "s.pcap", records)
    (s,) = read_pcap(p).stats
    assert s.frames_read == 10
    assert s.frames_kept == 1
    assert s.skipped == {
        "bad_radiotap": 1,
        "bad_fcs": 1,
        "fcs_mismatch": 1,
        "no_signal": 1,
        "implausible_rss": 2,
        "short_frame": 1,
        "unsupported_frame": 1,
        "no_transmitter": 1,
    }
    assert list(s.skipped) == [r for r in SKIP_REASONS if r in s.skipped]
    assert PLAUSIBLE_RSS_DBM == (-120.0, 0.0)


def test_snapped_frames_are_skipped(tmp_path: Path) -> None:
    buf = radiotap_header(-40) + probe_request(TX, 1, b"abc")
    path = tmp_path / "snap.pcap"
    with open(path, "wb") as fh:
        fh.write(bytes(dpkt.pcap.LEFileHdr(snaplen=40, linktype=127)))
        fh.write(struct.pack("<IIII", 1, 0, 40, len(buf)) + buf[:40])
    (s,) = read_pcap(path).stats
    assert s.skipped == {"snapped": 1}


# --------------------------------------------------------------------------
# record layer: timestamps, pcapng


def test_microsecond_and_nanosecond_pcap_timestamps(tmp_path: Path) -> None:
    buf = radiotap_header(-40) + probe_request(TX, 1, b"t")
    from decimal import Decimal

    p_ns = tmp_path / "ns.pcap"
    with open(p_ns, "wb") as fh:
        w = dpkt.pcap.Writer(fh, linktype=127, nano=True)
        w.writepkt_time(buf, Decimal("1700000000.123456789"))
    p_us = _pcap(tmp_path / "us.pcap", [(1700000000.123456, buf)], nano=False)
    assert int(read_pcap(p_ns).frames.timestamp_ns[0]) == 1700000000_123456789
    assert int(read_pcap(p_us).frames.timestamp_ns[0]) == 1700000000_123456000
    # big-endian nanosecond pcap, written by hand
    p_be = tmp_path / "be.pcap"
    p_be.write_bytes(
        struct.pack(">IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 65535, 127)
        + struct.pack(">IIII", 1700000000, 999_999_999, len(buf), len(buf))
        + buf
    )
    f = read_pcap(p_be).frames
    assert int(f.timestamp_ns[0]) == 1700000000_999999999
    assert f.rss_dbm[0] == -40.0


def test_a_pcap_record_with_a_sub_second_field_of_a_second_or_more_is_skipped(
    tmp_path: Path,
) -> None:
    """Counted as ``bad_timestamp`` (it would read as a time a second or more
    later, a frame that no other receiver heard then); the records around it are kept."""
    buf = radiotap_header(-40) + probe_request(TX, 1, b"t")
    for magic, frac_ok, frac_bad in (
        (0xA1B23C4D, 999_999_999, 2_000_000_000),  # nanoseconds
        (0xA1B2C3D4, 999_999, 1_000_000),  # microseconds
    ):
        path = tmp_path / f"frac{magic:x}.pcap"
        rec = [struct.pack("<IIII", 1700000000 + k, frac, len(buf), len(buf)) + buf
               for k, frac in enumerate((frac_ok, frac_bad, 0))]  # fmt: skip
        path.write_bytes(struct.pack("<IHHiIII", magic, 2, 4, 0, 0, 65535, 127) + b"".join(rec))
        cap = read_pcap(path)
        assert cap.stats[0].skipped == {"bad_timestamp": 1}
        assert cap.stats[0].frames_kept == 2


def _idb(cls: type, linktype: int, tsresol: int | None = None, tsoffset: int | None = None):
    opts = []
    opt_cls = dpkt.pcapng.PcapngOptionLE if cls.__hdr_fmt__[0] == "<" else dpkt.pcapng.PcapngOption
    fmt = cls.__hdr_fmt__[0]
    if tsresol is not None:
        opts.append(opt_cls(code=dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL, data=bytes([tsresol])))
    if tsoffset is not None:
        opts.append(
            opt_cls(code=dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET, data=struct.pack(fmt + "q", tsoffset))
        )
    opts.append(opt_cls(code=dpkt.pcapng.PCAPNG_OPT_ENDOFOPT))
    return cls(linktype=linktype, snaplen=65535, opts=opts)


def _epb(cls: type, iface: int, ticks: int, data: bytes) -> bytes:
    return bytes(
        cls(
            iface_id=iface,
            ts_high=ticks >> 32,
            ts_low=ticks & 0xFFFFFFFF,
            caplen=len(data),
            pkt_len=len(data),
            pkt_data=data,
        )
    )


def test_pcapng_interfaces_resolutions_and_sections(tmp_path: Path) -> None:
    ng = dpkt.pcapng
    frames = [radiotap_header(-40 - k) + probe_request(TX, k, b"n") for k in range(6)]
    le = bytes(ng.SectionHeaderBlockLE())
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=9))  # ns
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127))  # default µs
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 105))  # 802.11 without radiotap
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=0x80 | 20, tsoffset=100))
    le += _epb(ng.EnhancedPacketBlockLE, 0, 1700000000_123456789, frames[0])
    le += _epb(ng.EnhancedPacketBlockLE, 1, 1700000000_123456, frames[1])
    le += _epb(ng.EnhancedPacketBlockLE, 2, 5, frames[2])
    le += _epb(ng.EnhancedPacketBlockLE, 3, 3 * 2**20 + 2**19, frames[3])  # 3.5 s + 100 s
    # a second section, big-endian, redefines interface 0 as microseconds
    be = bytes(ng.SectionHeaderBlock())
    be += bytes(_idb(ng.InterfaceDescriptionBlock, 127, tsresol=3))  # ms
    be += _epb(ng.EnhancedPacketBlock, 0, 42, frames[4])
    spb = struct.pack(">III", 3, 16 + 4, len(frames[5][:4])) + frames[5][:4] + struct.pack(">I", 20)
    path = tmp_path / "multi.pcapng"
    path.write_bytes(le + be + spb)
    cap = read_capture(path)
    (s,) = cap.stats
    assert s.receiver_id == "multi"
    assert s.frames_read == 6
    assert s.skipped == {"wrong_link_type": 1, "no_timestamp": 1}
    assert list(cap.frames.timestamp_ns) == [
        1700000000_123456789,
        1700000000_123456000,
        103_500_000_000,
        42_000_000,
    ]
    assert list(cap.frames.rss_dbm) == [-40.0, -41.0, -43.0, -44.0]


def _one_interface_pcapng(
    path: Path, tsresol: int | None, tsoffset: int | None, ticks: list[int]
) -> Path:
    ng = dpkt.pcapng
    blob = bytes(ng.SectionHeaderBlockLE())
    blob += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=tsresol, tsoffset=tsoffset))
    for k, t in enumerate(ticks):
        blob += _epb(
            ng.EnhancedPacketBlockLE, 0, t, radiotap_header(-40) + probe_request(TX, k, b"")
        )
    path.write_bytes(blob)
    return path


def test_pcapng_timestamps_outside_int64_are_counted(tmp_path: Path) -> None:
    i64 = 2**63 - 1
    cases = [
        # (if_tsresol, if_tsoffset, ticks) -> kept timestamps; the others are bad_timestamp
        (0, None, [10**11, 5], [5_000_000_000]),  # 1e11 s is beyond year 2262
        (9, 2**62, [1], []),  # offset of 2^62 s
        (9, -(2**62), [0], []),  # before 1677
        (9, None, [i64, i64 + 1, 2**64 - 1], [i64]),  # ns ticks: the int64 edge is exact
        (9, -1, [0], [-1_000_000_000]),  # a negative time that fits is kept
    ]
    for k, (tsresol, tsoffset, ticks, kept) in enumerate(cases):
        path = _one_interface_pcapng(tmp_path / f"t{k}.pcapng", tsresol, tsoffset, ticks)
        cap = read_pcap(path)
        (s,) = cap.stats
        assert (s.frames_read, s.frames_kept) == (len(ticks), len(kept))
        bad = len(ticks) - len(kept)
        assert s.skipped == ({"bad_timestamp": bad} if bad else {})
        assert cap.frames.timestamp_ns.dtype == np.int64
        assert [int(t) for t in cap.frames.timestamp_ns] == kept
    assert SKIP_REASONS.index("bad_timestamp") < SKIP_REASONS.index("truncated_record")
    # a packet of a non-radiotap interface is counted under its first reason
    ng = dpkt.pcapng
    blob = bytes(ng.SectionHeaderBlockLE())
    blob += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127))
    blob += bytes(_idb(ng.InterfaceDescriptionBlockLE, 105, tsresol=0))
    blob += _epb(ng.EnhancedPacketBlockLE, 1, 10**11, probe_request(TX, 1, b""))
    blob += _epb(ng.EnhancedPacketBlockLE, 0, 1, radiotap_header(-40) + probe_request(TX, 2, b""))
    path = tmp_path / "mixed.pcapng"
    path.write_bytes(blob)
    (s,) = read_pcap(path).stats
    assert (s.frames_kept, s.skipped) == (1, {"wrong_link_type": 1})


@FUZZ
@given(
    tsresol=st.one_of(st.none(), st.integers(0, 30), st.integers(0x80, 0x80 | 70)),
    tsoffset=st.one_of(st.none(), st.integers(-(2**63), 2**63 - 1)),
    ticks=st.integers(0, 2**64 - 1),
)
def test_pcapng_timestamps_are_exact(
    tmp_path: Path, tsresol: int | None, tsoffset: int | None, ticks: int
) -> None:
    """ns = floor(ticks / ticks-per-second · 10^9) + if_tsoffset · 10^9, or a counted skip."""
    r = 6 if tsresol is None else tsresol
    per_second = (2 if r & 0x80 else 10) ** (r & 0x7F)
    expected = int(Fraction(ticks * 10**9, per_second) // 1) + (tsoffset or 0) * 10**9
    path = _one_interface_pcapng(tmp_path / "exact.pcapng", tsresol, tsoffset, [ticks])
    cap = read_pcap(path)
    if -(2**63) <= expected < 2**63:
        assert [int(t) for t in cap.frames.timestamp_ns] == [expected]
    else:
        assert cap.stats[0].skipped == {"bad_timestamp": 1}


def test_pcapng_without_radiotap_interface_is_an_error(tmp_path: Path) -> None:
    ng = dpkt.pcapng
    blob = bytes(ng.SectionHeaderBlockLE()) + bytes(_idb(ng.InterfaceDescriptionBlockLE, 105))
    blob += _epb(ng.EnhancedPacketBlockLE, 0, 1, probe_request(TX, 1, b""))
    path = tmp_path / "x.pcapng"
    path.write_bytes(blob)
    with pytest.raises(InputError, match=r"no radiotap interface \(link types: 105"):
        read_capture(path)


def test_receiver_id_from_path() -> None:
    assert receiver_id_from_path("/a/b/rx-3.pcapng") == "rx-3"
    assert receiver_id_from_path("rx1.pcap") == "rx1"
    assert receiver_id_from_path("lab.v2.csv") == "lab.v2"


# --------------------------------------------------------------------------
# bad input: one clear error or a counted skip


def _small_capture(tmp_path: Path, n: int = 5) -> Path:
    recs = [(10.0 + k, radiotap_header(-50) + probe_request(TX, k, b"x")) for k in range(n)]
    return _pcap(tmp_path / "ok.pcap", recs)


def test_truncated_pcap_keeps_the_frames_before(tmp_path: Path) -> None:
    p = _small_capture(tmp_path)
    raw = p.read_bytes()
    for cut in (7, 20):
        t = tmp_path / f"cut{cut}.pcap"
        t.write_bytes(raw[:-cut])
        (s,) = read_pcap(t).stats
        assert (s.frames_read, s.frames_kept, s.skipped) == (5, 4, {"truncated_record": 1})


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "empty file"),
        (b"\xd4\xc3\xb2\xa1\x02\x00", "truncated pcap file header"),
        (b"\x00\x01\x02\x03garbage\xff\xfe", "not a pcap, pcapng or CSV capture"),
        (bytes(dpkt.pcap.LEFileHdr(linktype=1)), r"link type 1 \(Ethernet\)"),
        (bytes(dpkt.pcap.LEFileHdr(linktype=105)), "802.11 without radiotap"),
        (
            bytes(dpkt.pcap.LEFileHdr(linktype=127)) + struct.pack("<IIII", 0, 0, 10**7, 10**7),
            "corrupt pcap record",
        ),
        (b"\x0a\x0d\x0d\x0a\x1c\x00\x00\x00\x99\x99\x99\x99", "bad byte-order magic"),
        (  # a second section header claiming 4 GiB: refused, not read into memory
            bytes(dpkt.pcapng.SectionHeaderBlockLE())
            + b"\x0a\x0d\x0d\x0a"
            + struct.pack("<I", 0xFFFFFFF0)
            + b"\x4d\x3c\x2b\x1a",
            r"corrupt pcapng block at byte \d+: length 4294967280",
        ),
    ],
)
def test_bad_files_give_one_line_errors(tmp_path: Path, content: bytes, message: str) -> None:
    p = tmp_path / "bad.pcap"
    p.write_bytes(content)
    with pytest.raises(InputError, match=message) as err:
        read_capture(p)
    assert "\n" not in str(err.value)
    assert str(p) in str(err.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="file not found"):
        read_capture(tmp_path / "nope.pcap")


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data())
def test_reader_survives_corrupted_files(tmp_path: Path, data: st.DataObject) -> None:
    raw = bytearray(_small_capture(tmp_path, 3).read_bytes())
    for _ in range(data.draw(st.integers(0, 6))):
        pos = data.draw(st.integers(0, len(raw) - 1))
        raw[pos] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(raw)))
    tail = data.draw(st.binary(max_size=40))
    p = tmp_path / "fuzz.pcap"
    p.write_bytes(bytes(raw[:cut]) + tail)
    try:
        cap = read_capture(p, "rx")
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    (s,) = cap.stats
    assert s.frames_kept + sum(s.skipped.values()) == s.frames_read
    assert set(s.skipped) <= set(SKIP_REASONS)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(blob=st.binary(max_size=300), pcapng=st.booleans())
def test_reader_survives_garbage_after_a_valid_header(
    tmp_path: Path, blob: bytes, pcapng: bool
) -> None:
    if pcapng:
        head = bytes(dpkt.pcapng.SectionHeaderBlockLE()) + bytes(
            _idb(dpkt.pcapng.InterfaceDescriptionBlockLE, 127)
        )
    else:
        head = bytes(dpkt.pcap.LEFileHdr(linktype=127))
    p = tmp_path / "g.pcap"
    p.write_bytes(head + blob)
    try:
        read_capture(p, "rx")
    except InputError as exc:
        assert "\n" not in str(exc)


def _fuzz_base_pcapng() -> bytes:
    """A valid pcapng: two sections (LE, BE), four interfaces with options, all packet blocks."""
    ng = dpkt.pcapng
    frame = [radiotap_header(-40 - k) + probe_request(TX, k, b"fz") for k in range(6)]
    le = bytes(ng.SectionHeaderBlockLE())
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=9, tsoffset=1_700_000_000))
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=0x80 | 20, tsoffset=-5))
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 105))
    le += bytes(_idb(ng.InterfaceDescriptionBlockLE, 127, tsresol=3))
    le += _epb(ng.EnhancedPacketBlockLE, 0, 123_456_789, frame[0])
    le += _epb(ng.EnhancedPacketBlockLE, 1, 3 * 2**20, frame[1])
    le += _epb(ng.EnhancedPacketBlockLE, 2, 7, frame[2])
    n3 = len(frame[3])
    pb = ng.PacketBlockLE(iface_id=3, ts_low=42, caplen=n3, pkt_len=n3, pkt_data=frame[3])
    le += bytes(pb)  # the obsolete packet block
    be = bytes(ng.SectionHeaderBlock())
    be += bytes(_idb(ng.InterfaceDescriptionBlock, 127, tsresol=6, tsoffset=2**30))
    be += _epb(ng.EnhancedPacketBlock, 0, 2**50, frame[4])
    spb = frame[5] + b"\0" * (-len(frame[5]) % 4)
    be += (
        struct.pack(">III", 3, 16 + len(spb), len(frame[5]))
        + spb
        + struct.pack(">I", 16 + len(spb))
    )
    return le + be


def test_fuzz_base_pcapng_is_valid(tmp_path: Path) -> None:
    p = tmp_path / "base.pcapng"
    p.write_bytes(_fuzz_base_pcapng())
    cap = read_pcap(p)
    (s,) = cap.stats
    assert (s.frames_read, s.frames_kept) == (6, 4)
    assert s.skipped == {"wrong_link_type": 1, "no_timestamp": 1}
    assert [int(t) for t in cap.frames.timestamp_ns] == [
        1_700_000_000_123_456_789,
        -2_000_000_000,
        42_000_000,
        2**30 * 10**9 + 2**50 * 1000,
    ]


_MUTATION = st.tuples(
    st.sampled_from(("flip", "overwrite", "insert", "delete", "truncate")),
    st.floats(0.0, 1.0, exclude_max=True),  # where, as a fraction of the current length
    st.integers(0, 255),
    st.binary(min_size=1, max_size=12),
)


def _mutate(raw: bytearray, op: str, where: float, byte: int, blob: bytes) -> None:
    pos = int(where * len(raw)) if raw else 0
    if op == "flip" and raw:
        raw[pos] ^= 1 << (byte % 8)
    elif op == "overwrite" and raw:
        raw[pos : pos + len(blob)] = blob[: len(raw) - pos]
    elif op == "insert":
        raw[pos:pos] = blob
    elif op == "delete":
        del raw[pos : pos + 1 + byte % 16]
    elif op == "truncate":
        del raw[pos:]


@FUZZ
@given(mutations=st.lists(_MUTATION, min_size=1, max_size=6))
def test_pcapng_reader_survives_mutations(
    tmp_path: Path, mutations: list[tuple[str, float, int, bytes]]
) -> None:
    """Flipped, overwritten, inserted, deleted or cut bytes of a valid multi-interface
    pcapng: either frames with int64 times and consistent counts, or a one-line InputError."""
    raw = bytearray(_fuzz_base_pcapng())
    for m in mutations:
        _mutate(raw, *m)
    p = tmp_path / "mut.pcapng"
    p.write_bytes(bytes(raw))
    try:
        cap = read_pcap(p, "rx")
    except InputError as exc:
        assert "\n" not in str(exc)
        assert str(p) in str(exc)
        return
    (s,) = cap.stats
    assert s.frames_kept + sum(s.skipped.values()) == s.frames_read
    assert set(s.skipped) <= set(SKIP_REASONS)
    ts = cap.frames.timestamp_ns
    assert ts.dtype == np.int64
    assert ts.shape == (s.frames_kept,)


# --------------------------------------------------------------------------
# CSV capture form

_H = "ab" * 32


def test_csv_capture_form(tmp_path: Path) -> None:
    p = tmp_path / "cap.csv"
    p.write_text(
        "receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm,extra\n"
        f"rx1,10.5,{_H.upper()},AA-BB-CC-DD-EE-FF,-61.5,x\n"
        f"rx2,10.5001,{_H},aa:bb:cc:dd:ee:ff,-70,y\n"
        f"rx2,11,{_H},aa:bb:cc:dd:ee:ff,3,z\n"
    )
    cap = read_capture(p)
    assert [s.receiver_id for s in cap.stats] == ["rx1", "rx2"]
    assert cap.stats[1].skipped == {"implausible_rss": 1}
    assert (cap.stats[1].frames_read, cap.stats[1].frames_kept) == (2, 1)
    f = cap.frames
    assert list(f.timestamp_ns) == [10_500_000_000, 10_500_100_000]
    assert list(f.frame_sha256) == [_H, _H]
    assert list(f.transmitter) == ["aa:bb:cc:dd:ee:ff"] * 2
    assert list(f.rss_dbm) == [-61.5, -70.0]


@pytest.mark.parametrize(
    ("row", "message"),
    [
        (f"rx1,1,{_H[:-1]},aa:bb:cc:dd:ee:ff,-50", r"cap.csv:2, column 'frame_sha256'"),
        # a transmitter id has no whitespace or commas (contract); a name is fine
        (f"rx1,1,{_H},my phone,-50", r"cap.csv:2, column 'transmitter'.*whitespace"),
        (f'rx1,1,{_H},"a,b",-50', r"cap.csv:2, column 'transmitter'.*commas"),
        (f'rx1,1,{_H},"",-50', r"cap.csv:2, column 'transmitter'"),
        (f"rx1,x,{_H},aa:bb:cc:dd:ee:ff,-50", r"cap.csv:2, column 'timestamp_s'"),
        (f"rx1,1,{_H},aa:bb:cc:dd:ee:ff,nan", r"cap.csv:2, column 'rss_dbm'"),
        # beyond int64 nanoseconds (year 2262): an error, not a wrapped time
        (f"rx1,1e12,{_H},aa:bb:cc:dd:ee:ff,-50", r"cap.csv:2, column 'timestamp_s'.*range"),
        (f"rx1,1e300,{_H},aa:bb:cc:dd:ee:ff,-50", r"cap.csv:2, column 'timestamp_s'.*range"),
    ],
)
def test_csv_capture_errors(tmp_path: Path, row: str, message: str) -> None:
    p = tmp_path / "cap.csv"
    p.write_text("receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm\n" + row + "\n")
    with pytest.raises(InputError, match=message):
        read_capture_csv(p)


def test_csv_capture_refuses_a_receiver_name(tmp_path: Path) -> None:
    p = tmp_path / "cap.csv"
    p.write_text("receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm\n")
    assert len(read_capture(p).frames) == 0
    with pytest.raises(InputError, match="receiver_id column"):
        read_capture(p, "rx9")


# --------------------------------------------------------------------------
# writer


def test_writer_files_are_real_80211_behind_radiotap(tmp_path: Path) -> None:
    rows = [
        ("7", 1.0, TX, "rx1", -55.4),
        ("7", 1.0, TX, "rx2", -60.6),
        ("8", 2.0, TX, "rx1", -56.0),
    ]
    sim = write_receiver_pcaps(
        rows,
        tmp_path,
        rng=np.random.default_rng(1),
        epoch_s=1000.0,
        fcs={"rx2": True},
        antenna_signals={"rx2": True},
    )
    assert sim.frames_written == {"rx1": 2, "rx2": 1}
    with open(sim.paths["rx1"], "rb") as fh:
        recs = list(dpkt.pcap.Reader(fh))
    for _ts, buf in recs:
        rt = dpkt.radiotap.Radiotap(buf)
        wlan = rt.data
        assert wlan.type == dpkt.ieee80211.MGMT_TYPE
        assert wlan.subtype == dpkt.ieee80211.M_PROBE_REQ
        assert wlan.mgmt.src == bytes.fromhex(TX.replace(":", ""))
    f1 = read_pcap(sim.paths["rx1"]).frames
    f2 = read_pcap(sim.paths["rx2"]).frames
    assert f1.frame_sha256[0] == f2.frame_sha256[0]  # same packet, same hash despite FCS
    assert f1.frame_sha256[0] != f1.frame_sha256[1]
    assert list(f1.rss_dbm) == [-55.0, -56.0]
    assert f2.antenna_rss_dbm[0] == ((0, -63), (1, -66))
    assert int(f1.timestamp_ns[0]) == 1001_000_000_000


def test_csv_capture_accepts_the_ids_of_devices_csv(tmp_path: Path) -> None:
    """Contract: a transmitter id is any string without commas or whitespace; a MAC is
    normalised (lower case, ':'), a name only lower-cased (matching is case-insensitive)."""
    p = tmp_path / "cap.csv"
    p.write_text(
        "receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm\n"
        f"rx1,1,{_H},phone,-50\nrx1,2,{_H},AA-BB-CC-DD-EE-FF,-51\nrx1,3,{_H},my-Tag_2,-52\n"
    )
    f = read_capture_csv(p).frames
    assert list(f.transmitter) == ["phone", "aa:bb:cc:dd:ee:ff", "my-tag_2"]


@settings(max_examples=200, deadline=None)
@given(st.text(min_size=0, max_size=80))
def test_transmitter_id_rule(value: str) -> None:
    problem = transmitter_id_problem(value)
    ok = (
        0 < len(value) <= 64
        and "," not in value
        and not any(c.isspace() for c in value)
        and value.isprintable()
    )
    assert (problem is None) == ok
    if ok:
        c = canonical_transmitter(value)
        assert canonical_transmitter(c) == c and c.lower() == c
        assert transmitter_id_problem(c) is None
