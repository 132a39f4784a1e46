"""Interpolation error of the survey map on the paper's standard scenario.

Compares the interpolated channel map ``M_r`` (1 m survey → 0.1 m grid) with
the noise-free channel model at every candidate point, for both interpolation
methods, over several seeds; prints RMS / p95 / max error in dB, overall and
more than 2 m from any receiver.

``--pose 3d``: the 3-D filter's channel (:mod:`radiopose.survey_height`: the
survey at 1.2 m moved along 3-D distance) on the hand-held scenario's sites, at
every candidate position at heights 0.8, 1.2 and 1.6 m, for the survey's own
map, the detrended maps (docs/pose3d.md, "Detrended survey maps") and the
detrended maps with the receivers' own gain removed and added back ("The
receiver's gain in the height model"; ``--rx-pattern-error-db`` and
``--rx-orientation-error-deg`` build the models from receivers enrolled with
errors); error
(model − channel, dB) of each receiver's channel by the 3-D distance to that
receiver. Usage:
``python scripts/survey_interpolation_error.py [--seeds 5] [--first-seed 100] [--quick]
[--pose 2d|3d] [--rx-pattern-error-db E] [--rx-orientation-error-deg A]``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from radiopose.patterns import isotropic
from radiopose.patterns.pattern import Pattern
from radiopose.patterns.synthetic import smartphone_like
from radiopose.scripting import non_negative_float, non_negative_int, positive_int, run_script
from radiopose.simulate import ScenarioConfig, link_rss_dbm, simulate
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.site import Site, assemble_site
from radiopose.survey_height import build_height_model

QUICK = {"size_m": 10.0, "min_receiver_spacing_m": 3.0}
"""``--quick``: a small site, to check that the script runs (its numbers mean nothing)."""


def interpolation_error(seeds: range = range(100, 105), quick: bool = False) -> None:
    """Print the Markdown table of interpolation errors over ``seeds``."""
    base = ScenarioConfig(duration_s=0.01, **(QUICK if quick else {}))
    print("| method | region | RMS (dB) | p95 (dB) | max (dB) |")
    print("|---|---|---|---|---|")
    for method in ("cubic", "linear"):
        errs_all, errs_far = [], []
        for seed in seeds:
            sim = simulate(base, seed=seed)
            s = sim.site
            site = assemble_site(
                s.name,
                s.area,
                s.orientations,
                replace(s.survey_config, interpolation=method),
                s.receivers,
                s.devices,
                s.patterns,
                s.survey_rows,
            )
            pts = site.area.points_m()
            rx = site.receiver_positions_m()
            rx_o = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in site.receivers])
            pats = tuple(site.patterns[r.pattern] for r in site.receivers)
            truth = link_rss_dbm(
                sim.config.channel, pts, np.zeros((len(pts), 3)), isotropic(), 0.0, rx, rx_o, pats
            )
            err = site.survey_map.m_db.reshape(len(rx), -1).T - truth
            far = np.min(np.linalg.norm(pts[:, None] - rx[None], axis=-1), axis=1) > 2.0
            errs_all.append(err.ravel())
            errs_far.append(err[far].ravel())
        for name, e in (
            ("all", np.concatenate(errs_all)),
            ("> 2 m from receivers", np.concatenate(errs_far)),
        ):
            a = np.abs(e)
            print(
                f"| {method} | {name} | {np.sqrt(np.mean(e**2)):.3f} | "
                f"{np.percentile(a, 95):.3f} | {a.max():.2f} |"
            )


HEIGHTS_M = (0.8, 1.2, 1.6)
"""``--pose 3d``: the device heights scored (the hand-held range and the survey's)."""
BANDS_M = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, np.inf))
"""``--pose 3d``: bands of the 3-D distance to the receiver, metres."""


