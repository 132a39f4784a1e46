"""Likelihood and pipeline throughput, as ratios against the reference in the same run.

Sections (``python benchmarks/bench_likelihood.py [--quick] [--markdown FILE]``):

1. Full-grid scoring + top-k (k = 100) on the paper's standard scenario
   (201 × 201 positions × 360 azimuths × 4 receivers): the reference scorer,
   the vectorised numpy scorer, and the compiled shift kernel cold (no hint
   from a previous packet) and warm (consecutive packets of one track).
   Reported: ms/packet, speed-up over the reference, nominal GFLOP/s
   (2 FLOP per candidate-receiver term: one subtraction, one multiply-add).
2. The whole pipeline (``full`` method, clustering and models included) over a
   2,000-packet trace: batch ``locate`` and the streaming ``Tracker``.
3. Scaling of the compiled kernel: grid size, receivers, azimuth step and 3-D
   orientation candidates (pitch × roll lists).
4. Peak memory of a process that localises the standard scenario.
5. Start-up: a fresh process loads a site from disk, prepares the device's
   tables and scores a first packet; run twice (the second run finds numba's
   compiled kernels in its on-disk cache).

Every number is measured in this run on this machine; nothing is tuned to it.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from benchmarks.common import machine
from radiopose.geometry import orientation_matrices
from radiopose.likelihood import ReferenceScorer, TableScorer, candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.site import OrientationGrid

TX = "02:00:00:00:00:01"


def per_packet_s(fn: Callable[[object], object], items: list, repeat: int = 1) -> float:
    """Median over ``repeat`` passes of the mean seconds per item."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for it in items:
            fn(it)
        times.append((time.perf_counter() - t0) / len(items))
    return float(np.median(times))


def scenario(seed: int = 101, **kw):
    cfg = replace(ScenarioConfig(), **kw)
    return simulate(cfg, seed=seed)


def section_scoring(quick: bool) -> list[dict]:
    sim = scenario(duration_s=1.0, noise_db=1.0)
    space = candidate_space(sim.site, TX)
    heard = [space.heard(p) for p in group_packets(sim.packets)]
    terms = space.n_candidates * space.n_receivers
    rows = []
    ref = ReferenceScorer(space)
    t_ref = per_packet_s(lambda h: ref.score_heard(h, 100), heard[: 1 if quick else 2])
    rows.append(("reference (float64, exhaustive)", t_ref))
    if not quick:
        tab = TableScorer(space)
        tab.score_heard(heard[0], 100)
        rows.append(
            (
                "numpy (float32 table + exact rescoring)",
                per_packet_s(lambda h: tab.score_heard(h, 100), heard[1:6]),
            )
        )
    fast = ShiftScorer(space)
    fast.score_heard(heard[0], 100)  # compile / load from cache

    def cold(h):
        fast._hint = np.empty(0, np.int64)
        return fast.score_heard(h, 100)

    rows.append(
        (
            "numba shift kernel, cold (first packet of a track)",
            per_packet_s(cold, heard[:40], repeat=3),
        )
    )
    plain = ShiftScorer(space, prune=False)
    plain.score_heard(heard[0], 100)
    rows.append(
        (
            "numba shift kernel, no pruning",
            per_packet_s(lambda h: plain.score_heard(h, 100), heard[:40], repeat=3),
        )
    )
    rows.append(
        (
            "numba shift kernel, warm (streaming)",
            per_packet_s(lambda h: fast.score_heard(h, 100), heard[:200], repeat=3),
        )
    )
    out = []
    for name, t in rows:
        out.append(
            {
                "scorer": name,
                "ms_per_packet": 1e3 * t,
                "speedup_vs_reference": t_ref / t,
                "nominal_gflops": 2.0 * terms / t / 1e9,
            }
        )
    return out


