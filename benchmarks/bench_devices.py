"""Many devices at one site through the live pipeline: throughput, memory, checkpoint.

A deployment tracks many phones at once, most of them of a few models. This
benchmark enrols ``N`` devices with one pattern and transmit power at the
paper's standard site (20 m × 20 m, 0.1 m and 1° candidates, 4 receivers;
``ScenarioConfig()``, σ 1 dB), gives each its own walk with turns (its own
seed), one packet every ``--interval-ms`` from a random phase, and feeds
every receiver's frames to the live pipeline
(:class:`radiopose.server.live.LivePipeline` over SQLite, in process, receiver
clocks aligned so that calibration is immediate), batches of 0.1 s of trace
per receiver as the agents send them. All batches are stored first, then the
pipeline steps until every packet has its estimate (throughput, as in
``scripts/live_pose3d.py``). Per method and ``N``:

* **packets per second** of the pipeline after the first tracked packet (wall
  and CPU), and the ratio to ``full`` (the paper's pipeline, the live default
  at a 2-D site) in the same run; the **offered load** ``N × 1000 /
  interval_ms`` packets/s beside it: a rate above the load keeps up;
* **memory**: the peak growth of the resident set over the run (MB), each
  variant in a forked process of its own;
* **checkpoint**: the size of the last pickled pipeline state (MB).

Methods: ``full``, ``filter`` (lag 0.25 s, with the live re-solve of each
track's first 1.5 s: the default), ``filter`` without the re-solve
(``live_resolve_times_s = ()``) and ``filter`` drawing full-grid hypotheses
every 0.5 s of a track instead of 0.1 s (``reentry_interval_s = 0.5``).

Usage::

    python -m benchmarks devices [--devices 10 50] [--interval-ms 100]
        [--duration-s 20] [--seed 424242] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import resource
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import emit, machine, table
from radiopose.filtering import FilterConfig
from radiopose.server.app import import_site_dir
from radiopose.server.db import Database
from radiopose.server.live import LiveConfig, LivePipeline
from radiopose.simulate import MotionConfig, ScenarioConfig, simulate
from radiopose.simulate.channel import link_rss_dbm
from radiopose.simulate.trajectories import device_path
from radiopose.site import Device
from radiopose.site_io import write_site
from radiopose.tracker import TrackerConfig

BATCH_S = 0.1
"""Trace seconds per batch of one receiver (the agents' batch interval)."""

EPOCH_NS = 1_000_000_000_000
"""Receiver time of the trace's start, ns (any positive value)."""

VARIANTS: dict[str, tuple[str, TrackerConfig | None]] = {
    "full": ("full", None),
    "filter": ("filter", None),
    "filter, no re-solve": (
        "filter",
        TrackerConfig(filter=replace(FilterConfig(), live_resolve_times_s=())),
    ),
    "filter, re-entry 0.5 s": (
        "filter",
        TrackerConfig(filter=replace(FilterConfig(), reentry_interval_s=0.5)),
    ),
}


def scene(n_devices: int, interval_ms: float, duration_s: float, seed: int):  # type: ignore[no-untyped-def]
    """The standard site with ``n_devices`` enrolled devices of one pattern and
    power, and every receiver's frames ``{receiver: [(ns, sha, tx, rss)]}``."""
    cfg = ScenarioConfig(duration_s=0.05, noise_db=1.0)
    sim = simulate(cfg, seed=seed)
    site = sim.site
    d0 = site.devices[0]
    devices = tuple(
        Device(f"02:00:00:00:{i // 256:02x}:{i % 256:02x}", d0.pattern, d0.tx_power_dbm)
        for i in range(n_devices)
    )
    site = replace(site, devices=devices)
    rx = site.receivers
    rx_xyz = np.array([[r.x_m, r.y_m, r.z_m] for r in rx])
    rx_orient = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in rx])
    rx_pats = tuple(site.patterns[r.pattern] for r in rx)
    motion = MotionConfig(path="walk", rotation="heading")
    rng = np.random.default_rng(seed)
    frames: dict[str, list[tuple[int, str, str, float]]] = {r.receiver_id: [] for r in rx}
    step_s = interval_ms / 1000.0
    n_packets = 0
    for dev in devices:
        t = rng.uniform(0.0, step_s) + np.arange(max(1, round(duration_s / step_s))) * step_s
        pos, ori = device_path(rng, t, (0.0, cfg.size_m, 0.0, cfg.size_m), cfg.z_m, motion)
        rss = link_rss_dbm(
            cfg.channel, pos, ori, site.patterns[dev.pattern], dev.tx_power_dbm,
            rx_xyz, rx_orient, rx_pats,
        )  # fmt: skip
        rss = rss + rng.normal(0.0, cfg.noise_db, rss.shape)
        for k in range(t.size):
            sha = hashlib.sha256(f"{dev.transmitter}/{k}".encode()).hexdigest()
            ns = EPOCH_NS + round(t[k] * 1e9)
            for j, r in enumerate(rx):
                frames[r.receiver_id].append((ns, sha, dev.transmitter, float(rss[k, j])))
        n_packets += t.size
    return site, frames, n_packets


