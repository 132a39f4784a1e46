"""The ``filter`` beside ``full`` on the shipped experiments' conditions (a few runs
each) → a table for ``docs/filter.md``.

Scenarios (standard scenario at σ = 1 dB unless said, seeds that no test uses):
packet loss (each receiver misses 30 % of the packets), 3 receivers, periodic
(hand-held) rotation and rotation beyond the paper's bound (450–900 °/s), as in
``src/radiopose/evaluate/experiments/*.toml``, and a gap of two minutes after
the first second (the filter re-acquires). ``filter`` is offline (1 s lag).

Usage::

    python scripts/filter_scenarios.py [--seeds 3] [--first-seed 1000]
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import replace

import numpy as np

from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.packets import Packets
from radiopose.scripting import non_negative_int, positive_int, run_script
from radiopose.simulate import MotionConfig, ScenarioConfig, Simulation, simulate

SCENARIOS: dict[str, ScenarioConfig] = {
    "standard (σ = 1 dB)": ScenarioConfig(noise_db=1.0),
    "30 % packet loss": ScenarioConfig(noise_db=1.0, loss_fraction=0.3),
    "3 receivers": ScenarioConfig(noise_db=1.0, n_receivers=3),
    "periodic rotation": ScenarioConfig(noise_db=1.0, motion=MotionConfig(rotation="periodic")),
    "rotation 450–900 °/s": ScenarioConfig(noise_db=1.0, motion=MotionConfig(rotation="fast")),
    "gap of 2 min at 1 s": ScenarioConfig(noise_db=1.0),
}


def _gapped(sim: Simulation) -> Simulation:
    """Every packet from 1 s on arrives 120 s later (truth shifted alike)."""
    p, tr = sim.packets, sim.truth
    shift = np.where(p.timestamp_s >= 1.0, 120.0, 0.0)
    packets = Packets(p.packet_id, p.timestamp_s + shift, p.transmitter, p.receiver_id, p.rss_dbm)
    t = tr.timestamp_s + np.where(tr.timestamp_s >= 1.0, 120.0, 0.0)
    return replace(sim, packets=packets, truth=replace(tr, timestamp_s=t))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=positive_int, default=3, help="number of seeds")
    ap.add_argument("--first-seed", type=non_negative_int, default=1000)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    lines = [
        "| scenario | method | coverage | pos mean (m) | pos median | ori mean (°) | ori median |",
        "|:---|:---|---:|---:|---:|---:|---:|",
    ]
    for name, cfg in SCENARIOS.items():
        per: dict[str, list] = {"filter": [], "full": []}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            sim = simulate(cfg, seed)
            scorer = build_scorer(sim, "numba")
            if name.startswith("gap"):
                sim = _gapped(sim)
            runs = run_methods(sim, ("filter", "full"), None, scorer)
            for m, r in runs.items():
                per[m].append(r)
                print(f"{name} seed {seed} {m}: pos {r.position_error_m.mean():.3f}", flush=True)
        for m, runs_ in per.items():
            pe = np.concatenate([r.position_error_m for r in runs_])
            oe = np.concatenate([r.orientation_error_deg for r in runs_])
            cov = sum(len(r.estimates) for r in runs_) / sum(r.n_packets for r in runs_)
            lines.append(
                f"| {name} | {m} | {100 * cov:.1f} % | {pe.mean():.3f} | {np.median(pe):.3f} | "
                f"{oe.mean():.2f} | {np.median(oe):.2f} |"
            )
    command = shlex.join(
        ["python", "scripts/filter_scenarios.py", *(sys.argv[1:] if argv is None else argv)]
    )
    lines += [
        "",
        f"Seeds {args.first_seed}–{args.first_seed + args.seeds - 1}, "
        f"{time.perf_counter() - t0:.0f} s (`{command}`).",
    ]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