def enrolled_with_error(site: Site, seed: int, pattern_db: float, orientation_deg: float) -> Site:
    """``site`` as a site file would hold it if its receivers' patterns and
    orientations had been enrolled with errors: each receiver pattern plus a
    smooth random pattern of range ``pattern_db`` (mean removed), each
    receiver's azimuth and pitch plus a normal error of SD ``orientation_deg``.
    The survey (measured through the true receivers) is unchanged."""
    if pattern_db <= 0 and orientation_deg <= 0:
        return site
    rng = np.random.default_rng([seed, 21])
    patterns = dict(site.patterns)
    receivers = []
    for r in site.receivers:
        p = site.patterns[r.pattern]
        if pattern_db > 0:
            err = smartphone_like(rng, "error", range_db=pattern_db)
            e = err.lookup_dbi(*np.meshgrid(p.azimuth_deg, p.polar_deg, indexing="ij"))
            patterns[r.pattern] = Pattern(p.name, p.azimuth_deg, p.polar_deg,
                                          p.directivity_dbi + e - e.mean())  # fmt: skip
        da, dp = rng.normal(0.0, orientation_deg, 2) if orientation_deg > 0 else (0.0, 0.0)
        receivers.append(replace(r, azimuth_deg=r.azimuth_deg + da, pitch_deg=r.pitch_deg + dp))
    return replace(site, patterns=patterns, receivers=tuple(receivers))


def height_model_error(
    seeds: range, quick: bool = False, rx_pattern_error_db: float = 0.0,
    rx_orientation_error_deg: float = 0.0,
) -> None:  # fmt: skip
    """Print the Markdown table of the 3-D channel's errors over ``seeds``; the
    models built from the site with its receivers enrolled with the given
    errors (:func:`enrolled_with_error`), the channel from the true ones."""
    base = replace(HandheldConfig(), duration_s=0.01, **(QUICK if quick else {}))
    print("| maps | distance to the receiver | points | RMS (dB) | mean (dB) | max (dB) |")
    print("|---|---|---|---|---|---|")
    variants = {"survey": {"detrend": False}, "detrended": {"detrend": True},
                "detrended + receiver gain": {"detrend": True, "receiver_gain": True}}  # fmt: skip
    errs: dict[str, list[np.ndarray]] = {name: [] for name in variants}
    dists: list[np.ndarray] = []
    for seed in seeds:
        site = simulate_handheld(base, seed=seed).site
        xy = site.area.points_m()[:, :2]
        pts = np.concatenate([np.column_stack([xy, np.full(len(xy), z)]) for z in HEIGHTS_M])
        rx = site.receiver_positions_m()
        rx_o = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in site.receivers])
        pats = tuple(site.patterns[r.pattern] for r in site.receivers)
        truth = link_rss_dbm(
            base.channel, pts, np.zeros((len(pts), 3)), isotropic(), 0.0, rx, rx_o, pats
        )
        dists.append(np.linalg.norm(pts[:, None] - rx[None], axis=-1).ravel())
        enrolled = enrolled_with_error(site, seed, rx_pattern_error_db, rx_orientation_error_deg)
        for name, kw in variants.items():
            hm = build_height_model(enrolled, **kw)
            errs[name].append((hm.channel_db(pts) - truth).ravel())
    d = np.concatenate(dists)
    for name, parts in errs.items():
        e = np.concatenate(parts)
        for lo, hi in BANDS_M:
            sel = (d >= lo) & (d < hi)
            if not sel.any():
                continue
            band = f"{lo:g}–{hi:g} m" if np.isfinite(hi) else f"≥ {lo:g} m"
            x = e[sel]
            print(
                f"| {name} | {band} | {sel.sum()} | "
                f"{np.sqrt(np.mean(x**2)):.3f} | {x.mean():+.3f} | {np.abs(x).max():.2f} |"
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=positive_int, default=5, help="number of seeds")
    ap.add_argument("--first-seed", type=non_negative_int, default=100)
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    ap.add_argument(
        "--pose", choices=("2d", "3d"), default="2d",
        help="3d: the 3-D filter's channel: the survey's map, detrended maps, receiver gain",
    )  # fmt: skip
    ap.add_argument(
        "--rx-pattern-error-db", type=non_negative_float, default=0.0,
        help="3d: the models' receiver patterns off by a smooth pattern of this range, dB",
    )  # fmt: skip
    ap.add_argument(
        "--rx-orientation-error-deg", type=non_negative_float, default=0.0,
        help="3d: the models' receiver azimuth and pitch off by a normal error of this SD",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.pose == "2d" and (args.rx_pattern_error_db or args.rx_orientation_error_deg):
        ap.error("--rx-pattern-error-db and --rx-orientation-error-deg apply with --pose 3d only")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if args.pose == "3d":
        height_model_error(
            seeds, args.quick, args.rx_pattern_error_db, args.rx_orientation_error_deg
        )
    else:
        interpolation_error(seeds, args.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
