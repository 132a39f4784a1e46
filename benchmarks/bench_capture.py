"""Capture ingest throughput: frames/s of ``read_pcap`` against baselines.

Writes a 100,000-frame radiotap pcap with :func:`write_receiver_pcaps` into a
temporary directory, then times, in the same run and on the same file:

* ``dpkt.pcap.Reader`` loop      — dpkt's record reader, no decoding (the floor);
* ``radiopose read_pcap``         — records + radiotap decode + SHA-256 + addr2;
* ``dpkt full dissection``        — dpkt.radiotap.Radiotap + 802.11 per frame;
* ``scapy rdpcap`` (if installed) — scapy's full dissection.

Run: ``python benchmarks/bench_capture.py [--frames N] [--repeat R]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import dpkt
import numpy as np

from radiopose.capture.records import read_pcap
from radiopose.capture.writer import write_receiver_pcaps


def make_capture(directory: Path, n_frames: int) -> Path:
    """A one-receiver pcap of ``n_frames`` probe requests from 20 transmitters."""
    rng = np.random.default_rng(0)
    rows = {
        "packet_id": np.arange(n_frames).astype(str),
        "timestamp_s": np.arange(n_frames) * 0.005,
        "transmitter": np.array([f"02:00:00:00:00:{k % 20:02x}" for k in range(n_frames)]),
        "receiver_id": np.full(n_frames, "rx1"),
        "rss_dbm": rng.uniform(-90, -30, n_frames),
    }
    sim = write_receiver_pcaps(
        rows, directory, rng=rng, epoch_s=1.7e9, antenna_signals={"rx1": False}
    )
    return sim.paths["rx1"]


def dpkt_loop(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _ts, _buf in dpkt.pcap.Reader(fh):
            n += 1
    return n


def dpkt_dissect(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _ts, buf in dpkt.pcap.Reader(fh):
            rt = dpkt.radiotap.Radiotap(buf)
            _ = rt.data  # the dissected 802.11 frame
            n += 1
    return n


def radiopose_read(path: Path) -> int:
    return len(read_pcap(path, "rx1").frames)


def scapy_read(path: Path) -> int:
    from scapy.utils import rdpcap  # type: ignore[import-not-found]

    return len(rdpcap(str(path)))


def best_rate(fn: Callable[[Path], int], path: Path, repeat: int) -> tuple[int, float]:
    best = float("inf")
    n = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = fn(path)
        best = min(best, time.perf_counter() - t0)
    return n, n / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = make_capture(Path(tmp), args.frames)
        size_mb = path.stat().st_size / 1e6
        cases: list[tuple[str, Callable[[Path], int], int]] = [
            ("dpkt.pcap.Reader loop (no decoding)", dpkt_loop, args.repeat),
            ("radiopose read_pcap (full ingest)", radiopose_read, args.repeat),
            ("dpkt Radiotap+802.11 dissection", dpkt_dissect, 1),
        ]
        try:
            import scapy  # type: ignore[import-not-found]  # noqa: F401

            cases.append(("scapy rdpcap (dissection)", scapy_read, 1))
        except ImportError:
            pass
        print(f"capture: {args.frames} frames, {size_mb:.1f} MB, best of {args.repeat}")
        print(f"{'reader':40s} {'frames':>8s} {'frames/s':>10s}")
        for name, fn, rep in cases:
            n, rate = best_rate(fn, path, rep)
            print(f"{name:40s} {n:8d} {rate:10,.0f}")


if __name__ == "__main__":
    main()
