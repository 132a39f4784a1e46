"""How fast the simulated hand-held phone turns (issue 18; docs/pose3d.md, "Motion noise").

For each seed, :func:`radiopose.simulate.handheld.handheld_path` is drawn at
200 Hz over the scenario's area and duration (no filter runs): the RMS and
peak of the azimuth's angular acceleration (°/s², from the unwrapped azimuth's
second difference) and the RMS rates of pitch and roll (°/s), against which
the 3-D filter's motion prior can be read (a white angular acceleration of
density q lets the turn rate drift q·√Δt in Δt).

Usage (simulation-only seeds)::

    python scripts/handheld_dynamics.py [--seeds 9000-9009] [--duration-s 4]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from radiopose.scripting import positive_float, run_script, usage_errors
from radiopose.simulate import seed_range
from radiopose.simulate.handheld import HandheldConfig, handheld_path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_range, default=range(9000, 9010), help="FIRST-LAST")
    ap.add_argument("--duration-s", type=positive_float, default=4.0)
    args = ap.parse_args(argv)
    cfg = replace(HandheldConfig(), duration_s=args.duration_s)
    with usage_errors(ap):  # the scenario's range of durations
        cfg.validate()
    t = np.arange(0.0, cfg.duration_s, 0.005)
    if t.size < 2:  # the rates need two samples
        ap.error(
            f"--duration-s must be above 0.005 s (two samples at 200 Hz), got {cfg.duration_s}"
        )
    print("| seed | azimuth acceleration RMS °/s² | peak °/s² | peak rate °/s | pitch rate RMS °/s "
          "| roll rate RMS °/s |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for seed in args.seeds:
        _, ori = handheld_path(
            np.random.default_rng(seed), t, (0.0, cfg.size_m, 0.0, cfg.size_m), cfg
        )
        az = np.degrees(np.unwrap(np.radians(ori[:, 0])))
        rate = np.gradient(az, t)
        acc = np.gradient(rate, t)
        pitch_rate = np.gradient(ori[:, 1], t)
        roll_rate = np.gradient(np.degrees(np.unwrap(np.radians(ori[:, 2]))), t)
        print(
            f"| {seed} | {np.sqrt(np.mean(acc**2)):.0f} | {np.abs(acc).max():.0f} | "
            f"{np.abs(rate).max():.0f} | {np.sqrt(np.mean(pitch_rate**2)):.0f} | "
            f"{np.sqrt(np.mean(roll_rate**2)):.0f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