def batches(frames: dict[str, list[tuple[int, str, str, float]]]) -> list[tuple[str, str, list]]:
    """``(receiver, batch id, frames)`` of 0.1 s of trace each, in time order."""
    out = []
    for r, rows in frames.items():
        rows = sorted(rows)
        k = np.array([(ns - EPOCH_NS) // round(BATCH_S * 1e9) for ns, *_ in rows])
        for i in np.unique(k):
            sel = np.flatnonzero(k == i)
            out.append((int(i), r, f"{r}-{i}", [rows[j] for j in sel]))
    out.sort(key=lambda b: (b[0], b[1]))
    return [(r, bid, rows) for _i, r, bid, rows in out]


def _status_mb(field: str) -> float:
    """``VmRSS`` or ``VmHWM`` (peak) of this process, MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_apart(site_dir: Path, db_path: Path, bs: list, n_packets: int, variant: str) -> dict:
    """:func:`run` in a forked child of its own, so that each variant's memory
    is measured from the same start (in one process a variant reuses what an
    earlier one freed). In process where this one may not fork (no fork here,
    or numba's OpenMP layer already launched, as in a test session)."""
    import multiprocessing

    from radiopose.filtering.forked import fork_available

    if not fork_available():
        return run(site_dir, db_path, bs, n_packets, variant)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        return pool.apply(run, (site_dir, db_path, bs, n_packets, variant))


def run(site_dir: Path, db_path: Path, bs: list, n_packets: int, variant: str) -> dict[str, Any]:
    """Store every batch, then step the pipeline until every packet is estimated."""
    method, tracker = VARIANTS[variant]
    db = Database(f"sqlite:///{db_path}")
    import_site_dir(db, site_dir)
    for r, bid, rows in bs:
        db.store_batch(r, bid, rows)
    cfg = LiveConfig(
        method=method, tracker=tracker, live_lag_s=0.25, calibration_s=1.0,
        idle_flush_s=1e6, batches_per_step=20, checkpoint_s=1.0,
    )  # fmt: skip
    with contextlib.suppress(OSError):  # the peak (VmHWM) from here, not the parent's
        Path("/proc/self/clear_refs").write_text("5")
    mem0 = _status_mb("VmRSS")
    p = LivePipeline(db, cfg)
    w0, c0 = time.perf_counter(), time.process_time()
    first: tuple[float, float, int] | None = None
    last = db.last_batch_id()
    while True:
        if p.state.cursor >= last:  # every batch read: the idle flush closes the rest
            p.config = replace(p.config, idle_flush_s=0.0)
        p.step()
        n = int(p.state.counts.get("packets", 0))  # packets tracked so far
        if first is None and n > 0:  # (the device models and scorer tables built)
            first = (time.perf_counter() - w0, time.process_time() - c0, n)
        if p.state.cursor >= last and p.state.flushed and not p._unsaved:
            break  # every packet tracked, every estimate committed
        if time.perf_counter() - w0 > 3600:
            raise RuntimeError(f"{variant}: the pipeline did not finish in 1 h")
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    ck = db.load_checkpoint(cfg.partition_key)
    w1, c1, n1 = first or (0.0, 0.0, 0)
    if n1 >= n_packets:  # a tiny run tracked everything in its first step: all of it counts
        w1, c1, n1 = 0.0, 0.0, 0
    tracked = int(p.state.counts.get("packets", 0))
    if tracked != n_packets:
        raise RuntimeError(f"{variant}: {tracked} packets tracked of {n_packets} sent")
    out = {
        "method": variant,
        "packets": n_packets,
        "coverage": len(db.estimates(limit=10**7)) / n_packets,
        "packets_per_s": (n_packets - n1) / max(wall - w1, 1e-9),
        "packets_per_cpu_s": (n_packets - n1) / max(cpu - c1, 1e-9),
        "total_s": wall,
        "memory_growth_mb": _status_mb("VmHWM") - mem0,
        "checkpoint_mb": (len(ck[1]) if ck is not None else 0) / 1e6,
    }
    db.close()
    return out


def main(argv: list[str] | None = None) -> int:
    from radiopose.scripting import check_output, non_negative_int, positive_float, positive_int

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=positive_int, nargs="+", default=[10, 50])
    ap.add_argument("--interval-ms", type=positive_float, default=100.0)
    ap.add_argument("--duration-s", type=positive_float, default=20.0)
    ap.add_argument("--seed", type=non_negative_int, default=424242)
    ap.add_argument(
        "--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS),
        help="rows to run (full first: the ratio's baseline)",
    )  # fmt: skip
    ap.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    a = ap.parse_args(argv)
    if a.markdown is not None:
        check_output(ap, "--markdown", files=[a.markdown])
    cols = ["devices", "method", "offered_per_s", "packets", "coverage", "packets_per_s",
            "ratio_vs_full", "packets_per_cpu_s", "memory_growth_mb", "checkpoint_mb"]  # fmt: skip
    fmt = {"offered_per_s": ".0f", "packets_per_s": ".0f", "ratio_vs_full": ".2f",
           "packets_per_cpu_s": ".0f", "memory_growth_mb": ".1f",
           "checkpoint_mb": ".2f"}  # fmt: skip
    lines = [
        f"Machine: `{machine()}`",
        "",
        f"Live pipeline, {a.interval_ms:g} ms between one device's packets, "
        f"{a.duration_s:g} s of trace, seed {a.seed} (`python -m benchmarks devices "
        + " ".join(sys.argv[1:] if argv is None else argv)
        + "`):",
        "",
    ]
    table_rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="radiopose-devices-") as tmp_name:
        tmp = Path(tmp_name)
        for n in a.devices:
            site, frames, n_packets = scene(n, a.interval_ms, a.duration_s, a.seed)
            site_dir = tmp / f"site-{n}"
            write_site(site, site_dir)
            bs = batches(frames)
            rows = []
            for v in a.variants:
                row = run_apart(site_dir, tmp / f"{n}-{v.replace(' ', '_')}.db", bs, n_packets, v)
                row.update(devices=n, offered_per_s=n * 1000.0 / a.interval_ms)
                rows.append(row)
                print(f"{n} devices: {row}", file=sys.stderr, flush=True)
            base = next((r["packets_per_s"] for r in rows if r["method"] == "full"), None)
            for r in rows:
                r["ratio_vs_full"] = r["packets_per_s"] / base if base else float("nan")
                r["coverage"] = f"{100 * r['coverage']:.1f} %"
                table_rows.append({c: r[c] for c in cols})
    return emit(lines + table(table_rows, fmt), None if a.markdown is None else str(a.markdown))


if __name__ == "__main__":
    from radiopose.scripting import run_script

    raise SystemExit(run_script(main))
