"""Why one accuracy run locks onto a wrong pose: truth versus best candidate.

For one seed of the standard scenario (default 1006, the outlier of
docs/accuracy.md at σ = 0.5 dB), prints for every 20th packet the truth, the
best candidate (compiled kernel, top-100) with its MSE, the MSE of the grid
candidate nearest the truth and that candidate's rank among the top 100.
Usage: ``python scripts/mirror_diagnosis.py [SEED] [SIGMA_DB] [--packets N] [--quick]``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from radiopose.likelihood import candidate_space, exact_mse_db2
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets
from radiopose.scripting import (
    non_negative_int,
    positive_float,
    positive_int,
    run_script,
    usage_errors,
)
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.units import angle_diff_deg


def diagnose(
    seed: int = 1006, sigma_db: float = 0.5, n_packets: int = 100, quick: bool = False
) -> None:
    """Print truth versus best candidate for every 20th of the first ``n_packets`` packets."""
    base = ScenarioConfig.smoke() if quick else ScenarioConfig()
    sim = simulate(replace(base, noise_db=sigma_db), seed=seed)
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    scorer = ShiftScorer(space)
    packets = group_packets(sim.packets)
    for i in range(0, min(n_packets, len(packets)), 20):
        heard = space.heard(packets[i])
        top = scorer.score_heard(heard, 100)
        p_true = sim.truth.position_m[i]
        az_true = sim.truth.orientation_deg[i, 0]
        pos = int(np.argmin(np.linalg.norm(space.positions_m - p_true, axis=1)))
        ori = int(np.argmin(np.abs(angle_diff_deg(space.orientations_deg[:, 0], az_true))))
        nearest = np.array([pos * space.n_orientations + ori])
        mse_true = float(exact_mse_db2(space, heard, nearest)[0])
        far = np.linalg.norm(space.candidate_positions_m(top.candidate_idx) - p_true, axis=1) > 5.0
        rank = int(np.sum(top.mse_db2 < mse_true))
        best_p = space.candidate_positions_m(top.candidate_idx[:1])[0]
        best_az = space.candidate_orientations_deg(top.candidate_idx[:1])[0, 0]
        print(
            f"packet {i}: truth ({p_true[0]:.2f}, {p_true[1]:.2f}) m az {az_true:.1f}°, "
            f"nearest-grid MSE {mse_true:.3f} dB² (rank {rank if rank < 100 else '>100'}); "
            f"best ({best_p[0]:.1f}, {best_p[1]:.1f}) m az {best_az:.0f}° "
            f"MSE {top.mse_db2[0]:.3f} dB²; {int(far.sum())} of the top 100 > 5 m from the truth"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seed", type=non_negative_int, nargs="?", default=1006)
    ap.add_argument("sigma_db", type=positive_float, nargs="?", default=0.5, help="RSS noise σ, dB")
    ap.add_argument("--packets", type=positive_int, default=100, help="first packets to look at")
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    args = ap.parse_args(argv)
    with usage_errors(ap):  # σ within the scenario's range, before the simulation
        replace(ScenarioConfig(), noise_db=args.sigma_db).validate()
    diagnose(args.seed, args.sigma_db, args.packets, args.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
