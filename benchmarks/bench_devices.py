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

``--paced`` runs the same scene in real time instead: each batch is stored
when its 0.1 s of trace has passed on the wall clock and the pipeline steps
with the server's :class:`~radiopose.server.live.LiveConfig` defaults (but the
method), as under ``radiopose serve``. Measured from ``--warm-s`` (default half
the trace, at most 10 s) to the trace's end, per method and ``N``:

* **bytes written per second** by the process (``wchar`` of ``/proc/self/io``:
  frames stored, output committed and checkpoints, SQLite's WAL included),
  per device, and the ratio to ``full``'s in the same run;
* **commits** and **checkpoint writes** per second, and the **CPU share** the
  process used (1.0 = one core busy);
* at the end: **latency** p50/p95 of the last 1,000 estimates (report
  arrival to estimate commit, as ``/health`` gives it) and the **backlog**
  (batches stored but not yet read: 0 keeps up).

Usage::

    python -m benchmarks devices [--devices 10 50] [--interval-ms 100]
        [--duration-s 20] [--seed 424242] [--paced [--warm-s S]] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import resource
import sys
import tempfile
import threading
import time
from collections.abc import Callable
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
    return [(r, bid, rows) for _end_s, r, bid, rows in timed_batches(frames)]


def timed_batches(
    frames: dict[str, list[tuple[int, str, str, float]]],
) -> list[tuple[float, str, str, list]]:
    """``(trace time at the batch's end s, receiver, batch id, frames)``, 0.1 s of
    trace each, in time order: an agent sends a batch when its 0.1 s is over."""
    out = []
    for r, rows in frames.items():
        rows = sorted(rows)
        k = np.array([(ns - EPOCH_NS) // round(BATCH_S * 1e9) for ns, *_ in rows])
        for i in np.unique(k):
            sel = np.flatnonzero(k == i)
            out.append(((int(i) + 1) * BATCH_S, r, f"{r}-{i}", [rows[j] for j in sel]))
    out.sort(key=lambda b: (b[0], b[1]))
    return out


def _status_mb(field: str) -> float:
    """``VmRSS`` or ``VmHWM`` (peak) of this process, MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_apart(fn: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any]:
    """``fn(*args)`` (:func:`run` or :func:`run_paced`) in a forked child of its
    own, so that each variant's memory and written bytes are measured from the
    same start (in one process a variant reuses what an earlier one freed). In
    process where this one may not fork (no fork here, or numba's OpenMP layer
    already launched, as in a test session)."""
    import multiprocessing

    from radiopose.filtering.forked import fork_available

    if not fork_available():
        return fn(*args)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        return pool.apply(fn, args)


def _written_bytes() -> int:
    """Bytes this process has handed to ``write``/``pwrite`` so far (``wchar`` of
    ``/proc/self/io``): its database's writes, whether or not the page cache has
    flushed them to the disk yet."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("wchar:"):
            return int(line.split()[1])
    raise RuntimeError("/proc/self/io has no wchar line (Linux only)")


def run_paced(
    site_dir: Path, db_path: Path, bs: list, n_packets: int, variant: str, warm_s: float
) -> dict[str, Any]:
    """Store each batch when its 0.1 s of trace is over on the wall clock (as
    the agents send them; a thread of its own, as the API is beside the
    pipeline, so a slow step delays no arrival) and step the pipeline with the
    server's defaults
    (:class:`LiveConfig` but the method), as ``radiopose serve`` does. Measured
    after ``warm_s`` s to the trace's end: bytes written per second, commits
    and checkpoint writes per second, the pipeline's CPU share; at the end:
    latency p50/p95 of the last 1,000 estimates and the batches not yet read."""
    method, tracker = VARIANTS[variant]
    db = Database(f"sqlite:///{db_path}")
    import_site_dir(db, site_dir)
    p = LivePipeline(db, LiveConfig(method=method, tracker=tracker))
    counts = {"commits": 0, "checkpoints": 0}
    commit = db.commit_step

    def counted(*args: Any, **kw: Any) -> None:  # state is the third argument
        counts["commits"] += 1
        counts["checkpoints"] += (args[2] if len(args) > 2 else kw.get("state")) is not None
        commit(*args, **kw)

    db.commit_step = counted  # type: ignore[method-assign]
    end_s, mark = bs[-1][0], None
    t0 = time.perf_counter()

    def agents() -> None:  # the API's side: batches stored as they come, whatever the pipeline does
        feed = Database(f"sqlite:///{db_path}")
        for at_s, r, bid, rows in bs:
            time.sleep(max(0.0, at_s - (time.perf_counter() - t0)))
            feed.store_batch(r, bid, rows)
        feed.close()

    feeder = threading.Thread(target=agents, daemon=True)
    feeder.start()
    while (now := time.perf_counter() - t0) < end_s:
        if mark is None and now >= warm_s:
            mark = (now, time.process_time(), _written_bytes(), dict(counts))
        if p.step() == 0:
            time.sleep(0.01)
    feeder.join()
    if mark is None:
        raise RuntimeError(f"the trace ({end_s:g} s) is not longer than the warm-up ({warm_s:g} s)")
    span = time.perf_counter() - t0 - mark[0]
    lat = np.asarray(db.recent_latencies_s(1_000))
    ck = db.load_checkpoint(p.config.partition_key)
    out = {
        "method": variant,
        "packets": n_packets,
        "written_mb_per_s": (_written_bytes() - mark[2]) / span / 1e6,
        "commits_per_s": (counts["commits"] - mark[3]["commits"]) / span,
        "checkpoints_per_s": (counts["checkpoints"] - mark[3]["checkpoints"]) / span,
        "cpu_share": (time.process_time() - mark[1]) / span,
        "latency_p50_s": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "latency_p95_s": float(np.percentile(lat, 95)) if lat.size else float("nan"),
        "backlog_batches": db.last_batch_id() - p.state.cursor,
        "checkpoint_mb": (len(ck[1]) if ck is not None else 0) / 1e6,
    }
    db.close()
    return out


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
    ap.add_argument(
        "--paced", action="store_true",
        help="real time: batches stored as their trace time passes, the server's "
        "LiveConfig; disk writes, commits, latency and backlog instead of throughput",
    )  # fmt: skip
    ap.add_argument(
        "--warm-s", type=positive_float, default=None,
        help="--paced: seconds before the measurement starts (default: half the trace, "
        "at most 10)",
    )  # fmt: skip
    a = ap.parse_args(argv)
    if a.markdown is not None:
        check_output(ap, "--markdown", files=[a.markdown])
    if a.warm_s is not None and not a.paced:
        ap.error("--warm-s applies to --paced runs only")
    warm_s = min(10.0, a.duration_s / 2) if a.warm_s is None else a.warm_s
    if a.paced and warm_s >= a.duration_s:
        ap.error(f"--warm-s {warm_s:g} leaves nothing of a {a.duration_s:g} s trace to measure")
    if a.paced:
        cols = ["devices", "method", "offered_per_s", "written_mb_per_s",
                "written_kb_per_device_s", "written_vs_full", "commits_per_s",
                "checkpoints_per_s", "cpu_share", "latency_p50_s", "latency_p95_s",
                "backlog_batches", "checkpoint_mb"]  # fmt: skip
        fmt = {"offered_per_s": ".0f", "written_mb_per_s": ".2f", "written_kb_per_device_s": ".0f",
               "written_vs_full": ".2f", "commits_per_s": ".1f", "checkpoints_per_s": ".2f",
               "cpu_share": ".2f", "latency_p50_s": ".2f", "latency_p95_s": ".2f",
               "checkpoint_mb": ".2f"}  # fmt: skip
        what = f"real time, measured from {warm_s:g} s to the trace's end"
    else:
        cols = ["devices", "method", "offered_per_s", "packets", "coverage",
                "packets_per_s", "ratio_vs_full", "packets_per_cpu_s", "memory_growth_mb",
                "checkpoint_mb"]  # fmt: skip
        fmt = {"offered_per_s": ".0f", "packets_per_s": ".0f", "ratio_vs_full": ".2f",
               "packets_per_cpu_s": ".0f", "memory_growth_mb": ".1f",
               "checkpoint_mb": ".2f"}  # fmt: skip
        what = "all batches stored first, then stepped to the end"
    lines = [
        f"Machine: `{machine()}`",
        "",
        f"Live pipeline, {a.interval_ms:g} ms between one device's packets, "
        f"{a.duration_s:g} s of trace, seed {a.seed}, {what} (`python -m benchmarks devices "
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
            rows = []
            for v in a.variants:
                db_path = tmp / f"{n}-{v.replace(' ', '_').replace(',', '')}.db"
                if a.paced:
                    args = (site_dir, db_path, timed_batches(frames), n_packets, v, warm_s)
                    row = run_apart(run_paced, *args)
                else:
                    row = run_apart(run, site_dir, db_path, batches(frames), n_packets, v)
                row.update(devices=n, offered_per_s=n * 1000.0 / a.interval_ms)
                rows.append(row)
                print(f"{n} devices: {row}", file=sys.stderr, flush=True)
            key = "written_mb_per_s" if a.paced else "packets_per_s"
            base = next((r[key] for r in rows if r["method"] == "full"), None)
            for r in rows:
                ratio = r[key] / base if base else float("nan")
                if a.paced:
                    r["written_vs_full"] = ratio
                    r["written_kb_per_device_s"] = r["written_mb_per_s"] * 1e3 / n
                else:
                    r["ratio_vs_full"] = ratio
                    r["coverage"] = f"{100 * r['coverage']:.1f} %"
                table_rows.append({c: r[c] for c in cols})
    return emit(lines + table(table_rows, fmt), None if a.markdown is None else str(a.markdown))


if __name__ == "__main__":
    from radiopose.scripting import run_script

    raise SystemExit(run_script(main))
