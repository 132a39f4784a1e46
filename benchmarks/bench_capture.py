"""Capture ingest throughput: frames/s of ``read_pcap``, as ratios against a baseline.

Writes a 100,000-frame radiotap pcap with :func:`write_receiver_pcaps` (and a
pcapng copy of the same frames) into a temporary directory, then times, in the
same run and on the same frames:

* ``dpkt.pcap.Reader`` loop      — dpkt's record reader, no decoding: the
  baseline (ratio 1.00);
* ``scapy RawPcapReader`` loop   — scapy's raw record reader, no decoding
  (if scapy is installed);
* radiopose record loop          — ``iter_raw_records``, no decoding;
* ``radiopose read_pcap``         — records + radiotap decode + SHA-256 + addr2,
  on the pcap and on the pcapng copy;
* dpkt full dissection           — ``dpkt.radiotap.Radiotap`` + 802.11 per frame;
* scapy full dissection          — ``scapy.utils.rdpcap`` with the RadioTap/Dot11
  layers, on the first ``--scapy-frames`` frames (it is slow).

Every rate is the best of ``--repeat`` runs (one run for the dissections);
each ratio is that rate over the baseline's rate of the same run.

Run: ``python -m benchmarks capture [--frames N] [--repeat R] [--scapy-frames M]
[--markdown]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import tempfile
import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import dpkt
import numpy as np

from radiopose.capture.records import iter_raw_records, read_pcap
from radiopose.capture.writer import write_receiver_pcaps

REPO = Path(__file__).resolve().parents[1]


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


def pcapng_copy(path: Path) -> Path:
    """The frames of a pcap as a one-interface pcapng (nanosecond ticks)."""
    out = path.with_suffix(".pcapng")
    with open(path, "rb") as fh, open(out, "wb") as dst:
        idb = dpkt.pcapng.InterfaceDescriptionBlockLE(
            linktype=127,
            snaplen=65535,
            opts=[
                dpkt.pcapng.PcapngOptionLE(code=dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL, data=b"\x09"),
                dpkt.pcapng.PcapngOptionLE(code=dpkt.pcapng.PCAPNG_OPT_ENDOFOPT),
            ],
        )
        dst.write(bytes(dpkt.pcapng.SectionHeaderBlockLE()) + bytes(idb))
        for ts, buf in dpkt.pcap.Reader(fh):
            ticks = int(ts * 1_000_000_000)
            epb = dpkt.pcapng.EnhancedPacketBlockLE(
                ts_high=ticks >> 32,
                ts_low=ticks & 0xFFFFFFFF,
                caplen=len(buf),
                pkt_len=len(buf),
                pkt_data=buf,
            )
            dst.write(bytes(epb))
    return out


def dpkt_loop(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _ts, _buf in dpkt.pcap.Reader(fh):
            n += 1
    return n


def scapy_raw_loop(path: Path) -> int:
    from scapy.utils import RawPcapReader  # type: ignore[import-not-found]

    n = 0
    with RawPcapReader(str(path)) as reader:
        for _buf, _meta in reader:
            n += 1
    return n


def radiopose_loop(path: Path) -> int:
    n = 0
    with open(path, "rb", buffering=1 << 20) as fh:
        for _rec in iter_raw_records(fh, path):
            n += 1
    return n


def radiopose_read(path: Path) -> int:
    return len(read_pcap(path, "rx1").frames)


def dpkt_dissect(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for _ts, buf in dpkt.pcap.Reader(fh):
            rt = dpkt.radiotap.Radiotap(buf)
            _ = rt.data  # the dissected 802.11 frame
            n += 1
    return n


def scapy_dissect(count: int) -> Callable[[Path], int]:
    def run(path: Path) -> int:
        from scapy.utils import rdpcap

        return len(rdpcap(str(path), count=count))

    return run


def best_rate(fn: Callable[[Path], int], path: Path, repeat: int) -> tuple[int, float]:
    best = float("inf")
    n = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = fn(path)
        best = min(best, time.perf_counter() - t0)
    return n, n / best


def _version(package: str) -> str:
    try:
        return version(package)
    except PackageNotFoundError:
        return "not installed"


def machine() -> str:
    """nproc, CPU model, Python, dpkt/scapy versions and the commit, on one line."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "--no-optional-locks", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        commit += " + working tree" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return (
        f"{os.cpu_count()} CPUs ({cpu}), Python {platform.python_version()}, "
        f"dpkt {_version('dpkt')}, scapy {_version('scapy')}, commit {commit}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100_000, help="frames in the capture")
    ap.add_argument("--repeat", type=int, default=3, help="runs per fast reader (best kept)")
    ap.add_argument(
        "--scapy-frames", type=int, default=2_000, help="frames for scapy's full dissection"
    )
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    args = ap.parse_args()
    try:  # imported here, outside the timings; dot11 makes rdpcap dissect RadioTap/Dot11
        from scapy.layers import dot11  # type: ignore[import-not-found]

        have_scapy = dot11 is not None
    except ImportError:
        have_scapy = False
    with tempfile.TemporaryDirectory() as tmp:
        path = make_capture(Path(tmp), args.frames)
        ng = pcapng_copy(path)
        size_mb = path.stat().st_size / 1e6
        cases: list[tuple[str, Callable[[Path], int], Path, int]] = [
            ("dpkt.pcap.Reader loop, no decoding (baseline)", dpkt_loop, path, args.repeat),
        ]
        if have_scapy:
            cases.append(
                ("scapy RawPcapReader loop, no decoding", scapy_raw_loop, path, args.repeat)
            )
        cases += [
            ("radiopose iter_raw_records loop, no decoding", radiopose_loop, path, args.repeat),
            ("radiopose read_pcap, pcap (full ingest)", radiopose_read, path, args.repeat),
            ("radiopose read_pcap, pcapng (full ingest)", radiopose_read, ng, args.repeat),
            ("dpkt Radiotap + 802.11 dissection", dpkt_dissect, path, 1),
        ]
        if have_scapy:
            n_sc = min(args.scapy_frames, args.frames)
            cases.append(
                (
                    f"scapy rdpcap RadioTap/Dot11 dissection ({n_sc:,} frames)",
                    scapy_dissect(n_sc),
                    path,
                    1,
                )
            )
        print(f"capture: {args.frames:,} frames, {size_mb:.1f} MB pcap, best of {args.repeat}")
        print(machine())
        if args.markdown:
            print("\n| reader (same frames, same run) | frames | frames/s | ratio |")
            print("|---|---:|---:|---:|")
        else:
            print(f"{'reader':56s} {'frames':>8s} {'frames/s':>11s} {'ratio':>6s}")
        base = 0.0
        for name, fn, p, rep in cases:
            n, rate = best_rate(fn, p, rep)
            base = base or rate
            if args.markdown:
                print(f"| {name} | {n:,} | {rate:,.0f} | {rate / base:.3f} |")
            else:
                print(f"{name:56s} {n:8d} {rate:11,.0f} {rate / base:6.3f}")


if __name__ == "__main__":
    main()
