"""Throughput and lag of the live pipeline at a 3-D site → docs/server.md ("3-D site").

Simulates the 3-D hand-held scenario (``radiopose simulate --pose 3d``: 20 m ×
20 m, receivers at mixed heights) and, as the baseline measured in the same
run, a 2-D scenario with the same receivers count, packet rate and candidate
steps (20 m, 0.25 m, 5°), writes one pcap per receiver (clock offsets ±0.2 s)
and feeds their frames to the live pipeline (:class:`radiopose.server.live.LivePipeline`
over a SQLite database, method ``filter``, live lag 0.25 s), in process:

* **throughput**: every batch stored first, then the pipeline steps until every
  packet's estimate is committed; packets per wall second and per CPU second
  of the pipeline after its first tracked packet (which pays for the device's
  model: the 2-D site scorer or the 3-D coarse table, reported apart as
  ``prepare_s``);
* **lag** (``--paced``): the frames are stored in real time, one batch per
  receiver every 0.1 s of trace (as the receiver agents send them), while the
  pipeline polls; report → estimate latency (``estimated_s − last_report_s``,
  what ``/health`` shows) p50/p95 over the estimates of the trace's second half
  (the clock calibration, the device's preparation and the backlog they leave
  excluded: run at least 20 s so that the pipeline has caught up by then).

Usage::

    python scripts/live_pose3d.py [--duration-s 10] [--interval-ms 20] [--receivers 6]
        [--seed 18300] [--size-m 20] [--paced] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.capture.records import FrameRecords, read_pcap
from radiopose.capture.writer import write_receiver_pcaps
from radiopose.scripting import (
    check_output,
    non_negative_int,
    positive_float,
    positive_int,
    run_script,
    usage_errors,
)
from radiopose.server.app import import_site_dir
from radiopose.server.db import Database
from radiopose.server.live import LiveConfig, LivePipeline
from radiopose.simulate import ScenarioConfig, Simulation, simulate
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

BATCH_S = 0.1
"""Trace seconds per batch of one receiver (the agents' batch interval)."""


def scene_config(
    kind: str, n_rx: int, interval_ms: float, duration_s: float, size_m: float = 20.0
) -> HandheldConfig | ScenarioConfig:
    """The configuration of :func:`scene`."""
    spacing_m = min(4.0, size_m / 3.0)
    if kind == "3d":
        return HandheldConfig(
            size_m=size_m, n_receivers=n_rx, interval_ms=interval_ms, duration_s=duration_s,
            min_receiver_spacing_m=spacing_m,
        )  # fmt: skip
    return ScenarioConfig(
        size_m=size_m, step_m=0.25, azimuth_step_deg=5.0, n_receivers=n_rx,
        interval_ms=interval_ms, duration_s=duration_s, min_receiver_spacing_m=spacing_m,
    )  # fmt: skip


def scene(
    kind: str, n_rx: int, interval_ms: float, duration_s: float, seed: int, size_m: float = 20.0
) -> Simulation:
    """The 3-D hand-held scenario or its 2-D baseline (``size_m`` square, 0.25 m, 5°)."""
    cfg = scene_config(kind, n_rx, interval_ms, duration_s, size_m)
    if isinstance(cfg, HandheldConfig):
        return simulate_handheld(cfg, seed=seed)
    return simulate(cfg, seed=seed)


def batches(frames: dict[str, FrameRecords]) -> list[tuple[float, str, str, list[Any]]]:
    """``(trace time of the last frame, receiver, batch id, rows)`` in time order."""
    out = []
    t0 = min(int(f.timestamp_ns.min()) for f in frames.values() if len(f))
    for r, f in frames.items():
        t = (f.timestamp_ns - t0) / 1e9
        k = np.floor(t / BATCH_S).astype(int)
        for i in np.unique(k):
            sel = np.flatnonzero(k == i)
            g = f.take(sel)
            rows = list(zip(g.timestamp_ns.tolist(), g.frame_sha256, g.transmitter,
                            g.rss_dbm.tolist(), strict=True))  # fmt: skip
            out.append((float((i + 1) * BATCH_S), r, f"{r}-{i}", rows))
    out.sort(key=lambda b: (b[0], b[1]))
    return out


def _db(tmp: Path, name: str, site_dir: Path) -> Database:
    db = Database(f"sqlite:///{tmp / name}")
    import_site_dir(db, site_dir)
    return db


def live_config(**kw: Any) -> LiveConfig:
    base = {"method": "filter", "live_lag_s": 0.25, "calibration_s": 1.0, "poll_s": 0.02}
    return LiveConfig(**{**base, **kw})


def throughput(db: Database, bs: list[tuple[float, str, str, list[Any]]], n_packets: int) -> dict:
    for _t, r, bid, rows in bs:
        db.store_batch(r, bid, rows)
    p = LivePipeline(db, live_config(idle_flush_s=1e6, batches_per_step=20))
    steps: list[tuple[float, float, int]] = []  # (wall, cpu, packets tracked) after each step
    w0, c0 = time.perf_counter(), time.process_time()
    while p.state.cursor < db.last_batch_id():
        p.step()
        steps.append((time.perf_counter() - w0, time.process_time() - c0, _tracked(p)))
    p.config = replace(p.config, idle_flush_s=0.0)
    while len(db.estimates(limit=10**7)) < n_packets:
        p.step()
        steps.append((time.perf_counter() - w0, time.process_time() - c0, _tracked(p)))
        if steps[-1][0] > 3600:
            raise RuntimeError("the pipeline did not answer every packet")
    first = next(i for i, s in enumerate(steps) if s[2] > 0)  # the device's model built here
    w1, c1, n1 = steps[first]
    wall, cpu, n = steps[-1]
    return {
        "packets": n,
        "prepare_s": w1 - (steps[first - 1][0] if first else 0.0),
        "packets_per_s": (n - n1) / max(wall - w1, 1e-9),
        "packets_per_cpu_s": (n - n1) / max(cpu - c1, 1e-9),
        "total_s": wall,
    }


def _tracked(p: LivePipeline) -> int:
    return int(p.state.counts.get("packets", 0))


def paced(db: Database, bs: list[tuple[float, str, str, list[Any]]], n_packets: int) -> dict:
    """Store the batches in real time while the pipeline polls; latency percentiles."""
    start = time.monotonic()

    def feed() -> None:
        for t, r, bid, rows in bs:
            wait = start + t - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            db.store_batch(r, bid, rows)

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    p = LivePipeline(db, live_config(idle_flush_s=0.5))
    end = start + bs[-1][0] + 600
    while time.monotonic() < end:
        if p.step() == 0:
            if not th.is_alive() and len(db.estimates(limit=10**7)) >= n_packets:
                break
            time.sleep(p.config.poll_s)
    th.join()
    est = db.estimates(limit=10**7)
    t = np.array([e["timestamp_s"] for e in est])
    lat = np.array([e["estimated_s"] - e["last_report_s"] for e in est])
    keep = t >= t.min() + 0.5 * (t.max() - t.min())
    return {
        "estimates": len(est),
        "latency_p50_ms": 1000 * float(np.percentile(lat[keep], 50)),
        "latency_p95_ms": 1000 * float(np.percentile(lat[keep], 95)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=positive_float, default=10.0)
    ap.add_argument("--interval-ms", type=positive_float, default=20.0)
    ap.add_argument("--receivers", type=positive_int, default=6)
    ap.add_argument("--seed", type=non_negative_int, default=18300)
    ap.add_argument("--size-m", type=positive_float, default=20.0, help="side of both sites, m")
    ap.add_argument("--paced", action="store_true", help="also measure the lag in real time")
    ap.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = ap.parse_args(argv)
    if a.out is not None:
        check_output(ap, "--out", files=[a.out])
    with usage_errors(ap):  # both sites' ranges (3 receivers at least), before the runs
        for kind in ("2d", "3d"):
            scene_config(kind, a.receivers, a.interval_ms, a.duration_s, a.size_m).validate()
    rows = []
    with tempfile.TemporaryDirectory(prefix="radiopose-live3d-") as tmp_name:
        tmp = Path(tmp_name)
        for kind in ("2d", "3d"):
            sim = scene(kind, a.receivers, a.interval_ms, a.duration_s, a.seed, a.size_m)
            root = tmp / kind
            sim.write(root)
            pc = write_receiver_pcaps(
                sim.packets, root / "pcaps", rng=np.random.default_rng(a.seed),
                clock_offset_s={"rx2": 0.2, "rx3": -0.2}, jitter_s=2e-6, epoch_s=1000.0,
            )  # fmt: skip
            frames = {r: read_pcap(path, r).frames for r, path in pc.paths.items()}
            bs = batches(frames)
            n_packets = len(set(sim.packets.packet_id))
            row: dict[str, Any] = {"site": kind}
            row.update(throughput(_db(tmp, f"{kind}-t.db", root / "site"), bs, n_packets))
            if a.paced:
                row.update(paced(_db(tmp, f"{kind}-p.db", root / "site"), bs, n_packets))
            rows.append(row)
            print(f"{kind}: {row}", file=sys.stderr, flush=True)
    base = rows[0]["packets_per_s"]
    head = ["site", "packets", "prepare_s", "packets_per_s", "ratio_vs_2d", "packets_per_cpu_s"]
    if a.paced:
        head += ["latency_p50_ms", "latency_p95_ms"]
    lines = [
        f"Live pipeline, method filter (lag 0.25 s), {a.receivers} receivers, a packet every "
        f"{a.interval_ms:g} ms for {a.duration_s:g} s, seed {a.seed}:",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for r in rows:
        r["ratio_vs_2d"] = r["packets_per_s"] / base
        cells = []
        for h in head:
            v = r[h]
            cells.append(v if isinstance(v, str) else f"{v:.0f}" if abs(v) >= 10 else f"{v:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines)
    print(text)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
