"""Full-grid versus bounded search of the `full` pipeline on the accuracy seeds.

Runs ``locate(..., "full")`` with ``TrackerConfig()`` and with
``TrackerConfig(search="bounded")`` (compiled kernel) on the standard scenario,
seeds 1000–1009, σ = 0.5 and 3 dB, and prints pooled mean/median orientation
error, mean position error and mean coverage for each (docs/pipeline.md,
"Decisions"). Usage: ``python scripts/bounded_search_accuracy.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from radiopose.evaluate.scoring import match_truth, orientation_error_deg
from radiopose.likelihood import candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import TrackerConfig, locate


def main(seeds: range = range(1000, 1010), sigmas: tuple[float, ...] = (0.5, 3.0)) -> None:
    configs = {"full grid": TrackerConfig(), "bounded": TrackerConfig(search="bounded")}
    for sigma in sigmas:
        acc: dict[str, list] = {name: [] for name in configs}
        for seed in seeds:
            sim = simulate(replace(ScenarioConfig(), noise_db=sigma), seed=seed)
            tx = sim.site.devices[0].transmitter
            space = candidate_space(sim.site, tx)
            n = len(group_packets(sim.packets))
            for name, cfg in configs.items():
                est = locate(sim.site, sim.packets, "full", cfg, None, {tx: ShiftScorer(space)})
                idx = match_truth(sim.truth, est.estimates)
                o = orientation_error_deg(
                    est.estimates.orientation_deg, sim.truth.orientation_deg[idx]
                )
                p = np.linalg.norm(est.estimates.position_m - sim.truth.position_m[idx], axis=1)
                acc[name].append((o, p, len(est.estimates) / n))
        for name, rows in acc.items():
            o = np.concatenate([r[0] for r in rows])
            p = np.concatenate([r[1] for r in rows])
            cov = np.mean([r[2] for r in rows])
            print(
                f"σ {sigma:g} dB, {name}: orientation mean {o.mean():.1f}° median "
                f"{np.median(o):.1f}°, position mean {p.mean():.2f} m, coverage {100 * cov:.1f} %"
            )


if __name__ == "__main__":
    main()
