"""How many 3-D poses fit one packet exactly? → "Why a single packet does not fix a 3-D pose"
in ``docs/pose3d.md``.

The first packet of a noise-free hand-held scene (``tests/test_pose3d.py``'s
small scene: 10 m × 10 m, receivers at mixed heights), fitted by least squares
(``scipy.optimize.least_squares``, the 3-D filter's expected RSS) from random
starting poses, with the transmit-power offset known (0) or free. A fit counts
as exact when its sum of squared residuals is below 0.01 dB²; it is "far" when
more than 0.3 m or 10° (rotation angle) from the true pose.

Usage::

    python scripts/pose3d_identifiability.py [--receivers 6] [--seed 424242] [--starts 150]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.particle3d import FilterModel3d, Pose3dConfig
from radiopose.geometry import relative_rotation_angle_deg
from radiopose.likelihood import candidate_space
from radiopose.scripting import non_negative_int, positive_int, run_script, usage_errors
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

SCENE = HandheldConfig(
    size_m=10.0, step_m=0.5, duration_s=0.05, noise_db=0.0, min_receiver_spacing_m=3.0
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--receivers", type=positive_int, default=6)
    ap.add_argument("--seed", type=non_negative_int, default=424242)
    ap.add_argument("--starts", type=positive_int, default=150)
    args = ap.parse_args(argv)
    with usage_errors(ap):  # the scene's range of receivers (3 at least)
        replace(SCENE, n_receivers=args.receivers).validate()
    k = args.receivers
    sim = simulate_handheld(replace(SCENE, n_receivers=k), seed=args.seed)
    site = sim.site
    cfg = Pose3dConfig(acquisition_step_m=5.0, acquisition_tilts=2)  # the grid is not used
    model = FilterModel3d.build3d(site, candidate_space(site, site.devices[0].transmitter), cfg)
    rss = sim.packets.rss_dbm[:k]
    true_xyz, true_deg = sim.truth.position_m[0], sim.truth.orientation_deg[0]

    def residual(x: np.ndarray, free_offset: bool) -> np.ndarray:
        S = np.zeros((1, K.N_COLUMNS))
        S[0, :3] = x[:3]
        S[0, [K.AZIMUTH_RAD, K.PITCH_RAD, K.ROLL_RAD]] = x[3:6]
        return rss - model.expected(S, np.arange(k))[0] - (x[6] if free_offset else 0.0)

    rng = np.random.default_rng(0)
    lo = [0.0, 0.0, 0.6, -50.0, -0.2, -3.2, -20.0]
    hi = [10.0, 10.0, 1.8, 50.0, 1.6, 3.2, 20.0]
    for free in (False, True):
        exact = []
        for _ in range(args.starts):
            x0 = np.r_[rng.uniform([0, 0, 0.6, 0, 0, -0.7], [10, 10, 1.8, 6.28, 1.5, 0.7]), 0.0]
            r = least_squares(residual, x0, args=(free,), bounds=(lo, hi))
            if np.sum(r.fun**2) < 0.01:
                d_m = float(np.linalg.norm(r.x[:3] - true_xyz))
                d_deg = float(relative_rotation_angle_deg(np.rad2deg(r.x[3:6]), true_deg)[0])
                exact.append((d_m, d_deg))
        far = sum(1 for d_m, d_deg in exact if d_m > 0.3 or d_deg > 10.0)
        print(
            f"{k} receivers, offset {'free' if free else 'known'}: {len(exact)} exact fits "
            f"of {args.starts} starts, {far} of them far from the true pose"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
