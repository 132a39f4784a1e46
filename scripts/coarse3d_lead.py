"""A lead for issue 18: a whole-file coarse HMM in 3-D, against the 3-D pipeline.

docs/pose3d.md, "A lead measured: a whole-file coarse HMM in 3-D". For each seed
the hand-held scenario is simulated (6 receivers, σ 1 dB, 4 s by default); the
3-D filter's acquisition grid (:class:`radiopose.filtering.particle3d.CoarseGrid`)
scores every 0.1 s window's median RSS at offset 0 (``Σ w (y − E)² / 2``,
``w = n / ((π/2) σ² + σ_g² n)``), height, pitch and roll are minimised per
(x, y, azimuth) cell, and the Viterbi path over (x, y, azimuth) (a walk of
0.35 m and 9° per window; since 2026-11-28 computed by
:mod:`radiopose.filtering.coarse3d`, which the optional refinement start
``refine_coarse_path`` uses: the same path) is compared with the truth at the
windows' times, beside the default offline ``locate``'s errors (unless
``--no-pipeline``).

Usage (tuning seeds only)::

    python scripts/coarse3d_lead.py --seeds 7104 7110-7124 [--no-pipeline]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from radiopose.evaluate.pose3d import axis_errors
from radiopose.filtering import particle3d
from radiopose.filtering.coarse3d import CoarseScorer, read_windows, window_path
from radiopose.likelihood import candidate_space
from radiopose.packets import group_packets
from radiopose.scripting import positive_float, positive_int, run_script, usage_errors
from radiopose.simulate import seed_range
from radiopose.simulate.handheld import HandheldConfig, Simulation, simulate_handheld
from radiopose.tracker import TrackerConfig, locate


def _azimuth_error_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def coarse_path(
    sim: Simulation, sigma_db: float, grid_sigma_db: float = 1.5
) -> tuple[np.ndarray, np.ndarray]:
    """The windows' mean times (s) and the Viterbi path's x, y (m), azimuth (°)
    at offset 0 (:func:`radiopose.filtering.coarse3d.window_path`, the tilts
    and height minimised per cell)."""
    obs = group_packets(sim.packets)
    space = candidate_space(sim.site, obs[0].transmitter)
    model = particle3d.FilterModel3d.build3d(sim.site, space, particle3d.Pose3dConfig())
    assert model.coarse is not None
    t = np.array([o.timestamp_s for o in obs])
    wins = read_windows(t, [space.heard(o) for o in obs], sigma_db, grid_sigma_db, 0.1)
    sc = CoarseScorer(model.coarse)
    cells, _ = window_path(sc, wins, 0.0, 0.35, 9.0)
    xs, ys, azs = sc.axes[3], sc.axes[4], sc.axes[2]
    path = np.column_stack([xs[cells[:, 0]], ys[cells[:, 1]], azs[cells[:, 2]]])
    return np.array([w.time_s for w in wins]), path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--seeds", type=seed_range, nargs="+", default=[range(7104, 7105)],
        help="seeds or ranges FIRST-LAST",
    )  # fmt: skip
    ap.add_argument("--receivers", type=positive_int, default=6)
    ap.add_argument("--sigma", type=positive_float, default=1.0, help="simulated σ, dB")
    ap.add_argument("--duration-s", type=positive_float, default=4.0)
    ap.add_argument("--no-pipeline", action="store_true", help="the coarse path only")
    args = ap.parse_args(argv)
    with usage_errors(ap):  # the scenario's ranges (3 receivers at least), before the runs
        replace(HandheldConfig(), n_receivers=args.receivers, noise_db=args.sigma,
                duration_s=args.duration_s).validate()  # fmt: skip
    print("| seed | pipeline: position m / rotation ° (azimuth °) | coarse path: position m / "
          "azimuth ° (max) | CPU s (pipeline, path) |")  # fmt: skip
    print("|---|---|---|---|")
    for seed in (s for r in args.seeds for s in r):
        cfg = replace(HandheldConfig(), n_receivers=args.receivers, noise_db=args.sigma,
                      duration_s=args.duration_s)  # fmt: skip
        sim = simulate_handheld(cfg, seed=seed)
        t0 = time.process_time()
        pipe = "–"
        if not args.no_pipeline:
            e = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter",
                                              TrackerConfig()).estimates)  # fmt: skip
            pipe = (f"{e.position_m.mean():.2f} / {e.rotation_deg.mean():.1f} "
                    f"({e.azimuth_deg.mean():.1f})")  # fmt: skip
        t1 = time.process_time()
        t, path = coarse_path(sim, args.sigma)
        t2 = time.process_time()
        i = np.searchsorted(sim.truth.timestamp_s, t).clip(0, sim.truth.timestamp_s.size - 1)
        pos_err = np.linalg.norm(path[:, :2] - sim.truth.position_m[i, :2], axis=1)
        az_err = _azimuth_error_deg(path[:, 2], sim.truth.orientation_deg[i, 0])
        print(f"| {seed} | {pipe} | {pos_err.mean():.2f} / {az_err.mean():.1f} "
              f"({az_err.max():.0f}) | {t1 - t0:.1f}, {t2 - t1:.1f} |", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
