"""Simulated receiver captures: one pcap per receiver, radiotap + real 802.11.

:func:`write_receiver_pcaps` turns synchronised packet rows (the columns of
``packets.csv``) into what the receivers of a real deployment would have
recorded: every packet becomes one 802.11 probe request (unique per
transmitter and ``packet_id``: the id is in the sequence number and in a
vendor-specific element, so all receivers hash the same bytes), behind a
radiotap header carrying the RSS as the dBm antenna signal (rounded to whole
dBm, as drivers report it). Each receiver's clock has its own offset and drift,
timestamps get Gaussian jitter, frames can be lost or recorded twice. Files
are written with ``dpkt.pcap.Writer``.

Receiver clock model (the same one :mod:`radiopose.capture.sync` estimates)::

    t_rx = t + offset_s + drift_ppm·1e-6·(t - t_first) + epoch_s + latency

with ``t`` the packet time and ``t_first`` the earliest packet time. The
ground truth of what ``radiopose sync`` should recover from the files is
written beside them (``pcap_truth.csv``, packets.csv columns, packets
renumbered 0, 1, 2, ... in time order as sync numbers them) and read back
with :func:`read_pcap_truth`: the input rows minus lost frames, minus rows
whose rounded RSS the reader rejects as implausible, minus every packet one of
whose receivers recorded it twice (a duplicate within the matching tolerance
makes the packet ambiguous by the synchronisation rule).
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import dpkt
import numpy as np

from radiopose.capture.radiotap import FIELD_ALIGN_SIZE
from radiopose.capture.records import LINKTYPE_IEEE802_11_RADIOTAP, PLAUSIBLE_RSS_DBM
from radiopose.packets import Packets, read_packets_csv, write_packets_csv
from radiopose.tables import write_table

__all__ = [
    "CLOCKS_FILE",
    "TRUTH_FILE",
    "CaptureConfig",
    "PcapSimulation",
    "pack_radiotap",
    "probe_request",
    "radiotap_header",
    "read_pcap_truth",
    "simulate_captures",
    "whole_dbm",
    "write_receiver_pcaps",
]

TRUTH_FILE = "pcap_truth.csv"
CLOCKS_FILE = "clocks.csv"

_VENDOR_OUI = b"\x02\x52\x50"  # locally administered, "RP"


# --------------------------------------------------------------------------
# frame building


def pack_radiotap(
    namespaces: Sequence[Mapping[int, bytes] | tuple[bytes, int, bytes, int]],
) -> bytes:
    """Pack a radiotap header from fields, aligning each as the standard says.

    Parameters
    ----------
    namespaces
        In order. A mapping ``{bit: raw little-endian field bytes}`` is a
        radiotap namespace (bits 0-27, one present word); a tuple
        ``(oui, sub_namespace, data, bitmap)`` is a vendor namespace whose
        ``data`` the decoder must skip. Consecutive namespaces are linked with
        bit 29 (radiotap) or bit 30 (vendor) plus bit 31.

    Returns
    -------
    bytes
        The header, ``it_len`` set.
    """
    n_words = len(namespaces)
    words = []
    for k, ns in enumerate(namespaces):
        word = 0
        if isinstance(ns, tuple):
            word = ns[3] & 0x1FFFFFFF
        else:
            for bit, raw in ns.items():
                if bit not in FIELD_ALIGN_SIZE or len(raw) != FIELD_ALIGN_SIZE[bit][1]:
                    raise ValueError(f"radiotap field {bit} needs a known bit and its size")
                word |= 1 << bit
        if k + 1 < n_words:
            word |= 1 << 31
            word |= 1 << (30 if isinstance(namespaces[k + 1], tuple) else 29)
        words.append(word)
    out = bytearray(b"\0\0\0\0")
    for w in words:
        out += struct.pack("<I", w)
    for k, ns in enumerate(namespaces):
        if not isinstance(ns, tuple):
            for bit in sorted(ns):
                align = FIELD_ALIGN_SIZE[bit][0]
                out += b"\0" * (-len(out) % align)
                out += ns[bit]
        if k + 1 < n_words and isinstance(nxt := namespaces[k + 1], tuple):
            oui, subns, data, _ = nxt
            out += b"\0" * (-len(out) % 2)
            out += bytes(oui[:3]).ljust(3, b"\0") + bytes([subns]) + struct.pack("<H", len(data))
            out += data
    struct.pack_into("<H", out, 2, len(out))
    return bytes(out)


def radiotap_header(
    signal_dbm: int,
    *,
    fcs: bool = False,
    channel_mhz: int = 2437,
    tsft_us: int | None = None,
    antenna_signals_dbm: Sequence[int] = (),
) -> bytes:
    """A Linux-style radiotap header: TSFT, Flags, Rate, Channel, signal, antenna.

    With ``antenna_signals_dbm`` the first namespace carries the combined
    ``signal_dbm`` and one more radiotap namespace per antenna carries that
    antenna's index and signal (extended present bitmaps).
    """
    first: dict[int, bytes] = {}
    if tsft_us is not None:
        first[0] = struct.pack("<Q", tsft_us & 0xFFFF_FFFF_FFFF_FFFF)
    first[1] = bytes([0x10 if fcs else 0x00])
    first[2] = b"\x02"  # 1 Mb/s
    first[3] = struct.pack("<HH", channel_mhz, 0x00A0)  # CCK, 2 GHz
    first[5] = struct.pack("<b", signal_dbm)
    first[11] = b"\x00"
    spaces: list[Mapping[int, bytes]] = [first]
    for ant, dbm in enumerate(antenna_signals_dbm):
        spaces.append({5: struct.pack("<b", dbm), 11: bytes([ant])})
    return pack_radiotap(spaces)


def _mac_bytes(mac: str) -> bytes:
    raw = bytes.fromhex(mac.replace(":", "").replace("-", ""))
    if len(raw) != 6:
        raise ValueError(f"not a MAC address: {mac!r}")
    return raw


def probe_request(transmitter: str, sequence: int, tag: bytes) -> bytes:
    """An 802.11 probe request from ``transmitter`` (no FCS).

    ``sequence`` goes into the sequence-control field (mod 4096) and ``tag``
    into a vendor-specific element, which makes the frame unique.
    """
    header = (
        b"\x40\x00\x00\x00"  # frame control (mgmt, probe request), duration
        + b"\xff" * 6
        + _mac_bytes(transmitter)
        + b"\xff" * 6
        + struct.pack("<H", (sequence % 4096) << 4)
    )
    tag = tag[:250]
    body = (
        b"\x00\x00"  # wildcard SSID
        + b"\x01\x04\x02\x04\x0b\x16"  # supported rates 1, 2, 5.5, 11 Mb/s
        + bytes([221, 3 + len(tag)])
        + _VENDOR_OUI
        + tag
    )
    return header + body


# --------------------------------------------------------------------------
# simulation


@dataclass(frozen=True, eq=False)
class PcapSimulation:
    """What :func:`write_receiver_pcaps` wrote.

    Attributes
    ----------
    paths
        ``receiver_id -> pcap file``.
    truth
        The packets ``radiopose sync`` should recover (also in ``pcap_truth.csv``).
    frames_written
        ``receiver_id -> frames`` written, duplicates included.
    clocks
        ``receiver_id -> (offset_s, drift_ppm)`` of each receiver's clock
        (filled by :func:`simulate_captures`).
    """

    paths: dict[str, Path]
    truth: Packets
    frames_written: dict[str, int]
    clocks: dict[str, tuple[float, float]] = field(default_factory=dict)


def _columns(packets: Any) -> dict[str, np.ndarray]:
    names = ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm")
    if isinstance(packets, Packets):
        cols = {n: np.asarray(getattr(packets, n)) for n in names}
    elif isinstance(packets, Mapping) or hasattr(packets, "columns"):
        cols = {n: np.asarray(packets[n]) for n in names}
    else:
        rows = list(packets)
        cols = {
            n: np.asarray([r[i] for r in rows], dtype=object if i != 1 and i != 4 else float)
            for i, n in enumerate(names)
        }
    out = {
        "packet_id": np.asarray([str(v) for v in cols["packet_id"]], dtype=object),
        "timestamp_s": np.asarray(cols["timestamp_s"], dtype=np.float64),
        "transmitter": np.asarray([str(v).lower() for v in cols["transmitter"]], dtype=object),
        "receiver_id": np.asarray([str(v) for v in cols["receiver_id"]], dtype=object),
        "rss_dbm": np.asarray(cols["rss_dbm"], dtype=np.float64),
    }
    n = out["timestamp_s"].shape[0]
    if any(v.shape != (n,) for v in out.values()):
        raise ValueError("packet columns must all have the same length")
    return out


def _per_receiver(value: float | Mapping[str, Any], rid: str, default: Any) -> Any:
    if isinstance(value, Mapping):
        return value.get(rid, default)
    return value


def write_receiver_pcaps(
    packets: Packets | Mapping[str, Any] | Sequence[Sequence[Any]],
    out_dir: str | os.PathLike[str],
    *,
    rng: np.random.Generator,
    clock_offset_s: float | Mapping[str, float] = 0.0,
    drift_ppm: float | Mapping[str, float] = 0.0,
    jitter_s: float = 0.0,
    loss_fraction: float = 0.0,
    duplicate_fraction: float = 0.0,
    duplicate_delay_s: float = 1e-3,
    epoch_s: float = 0.0,
    fcs: bool | Mapping[str, bool] = False,
    antenna_signals: bool | Mapping[str, bool] = False,
    nanosecond: bool = True,
    receiver_ids: Sequence[str] = (),
) -> PcapSimulation:
    """Write one radiotap pcap per receiver from synchronised packet rows.

    Parameters
    ----------
    packets
        Rows with ``packet_id, timestamp_s, transmitter, receiver_id, rss_dbm``
        (a :class:`radiopose.packets.Packets`, a mapping of columns, or a
        sequence of rows in that column order); ``timestamp_s`` is the send time.
    out_dir
        Directory for ``<receiver_id>.pcap`` and ``pcap_truth.csv`` (created).
    rng
        Random generator (loss, duplicates, jitter).
    clock_offset_s, drift_ppm
        Receiver clock offset (s) and drift (ppm), one value for all receivers
        or ``receiver_id -> value`` (missing receivers: 0).
    jitter_s
        Scale of the timestamp latency, seconds: each timestamp is late by
        ``|N(0, jitter_s)|`` (half-normal; a receiver stamps a frame after it
        arrives, and the constant part of its latency is its clock offset).
    loss_fraction
        Probability that a receiver misses a frame.
    duplicate_fraction
        Probability that a receiver records a kept frame a second time,
        ``U(0, duplicate_delay_s)`` seconds later.
    duplicate_delay_s
        Largest delay of a duplicate, seconds (keep it below the sync tolerance).
    epoch_s
        Added to every receiver timestamp (pcap times must not be negative).
    fcs
        Append a valid FCS (and set radiotap Flags 0x10): bool or per receiver.
    antenna_signals
        Also write two per-antenna signals (extended bitmaps): bool or per receiver.
    nanosecond
        Write nanosecond-resolution pcap (else microseconds).
    receiver_ids
        Receivers to write a capture for even if no row names them (a valid,
        empty pcap); first, in this order, then any others of the rows.

    Returns
    -------
    PcapSimulation
        Paths, frame counts and the expected synchronised packets.

    Raises
    ------
    ValueError
        Inconsistent columns, a fraction outside ``[0, 1]``, a negative timestamp.
    """
    for name, frac in (
        ("loss_fraction", loss_fraction),
        ("duplicate_fraction", duplicate_fraction),
    ):
        if not 0.0 <= frac <= 1.0:
            raise ValueError(f"{name} must be in [0, 1], got {frac}")
    cols = _columns(packets)
    n = int(cols["timestamp_s"].shape[0])
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    # Random draws in a fixed order: loss, duplicates, duplicate delays, jitter.
    lost = rng.random(n) < loss_fraction
    dup = (rng.random(n) < duplicate_fraction) & ~lost
    dup_delay_s = rng.uniform(0.0, duplicate_delay_s, n)
    # Timestamp latency: a receiver stamps a frame after it arrives, never before.
    noise_s = np.abs(rng.normal(0.0, jitter_s, n)) if jitter_s > 0 else np.zeros(n)

    t = cols["timestamp_s"]
    t_first = float(t.min()) if n else 0.0
    rss_int = np.clip(np.rint(cols["rss_dbm"]), -128, 127).astype(np.int64)
    lo, hi = PLAUSIBLE_RSS_DBM
    plausible = (rss_int >= lo) & (rss_int <= hi)

    rx_ids = list(dict.fromkeys([*receiver_ids, *cols["receiver_id"].tolist()]))
    t_rx = np.empty(n)
    for rid in rx_ids:
        m = cols["receiver_id"] == rid
        off = float(_per_receiver(clock_offset_s, rid, 0.0))
        drift = float(_per_receiver(drift_ppm, rid, 0.0))
        t_rx[m] = t[m] + off + drift * 1e-6 * (t[m] - t_first) + epoch_s
    t_rx += noise_s
    if n and float(np.min(t_rx)) < 0.0:
        raise ValueError("receiver timestamps would be negative; pass a larger epoch_s")

    frames: dict[tuple[str, str], bytes] = {}
    seq_of: dict[tuple[str, str], int] = {}
    paths: dict[str, Path] = {}
    written: dict[str, int] = {}
    for rid in rx_ids:
        idx = np.flatnonzero((cols["receiver_id"] == rid) & ~lost)
        with_fcs = bool(_per_receiver(fcs, rid, False))
        per_ant = bool(_per_receiver(antenna_signals, rid, False))
        recs: list[tuple[float, bytes]] = []
        for i in idx:
            key = (cols["transmitter"][i], cols["packet_id"][i])
            frame = frames.get(key)
            if frame is None:
                seq = seq_of.setdefault(key, len(seq_of))
                tag = f"{key[0]}/{key[1]}".encode()
                frame = frames[key] = probe_request(key[0], seq, tag)
            sig = int(rss_int[i])
            ants = (max(sig - 2, -128), max(sig - 5, -128)) if per_ant else ()
            ts = float(t_rx[i])
            rt = radiotap_header(sig, fcs=with_fcs, tsft_us=int(ts * 1e6), antenna_signals_dbm=ants)
            body = frame + struct.pack("<I", zlib.crc32(frame)) if with_fcs else frame
            recs.append((ts, rt + body))
            if dup[i]:
                recs.append((ts + float(dup_delay_s[i]), rt + body))
        recs.sort(key=lambda r: r[0])
        path = out / f"{rid}.pcap"
        with open(path, "wb") as fh:
            w = dpkt.pcap.Writer(
                fh, snaplen=65535, linktype=LINKTYPE_IEEE802_11_RADIOTAP, nano=nanosecond
            )
            for ts, pkt in recs:
                w.writepkt_time(pkt, ts)
        paths[rid] = path
        written[rid] = len(recs)

    # Ground truth: what survives loss and the reader's plausibility check,
    # without packets that a duplicate makes ambiguous.
    keep = ~lost & plausible
    bad_keys = {
        (cols["transmitter"][i], cols["packet_id"][i]) for i in np.flatnonzero(dup & plausible)
    }
    if bad_keys:
        keep &= np.asarray(
            [
                (tx, pid) not in bad_keys
                for tx, pid in zip(cols["transmitter"], cols["packet_id"], strict=True)
            ],
            dtype=bool,
        )
    # Number the surviving packets 0, 1, 2, ... in time order, as
    # `radiopose sync` numbers the packets it recovers.
    kept_t = t[keep]
    kept_keys = list(zip(cols["transmitter"][keep], cols["packet_id"][keep], strict=True))
    number: dict[tuple[str, str], int] = {}
    for i in np.argsort(kept_t, kind="stable"):
        number.setdefault(kept_keys[i], len(number))
    truth = Packets(
        packet_id=np.asarray([str(number[k]) for k in kept_keys], dtype=object),
        timestamp_s=t[keep] + epoch_s,
        transmitter=cols["transmitter"][keep],
        receiver_id=cols["receiver_id"][keep],
        rss_dbm=rss_int[keep].astype(np.float64),
    )
    write_packets_csv(truth, out / TRUTH_FILE)
    return PcapSimulation(paths, truth, written)


def read_pcap_truth(out_dir: str | os.PathLike[str]) -> Packets:
    """Read back the ground truth written by :func:`write_receiver_pcaps`.

    Timestamps are the packets' send times plus ``epoch_s``; they equal the
    synchronised times of a receiver with zero offset and drift used as the
    sync reference.
    """
    return read_packets_csv(Path(out_dir) / TRUTH_FILE)


# --------------------------------------------------------------------------
# simulated deployments (``radiopose simulate --pcap``)


@dataclass(frozen=True)
class CaptureConfig:
    """How imperfect the simulated receivers' captures are.

    The first receiver is the reference: its clock is the simulation clock
    (offset 0, drift 0), so ``radiopose sync`` with it as reference (the
    default) maps every packet back to the simulation's time axis.

    Attributes
    ----------
    clock_offset_max_s
        The other receivers' clock offsets are drawn from ``U(0, max)``, seconds
        (ahead of the reference, so that no pcap timestamp is negative).
    drift_max_ppm
        Their clock drifts are drawn from ``U(-max, max)``, ppm.
    jitter_s
        Scale of the half-normal timestamp latency of every receiver, seconds.
    duplicate_fraction
        Probability that a receiver records a frame twice (within 1 ms). By
        the synchronisation rule such a packet is ambiguous and dropped, so it
        is missing from ``radiopose sync``'s output (``pcap_truth.csv`` lists
        what remains).
    """

    clock_offset_max_s: float = 1.0
    drift_max_ppm: float = 20.0
    jitter_s: float = 20e-6
    duplicate_fraction: float = 0.0

    def out_of_range(self) -> tuple[str, float, float, float] | None:
        """The first setting out of its range as ``(name, value, low, high)``
        (NaN is out of every range), or ``None``."""
        checks = (
            ("clock_offset_max_s", self.clock_offset_max_s, 0.0, 3600.0),
            ("drift_max_ppm", self.drift_max_ppm, 0.0, 1000.0),
            ("jitter_s", self.jitter_s, 0.0, 1e-3),
            ("duplicate_fraction", self.duplicate_fraction, 0.0, 1.0),
        )
        for name, value, lo, hi in checks:
            if not lo <= value <= hi:
                return name, float(value), lo, hi
        return None

    def validate(self) -> None:
        """Raise :class:`ValueError` naming the first setting out of range."""
        bad = self.out_of_range()
        if bad is not None:
            name, value, lo, hi = bad
            raise ValueError(f"{name} must be in [{lo:g}, {hi:g}], got {value}")


def whole_dbm(packets: Packets) -> Packets:
    """The same rows with RSS rounded to whole dBm, as radiotap carries it."""
    return replace(packets, rss_dbm=np.rint(packets.rss_dbm) + 0.0)  # + 0.0: no "-0"


def simulate_captures(
    packets: Packets,
    receiver_ids: Sequence[str],
    out_dir: str | os.PathLike[str],
    *,
    seed: int,
    config: CaptureConfig | None = None,
) -> PcapSimulation:
    """Write what the receivers of a simulated scenario would have captured.

    Parameters
    ----------
    packets
        The simulation's ``packets.csv`` rows; RSS should already be whole
        dBm (:func:`whole_dbm`) for ``radiopose sync`` to reproduce them exactly.
    receiver_ids
        All receivers, reference first (a receiver may have heard nothing).
    out_dir
        Directory for ``<receiver_id>.pcap``, ``pcap_truth.csv`` and
        ``clocks.csv`` (``receiver_id, offset_s, drift_ppm``).
    seed
        The simulation's seed; the captures use their own random stream, so
        writing them does not change any other simulated file.
    config
        Imperfections (default :class:`CaptureConfig`).

    Returns
    -------
    PcapSimulation
        Paths, expected packets and each receiver's true clock.
    """
    cfg = config or CaptureConfig()
    cfg.validate()
    rng = np.random.default_rng([seed, 0x70636170])  # "pcap": a stream of its own
    ids = list(receiver_ids)
    clocks = {ids[0]: (0.0, 0.0)}
    for rid in ids[1:]:
        clocks[rid] = (
            float(rng.uniform(0.0, cfg.clock_offset_max_s)),
            float(rng.uniform(-cfg.drift_max_ppm, cfg.drift_max_ppm)),
        )
    sim = write_receiver_pcaps(
        packets,
        out_dir,
        rng=rng,
        clock_offset_s={r: c[0] for r, c in clocks.items()},
        drift_ppm={r: c[1] for r, c in clocks.items()},
        jitter_s=cfg.jitter_s,
        duplicate_fraction=cfg.duplicate_fraction,
        receiver_ids=ids,  # a receiver that heard nothing still gets a (valid, empty) capture
    )
    write_table(
        Path(out_dir) / CLOCKS_FILE,
        {
            "receiver_id": ids,
            "offset_s": [clocks[r][0] for r in ids],
            "drift_ppm": [clocks[r][1] for r in ids],
        },
        decimals={"offset_s": 9, "drift_ppm": 6},
    )
    return replace(sim, clocks=clocks)
