"""A lead for issue 18: a whole-file coarse HMM in 3-D, against the 3-D pipeline.

docs/pose3d.md, "A lead measured: a whole-file coarse HMM in 3-D". For each seed
the hand-held scenario is simulated (6 receivers, σ 1 dB, 4 s by default); the
3-D filter's acquisition grid (:class:`radiopose.filtering.particle3d.CoarseGrid`)
scores every 0.1 s window's median RSS at offset 0 (``Σ w (y − E)² / 2``,
``w = n / ((π/2) σ² + σ_g² n)``), height, pitch and roll are minimised per
(x, y, azimuth) cell, and the Viterbi path over (x, y, azimuth)
(:func:`radiopose.filtering.coarse_track._viterbi_path`; a walk of 0.35 m and
9° per window) is compared with the truth at the windows' times, beside the
default offline ``locate``'s errors (unless ``--no-pipeline``). Nothing in
the pipeline uses this: it measures whether the search would find the right
mode where the pipeline does not.

Usage (tuning seeds only)::

    python scripts/coarse3d_lead.py --seeds 7104 7110-7124 [--no-pipeline]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from radiopose.evaluate.pose3d import axis_errors
from radiopose.filtering import particle3d
from radiopose.filtering.coarse_track import _kernel, _viterbi_path
from radiopose.filtering.offset_profile import timed_windows
from radiopose.likelihood import candidate_space
from radiopose.packets import group_packets
from radiopose.simulate.handheld import HandheldConfig, Simulation, simulate_handheld
from radiopose.tracker import TrackerConfig, locate


def _seeds(items: list[str]) -> list[int]:
    out: list[int] = []
    for item in items:
        lo, _, hi = item.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def _azimuth_error_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def coarse_path(
    sim: Simulation, sigma_db: float, grid_sigma_db: float = 1.5
) -> tuple[np.ndarray, np.ndarray]:
    """The windows' mean times (s) and the Viterbi path's x, y (m), azimuth (°)."""
    obs = group_packets(sim.packets)
    space = candidate_space(sim.site, obs[0].transmitter)
    model = particle3d.FilterModel3d.build3d(sim.site, space, particle3d.Pose3dConfig())
    grid = model.coarse
    assert grid is not None
    pos, ori = grid.positions_m, grid.orientations_deg
    table = grid.table_dbm.astype(np.float64)
    xs, ys = np.unique(pos[:, 0]), np.unique(pos[:, 1])
    azs = np.unique(ori[:, 0])
    shape = (xs.size, ys.size, azs.size)
    # each (orientation, position) row's cell of (x, y, azimuth)
    cell = (
        (np.searchsorted(xs, pos[:, 0])[None, :] * shape[1] + np.searchsorted(ys, pos[:, 1]))
        * shape[2]
        + np.searchsorted(azs, ori[:, 0])[:, None]
    ).ravel()
    records = [(o.timestamp_s, space.heard(o), (o.packet_id, o.timestamp_s)) for o in obs]
    costs: list[np.ndarray] = []
    times: list[float] = []
    for heard, n, t in timed_windows(records, 0.1):
        if heard.n_heard < 3:
            continue
        w = n / ((math.pi / 2) * sigma_db**2 + grid_sigma_db**2 * n)
        e = np.asarray(heard.rss_dbm)[None, :] - table[:, np.asarray(heard.receiver_index)]
        best = np.full(math.prod(shape), np.inf)
        np.minimum.at(best, cell, 0.5 * (e * e) @ w)  # height, pitch, roll minimised
        costs.append(best)
        times.append(t)
    read = [(0 if q == 0 else 1, None, None) for q in range(len(costs))]
    step_m = float(np.min(np.diff(xs)))
    lx = np.log(_kernel(0.35 / step_m))
    la = np.log(_kernel(9.0 / float(azs[1] - azs[0])))
    path = _viterbi_path(
        read, np.zeros(len(costs), dtype=np.int64),
        lambda q: (costs[q], np.zeros_like(costs[q]), 0.0), 0.0, shape, lx, la,
    )  # fmt: skip
    return np.array(times), np.array([[xs[i], ys[j], azs[a]] for i, j, a in path])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", nargs="+", default=["7104"], help="seeds or ranges A-B")
    ap.add_argument("--receivers", type=int, default=6)
    ap.add_argument("--sigma", type=float, default=1.0, help="simulated σ, dB")
    ap.add_argument("--duration-s", type=float, default=4.0)
    ap.add_argument("--no-pipeline", action="store_true", help="the coarse path only")
    args = ap.parse_args(argv)
    print("| seed | pipeline: position m / rotation ° (azimuth °) | coarse path: position m / "
          "azimuth ° (max) | CPU s (pipeline, path) |")  # fmt: skip
    print("|---|---|---|---|")
    for seed in _seeds(args.seeds):
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
    raise SystemExit(main())