def section_pipeline(quick: bool) -> list[dict]:
    from radiopose.tracker import Tracker, TrackerConfig, locate

    n = 400 if quick else 2000
    sim = scenario(seed=202, duration_s=n * 0.005, noise_db=1.0)
    cfg = TrackerConfig(kernel="numba")
    space = candidate_space(sim.site, TX)
    scorer = ShiftScorer(space)
    scorer.score_heard(space.heard(group_packets(sim.packets)[0]), 100)
    out = []
    t0 = time.perf_counter()
    res = locate(sim.site, sim.packets, "full", cfg, scorers={TX: scorer})
    t_batch = time.perf_counter() - t0
    out.append(
        {
            "mode": "batch locate",
            "packets": n,
            "seconds": t_batch,
            "packets_per_s": n / t_batch,
            "estimates": len(res.estimates),
        }
    )
    bounded = replace(cfg, search="bounded")
    t0 = time.perf_counter()
    res_b = locate(sim.site, sim.packets, "full", bounded, scorers={TX: ShiftScorer(space)})
    t_b = time.perf_counter() - t0
    out.append(
        {
            "mode": "batch locate, bounded search",
            "packets": n,
            "seconds": t_b,
            "packets_per_s": n / t_b,
            "estimates": len(res_b.estimates),
        }
    )
    tracker = Tracker(sim.site, "full", cfg, scorers={TX: ShiftScorer(space)})
    obs = group_packets(sim.packets)
    t0 = time.perf_counter()
    n_est = 0
    for o in obs:
        est, _ = tracker.update(o)
        n_est += est is not None
    t_stream = time.perf_counter() - t0
    out.append(
        {
            "mode": "streaming Tracker.update",
            "packets": n,
            "seconds": t_stream,
            "packets_per_s": n / t_stream,
            "estimates": n_est,
        }
    )
    return out


def _scaling_case(label: str, sim, orient: OrientationGrid | None, n_packets: int) -> dict:
    space = candidate_space(sim.site, TX)
    if orient is not None:
        o = orient.orientations_deg()
        space = replace(space, orientations_deg=o, rotations=orientation_matrices(*o.T))
    scorer = ShiftScorer(space)
    heard = [space.heard(p) for p in group_packets(sim.packets)[:n_packets]]
    scorer.score_heard(heard[0], 100)
    t_warm = per_packet_s(lambda h: scorer.score_heard(h, 100), heard)
    plain = ShiftScorer(space, prune=False)
    t_plain = per_packet_s(lambda h: plain.score_heard(h, 100), heard[: max(3, n_packets // 4)])
    return {
        "case": label,
        "candidates": space.n_candidates,
        "receivers": space.n_receivers,
        "ms_per_packet_warm": 1e3 * t_warm,
        "ms_per_packet_unpruned": 1e3 * t_plain,
        "ns_per_candidate_unpruned": 1e9 * t_plain / space.n_candidates,
        "table_mb": scorer.nbytes / 1e6,
    }


def section_scaling(quick: bool) -> list[dict]:
    n = 10 if quick else 30
    out = []
    for size, step in ((5.0, 0.1), (10.0, 0.1), (20.0, 0.1), (40.0, 0.1)):
        if quick and size > 20:
            continue
        sim = scenario(
            seed=303,
            size_m=size,
            step_m=step,
            duration_s=0.2,
            min_receiver_spacing_m=min(4.0, size / 4),
        )
        grid = round(size / step) + 1
        out.append(_scaling_case(f"grid {grid}x{grid}", sim, None, n))
    for n_rx in (3, 4, 5, 6):
        sim = scenario(seed=304, n_receivers=n_rx, duration_s=0.2)
        out.append(_scaling_case(f"{n_rx} receivers", sim, None, n))
    sim = scenario(seed=305, azimuth_step_deg=0.5, duration_s=0.2)
    out.append(_scaling_case("azimuth step 0.5 deg", sim, None, n))
    sim3 = scenario(seed=306, size_m=10.0, duration_s=0.2, min_receiver_spacing_m=3.0)
    out.append(_scaling_case("10x10 m, 1 deg, pitch=roll=0", sim3, OrientationGrid(1.0), n))
    for k in (5, 9):
        lst = tuple(np.linspace(-40, 40, k))
        out.append(
            _scaling_case(
                f"10x10 m, 1 deg x {k} pitch x {k} roll",
                sim3,
                OrientationGrid(1.0, lst, lst),
                max(3, n // 5),
            )
        )
    return out


def section_memory() -> dict:
    code = (
        "import resource, numpy as np\n"
        "from radiopose.simulate import simulate, ScenarioConfig\n"
        "from radiopose.likelihood import candidate_space\n"
        "from radiopose.likelihood.compiled import ShiftScorer\n"
        "from radiopose.tracker import locate, TrackerConfig\n"
        "sim = simulate(ScenarioConfig(duration_s=0.5), seed=404)\n"
        "sp = candidate_space(sim.site, '02:00:00:00:00:01')\n"
        "r = locate(sim.site, sim.packets, 'full', TrackerConfig(kernel='numba'),"
        " scorers={'02:00:00:00:00:01': ShiftScorer(sp)})\n"
        "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
        "print(int(hwm[0].split()[1]) if hwm else"
        " resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    )
    # VmHWM, not ru_maxrss: Linux carries ru_maxrss across exec, so a child of this
    # (large) benchmark process would report the parent's peak.
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return {"peak_rss_mb": int(res.stdout.strip().splitlines()[-1]) / 1024.0}


_STARTUP_CODE = """
import sys, time
t0 = time.perf_counter()
from radiopose.likelihood import candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets, read_packets_csv
from radiopose.site import load_site
t1 = time.perf_counter()
site = load_site(sys.argv[1])
pk = group_packets(read_packets_csv(sys.argv[2]))
t2 = time.perf_counter()
space = candidate_space(site, site.devices[0].transmitter)
scorer = ShiftScorer(space)
t3 = time.perf_counter()
scorer.score_heard(space.heard(pk[0]), 100)
t4 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2, t4 - t3)
"""


def section_startup() -> list[dict]:
    """A fresh process: imports, site load, table preparation, first packet (s)."""
    import tempfile
    from pathlib import Path

    from radiopose.packets import write_packets_csv
    from radiopose.site import write_site

    sim = scenario(seed=505, duration_s=0.05)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        site_dir = Path(tmp) / "site"
        write_site(sim.site, site_dir)
        packets = Path(tmp) / "packets.csv"
        write_packets_csv(sim.packets, packets)
        for run in ("first", "second"):
            t0 = time.perf_counter()
            res = subprocess.run(
                [sys.executable, "-c", _STARTUP_CODE, str(site_dir), str(packets)],
                capture_output=True,
                text=True,
                check=True,
            )
            wall = time.perf_counter() - t0
            imp, load, prep, first = (float(x) for x in res.stdout.split())
            out.append(
                {
                    "run": run,
                    "process_wall_s": wall,
                    "imports_s": imp,
                    "load_site_s": load,
                    "prepare_tables_s": prep,
                    "first_packet_s": first,
                }
            )
    return out


def markdown(results: dict) -> str:
    lines = ["## Machine", "", "```", json.dumps(results["machine"], indent=1), "```", ""]

    def table(rows: list[dict], fmt: dict[str, str]) -> None:
        keys = list(rows[0])
        lines.append("| " + " | ".join(keys) + " |")
        lines.append("|" + "---|" * len(keys))
        for r in rows:
            lines.append(
                "| "
                + " | ".join(
                    format(r[k], fmt.get(k, "")) if isinstance(r[k], float) else str(r[k])
                    for k in keys
                )
                + " |"
            )
        lines.append("")

    lines += ["## 1. Full-grid scoring + top-100, standard scenario", ""]
    table(
        results["scoring"],
        {"ms_per_packet": ".2f", "speedup_vs_reference": ".0f", "nominal_gflops": ".1f"},
    )
    if "pipeline" in results:
        lines += ["## 2. Whole `full` pipeline", ""]
        table(results["pipeline"], {"seconds": ".2f", "packets_per_s": ".0f"})
    lines += ["## 3. Scaling of the compiled kernel", ""]
    table(
        results["scaling"],
        {
            "ms_per_packet_warm": ".2f",
            "ms_per_packet_unpruned": ".2f",
            "ns_per_candidate_unpruned": ".3f",
            "table_mb": ".1f",
        },
    )
    lines += [
        "## 4. Peak memory",
        "",
        f"{results['memory']['peak_rss_mb']:.0f} MB "
        "(whole process: standard scenario, `full` pipeline, compiled kernel)",
        "",
    ]
    if "startup" in results:
        lines += ["## 5. Start-up of a fresh process (standard scenario site)", ""]
        table(results["startup"], {k: ".3f" for k in results["startup"][0] if k != "run"})
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer packets and cases")
    ap.add_argument("--markdown", help="also write the tables to this Markdown file")
    ap.add_argument("--skip-pipeline", action="store_true")
    args = ap.parse_args(argv)
    results: dict = {"machine": machine()}
    results["scoring"] = section_scoring(args.quick)
    if not args.skip_pipeline:
        results["pipeline"] = section_pipeline(args.quick)
    results["scaling"] = section_scaling(args.quick)
    results["memory"] = section_memory()
    results["startup"] = section_startup()
    results["machine"]["peak_rss_this_process_mb"] = (
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    )
    text = markdown(results)
    print(text)
    if args.markdown:
        with open(args.markdown, "w", encoding="utf-8") as fh:
            fh.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
