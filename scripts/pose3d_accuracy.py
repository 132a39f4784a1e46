"""Accuracy of the 3-D filter on the hand-held scenario → the table in ``docs/pose3d.md``.

The 3-D hand-held scenario (``radiopose simulate --pose 3d``: 20 m × 20 m,
receivers at mixed heights, every other one on the ceiling, a full-sphere
phone pattern, a packet every 5 ms), the registry's ``filter`` method through
``radiopose.tracker.locate`` (offline: the fixed-lag smoother, 1 s lag;
``--causal`` for the causal filter, ``--live-lag-s L`` for the live server's:
lag ``L``, no refinement), σ told to nobody. Held-out seeds that no
test uses and that were not used for tuning (default 1100–1109; tuning used
7100–7119).

Per (receivers, σ): errors pooled over runs — mean 3-D position error, mean
rotation-angle error (the contract's orientation score), coverage — and the
per-axis means (height, azimuth, pitch, roll; :mod:`radiopose.evaluate.pose3d`).

The standard row is the 3-D filter with its defaults (``Pose3dConfig()``).
``--heading-prior-deg X`` adds, per (receivers, σ), a clearly labelled extra
row with the optional hand-held heading prior (the phone's top follows the
walking direction within X°; docs/pose3d.md), on the same seeds.
``--power-error-db E`` adds a row where ``devices.csv`` understates the
phone's transmit power by ``E`` dB (the same simulation; only the site's
enrolled power is changed): the filter's offset handling away from the
simulation's exact power.

Usage::

    python scripts/pose3d_accuracy.py [--seeds 10] [--first-seed 1100] [--receivers 4 6 8]
        [--sigmas 1.0] [--duration-s 4] [--causal | --live-lag-s 0.25] [--offset-prior-sd-db 6]
        [--heading-prior-deg 30] [--power-error-db 4] [--no-refine] [--refine-chosen-only]
        [--oracle] [--polish-modes K MARGIN SWITCH] [--reverse-pass] [--reverse-members]
        [--restarts N ...] [--offline-particles N ...] [--angular-noise Q ...]
        [--tilt-noise Q ...] [--pose3d-set FIELD=VALUE ...] [--only-variants]
        [--quick] [--out FILE.md]

The standard row is the filter with its defaults, offline the batch refinement
included (``Pose3dConfig.refine``); ``--no-refine`` adds the filter without it,
``--refine-chosen-only`` the refinement from the chosen member's track only
(``refine_from_members = False``), ``--oracle`` the refinement initialised at
the truth (true poses, offset 0 dB, σ told: about the best an estimator on
this likelihood and motion prior does near the right mode).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.evaluate.pose3d import AxisErrors, axis_errors, axis_errors_of
from radiopose.filtering import FilterConfig, particle3d
from radiopose.filtering.config import overrides_or_exit
from radiopose.filtering.refine3d import MotionPrior, refine_track
from radiopose.likelihood import candidate_space
from radiopose.scripting import (
    check_output,
    finite_float,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    run_script,
    usage_errors,
)
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker.batch import _check_packets as check_packets


def run_one(
    n_rx: int,
    sigma_db: float,
    seed: int,
    duration_s: float,
    causal: bool,
    offset_sd_db: float,
    pose3d: dict[str, Any] | None = None,
    power_error_db: float = 0.0,
    live_lag_s: float | None = None,
) -> AxisErrors:
    """One run's errors; ``pose3d`` overrides :class:`Pose3dConfig`'s defaults
    (a variant row) for the registry's ``filter`` method; ``power_error_db``
    lowers the site's enrolled transmit power below the simulated one;
    ``live_lag_s``: the live server's filter (that smoothing lag, the batch
    refinement off: what the streaming ``Tracker`` with that lag gives,
    ``tests/test_pose3d.py::test_live_lag_at_a_3d_site_replays_in_batch``)."""
    cfg = replace(HandheldConfig(), n_receivers=n_rx, noise_db=sigma_db, duration_s=duration_s)
    sim = simulate_handheld(cfg, seed=seed)
    if power_error_db:
        site = sim.site
        devices = tuple(replace(d, tx_power_dbm=d.tx_power_dbm - power_error_db)
                        for d in site.devices)  # fmt: skip
        sim = replace(sim, site=replace(site, devices=devices))
    tcfg = TrackerConfig(smoothing_lag_s=None) if causal else TrackerConfig()
    if live_lag_s is not None:
        tcfg = TrackerConfig(smoothing_lag_s=live_lag_s)
        pose3d = {**(pose3d or {}), "refine": False}
    tcfg = replace(tcfg, filter=replace(tcfg.filter, offset_prior_sd_db=offset_sd_db))
    # (the override goes into TrackerConfig.pose3d, which the filter reads; patching
    # particle3d.Pose3dConfig, as this script did before, did not reach it)
    tcfg = replace(tcfg, pose3d=replace(tcfg.pose3d, **(pose3d or {})))
    res = locate(sim.site, sim.packets, "filter", tcfg)
    return axis_errors(sim.truth, res.estimates)


def oracle_one(
    n_rx: int, sigma_db: float, seed: int, duration_s: float, pose3d: dict[str, Any] | None = None
) -> AxisErrors:
    """The batch refinement (:mod:`radiopose.filtering.refine3d`) initialised at
    the truth (true poses, true offset 0 dB, σ told): about the best an
    estimator on this likelihood and motion prior does near the right mode;
    ``pose3d`` overrides :class:`Pose3dConfig` (the refinement's prior)."""
    cfg = replace(HandheldConfig(), n_receivers=n_rx, noise_db=sigma_db, duration_s=duration_s)
    sim = simulate_handheld(cfg, seed=seed)
    obs = check_packets(sim.site, sim.packets)
    space = candidate_space(sim.site, obs[0].transmitter)
    p3 = replace(particle3d.Pose3dConfig(), **(pose3d or {}))
    model = particle3d.FilterModel3d.build3d(sim.site, space, p3)
    t = np.array([o.timestamp_s for o in obs])
    idx = np.searchsorted(sim.truth.timestamp_s, t)
    pos, ori = sim.truth.position_m[idx], sim.truth.orientation_deg[idx]
    fc = TrackerConfig().filter
    prior = MotionPrior.of_filter(
        fc, p3.height_noise_mps, p3.tilt_noise_dps,
        p3.refine_height_accel_noise_mps2, p3.refine_tilt_accel_noise_dps2,
    )  # fmt: skip
    r = refine_track(
        model, t, [space.heard(o) for o in obs], pos, ori, 0.0, max(sigma_db, 0.1), prior,
        offset_prior_sd_db=fc.offset_prior_sd_db, max_nfev=p3.refine_max_nfev,
    )  # fmt: skip
    return axis_errors_of(r.position_m, r.orientation_deg, pos, ori)


def pooled(runs: list[AxisErrors]) -> dict[str, float]:
    keys = ("position_m", "height_m", "rotation_deg", "azimuth_deg", "pitch_deg", "roll_deg")
    cat = {k: np.concatenate([getattr(r, k) for r in runs]) for k in keys}
    out = {k: float(v.mean()) if v.size else float("nan") for k, v in cat.items()}
    out["coverage"] = float(np.mean([r.coverage for r in runs]))
    out["worst_run_position_m"] = max(float(r.position_m.mean()) for r in runs)
    out["worst_run_rotation_deg"] = max(float(r.rotation_deg.mean()) for r in runs)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=positive_int, default=10, help="number of seeds")
    ap.add_argument("--first-seed", type=non_negative_int, default=1100)
    ap.add_argument("--receivers", type=positive_int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--sigmas", type=positive_float, nargs="+", default=[1.0])
    ap.add_argument("--duration-s", type=positive_float, default=4.0)
    mode_group = ap.add_mutually_exclusive_group()
    mode_group.add_argument("--causal", action="store_true", help="causal filter (no smoother)")
    mode_group.add_argument(
        "--live-lag-s", type=finite_float, default=None,
        help="the live server's filter: this smoothing lag (at most 0.25 s), no refinement",
    )  # fmt: skip
    ap.add_argument(
        "--offset-prior-sd-db",
        type=positive_float,
        default=FilterConfig().offset_prior_sd_db,
        help="prior σ of the transmit-power offset (default: the filter's)",
    )
    ap.add_argument(
        "--heading-prior-deg",
        type=non_negative_float,
        default=0.0,
        help="also run each condition with the hand-held heading prior at this spread (0: no)",
    )
    ap.add_argument(
        "--power-error-db",
        type=finite_float,
        default=0.0,
        help="also run each condition with devices.csv's power this many dB too low (0: no)",
    )
    ap.add_argument(
        "--no-refine",
        action="store_true",
        help="also run each condition without the offline batch refinement (Pose3dConfig.refine)",
    )
    ap.add_argument(
        "--refine-chosen-only",
        action="store_true",
        help="also run each condition refining only the chosen member's track",
    )
    ap.add_argument(
        "--refine-hybrid-s",
        type=non_negative_float,
        default=0.0,
        help="also run each condition with the refinement's hybrid start (segments of this "
        "many seconds; Pose3dConfig.refine_hybrid_segment_s)",
    )
    ap.add_argument(
        "--oracle",
        action="store_true",
        help="also run the batch refinement initialised at the truth (an oracle bound)",
    )
    ap.add_argument(
        "--refine-accel",
        type=non_negative_float,
        nargs=2,
        metavar=("HEIGHT_MPS2", "TILT_DPS2"),
        help="also run each condition (and its oracle with --oracle) with the refinement's "
        "constant-rate height and tilt prior at these densities (docs/pose3d.md)",
    )
    ap.add_argument(
        "--refine-polish",
        type=positive_int,
        nargs="+",
        default=None,
        help="with --refine-accel: one row per value of Pose3dConfig.refine_polish_starts",
    )
    ap.add_argument(
        "--polish-modes",
        type=non_negative_float,
        nargs=3,
        metavar=("K", "MARGIN", "SWITCH"),
        help="also run each condition polishing up to K distinct refined tracks within MARGIN "
        "(objective, σ² units) of the lowest, another mode replacing the lowest's polish only "
        "when lower by more than SWITCH (refine_polish_starts, refine_polish_margin, "
        "refine_polish_switch; docs/pose3d.md, 'Mode choice')",
    )
    ap.add_argument(
        "--reverse-pass",
        action="store_true",
        help="also run each condition with the offline reversed pass's track as one more "
        "refinement start (refine_reverse_pass; docs/pose3d.md, 'Reversed pass')",
    )
    ap.add_argument(
        "--reverse-members",
        action="store_true",
        help="also run each condition with the reversed pass's track and its bank members' "
        "tracks as starts (refine_reverse_pass and refine_reverse_members)",
    )
    ap.add_argument(
        "--restarts",
        type=non_negative_int,
        nargs="+",
        default=[],
        metavar="N",
        help="also run each condition with N offline mid-track restarts of the filter as more "
        "refinement starts, one row per N (refine_restarts; docs/pose3d.md, 'Mid-track restarts')",
    )
    ap.add_argument(
        "--offline-particles",
        type=positive_int,
        nargs="+",
        default=[],
        metavar="N",
        help="also run each condition with N particles per device in the offline passes "
        "(forward, reversed, restarts), one row per N (offline_n_particles; docs/pose3d.md, "
        "'Offline particles')",
    )
    ap.add_argument(
        "--angular-noise",
        type=positive_float,
        nargs="+",
        default=[],
        metavar="DPS2",
        help="also run each condition with the 3-D filter's azimuth acceleration density "
        "(and its refinement's) at DPS2 °/s²/√Hz, one row per value (angular_accel_noise_dps2)",
    )
    ap.add_argument(
        "--tilt-noise",
        type=positive_float,
        nargs="+",
        default=[],
        metavar="DPS",
        help="also run each condition with the 3-D filter's pitch/roll random-walk density at "
        "DPS °/√s, one row per value (tilt_noise_dps)",
    )
    ap.add_argument(
        "--pose3d-set",
        nargs="+",
        default=[],
        metavar="FIELD=VALUE",
        help="also run each condition with these Pose3dConfig overrides (VALUE a Python "
        "literal), one row for all of them together",
    )
    ap.add_argument(
        "--only-variants",
        action="store_true",
        help="skip the standard row (and its oracle): only the extra rows asked for",
    )
    ap.add_argument("--quick", action="store_true", help="smoke run: 1 seed, 6 receivers, 0.5 s")
    ap.add_argument("--out", help="also write the Markdown table to this file")
    args = ap.parse_args(argv)
    if args.live_lag_s is not None and not 0.0 <= args.live_lag_s <= 0.25:
        ap.error(f"--live-lag-s must lie in [0, 0.25] s (the live server's), got {args.live_lag_s}")
    if args.polish_modes and not (args.polish_modes[0].is_integer() and args.polish_modes[0] >= 1):
        ap.error(f"--polish-modes: K must be an integer >= 1, got {args.polish_modes[0]:g}")
    if args.refine_polish and not args.refine_accel:
        ap.error("--refine-polish applies with --refine-accel only")
    if args.out is not None:
        check_output(ap, "--out", files=[args.out])
    if args.quick:
        args.seeds, args.receivers, args.duration_s = 1, [6], 0.5
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    head = (
        "| receivers | σ dB | filter | position m | rotation ° | coverage | height m | azimuth ° | "
        "pitch ° | roll ° | worst run: position m / rotation ° |"
    )
    lines = [head, "|" + "---|" * 11]
    variants: list[tuple[str, dict[str, Any], float]] = [("standard", {}, 0.0)]
    if args.no_refine:
        variants.append(("without refinement", {"refine": False}, 0.0))
    if args.refine_chosen_only:
        variants.append(("refined from the chosen track only", {"refine_from_members": False}, 0.0))
    if args.refine_hybrid_s > 0:
        h = args.refine_hybrid_s
        variants.append(
            (f"+ hybrid start from {h:g} s segments", {"refine_hybrid_segment_s": h}, 0.0)
        )
    if args.oracle:
        variants.append(("oracle: refinement from the truth", {}, math.nan))
    if args.refine_accel:
        hq, tq = args.refine_accel
        acc = {"refine_height_accel_noise_mps2": hq, "refine_tilt_accel_noise_dps2": tq}
        label = f"refinement prior constant-rate (height {hq:g}, tilt {tq:g})"
        for k in args.refine_polish or [1]:
            variants.append((f"{label}, polish {k}", {**acc, "refine_polish_starts": k}, 0.0))
        if args.oracle:
            variants.append(("oracle, " + label, acc, math.nan))
    if args.polish_modes:
        k, margin, switch = int(args.polish_modes[0]), *args.polish_modes[1:]
        pm = {"refine_polish_starts": k, "refine_polish_margin": margin,
              "refine_polish_switch": switch}  # fmt: skip
        label = f"polish up to {k} modes within {margin:g}, switch {switch:g}"
        variants.append((label, pm, 0.0))
    if args.reverse_pass:
        variants.append(("+ reversed pass", {"refine_reverse_pass": True}, 0.0))
    if args.reverse_members:
        rm = {"refine_reverse_pass": True, "refine_reverse_members": True}
        variants.append(("+ reversed pass and its members", rm, 0.0))
    for n in args.offline_particles:
        variants.append((f"offline particles {n}", {"offline_n_particles": n}, 0.0))
    for n_restarts in args.restarts:
        label = f"+ {n_restarts} mid-track restart{'s' if n_restarts != 1 else ''}"
        variants.append((label, {"refine_restarts": n_restarts}, 0.0))
    for q in args.angular_noise:
        variants.append((f"angular noise {q:g}", {"angular_accel_noise_dps2": q}, 0.0))
    for q in args.tilt_noise:
        variants.append((f"tilt noise {q:g}", {"tilt_noise_dps": q}, 0.0))
    if args.pose3d_set:
        over = overrides_or_exit(ap, args.pose3d_set, "--pose3d-set", particle3d.Pose3dConfig)
        variants.append((", ".join(args.pose3d_set), over, 0.0))
    if args.only_variants:
        variants = [v for v in variants if v[1]]
    if args.heading_prior_deg > 0:
        h = args.heading_prior_deg
        variants.append((f"+ heading prior {h:g}°", {"heading_prior_deg": h}, 0.0))
    if args.power_error_db:
        e = args.power_error_db
        variants.append((f"devices.csv power {e:g} dB low", {}, e))
    if not variants:
        ap.error("--only-variants skips the standard row: ask for another row too")
    with usage_errors(ap):  # every run's settings within their ranges, before the runs
        for n_rx in args.receivers:
            for sigma in args.sigmas:
                replace(HandheldConfig(), n_receivers=n_rx, noise_db=sigma,
                        duration_s=args.duration_s).validate()  # fmt: skip
        FilterConfig(offset_prior_sd_db=args.offset_prior_sd_db)
        for _, p3, _ in variants:
            replace(particle3d.Pose3dConfig(), **p3)
    t0 = time.time()
    for n_rx in args.receivers:
        for sigma in args.sigmas:
            for label, p3, err in variants:
                args_one = (args.duration_s, args.causal, args.offset_prior_sd_db, p3, err,
                            args.live_lag_s)  # fmt: skip
                runs, cpus = [], []
                for s in seeds:
                    c0 = time.process_time()
                    if math.isnan(err):
                        r = oracle_one(n_rx, sigma, s, args.duration_s, p3)
                    else:
                        r = run_one(n_rx, sigma, s, *args_one)
                    cpus.append(time.process_time() - c0)
                    runs.append(r)
                    print(
                        f"  seed {s} {label}: {r.position_m.mean():.3f} m "
                        f"{r.rotation_deg.mean():.1f}° ({cpus[-1]:.1f} CPU s)",
                        flush=True,
                    )
                cpu_s = sum(cpus) / len(cpus)
                print(f"  {label}: {cpu_s:.1f} CPU s per run (simulation included)", flush=True)
                p = pooled(runs)
                lines.append(
                    f"| {n_rx} | {sigma:g} | {label} | {p['position_m']:.2f} | "
                    f"{p['rotation_deg']:.1f} | "
                    f"{100 * p['coverage']:.1f} % | {p['height_m']:.2f} | {p['azimuth_deg']:.1f} | "
                    f"{p['pitch_deg']:.1f} | {p['roll_deg']:.1f} | "
                    f"{p['worst_run_position_m']:.2f} / {p['worst_run_rotation_deg']:.1f} |"
                )
                print(lines[-1], flush=True)
    mode = "causal filter" if args.causal else "offline (fixed-lag smoother, 1 s)"
    if args.live_lag_s is not None:
        mode = f"live (lag {args.live_lag_s:g} s, no refinement)"
    mode += f", offset prior σ {args.offset_prior_sd_db:g} dB"
    text = "\n".join(
        [
            f"Seeds {seeds.start}–{seeds.stop - 1}, {args.duration_s:g} s traces, {mode}; "
            f"means pooled over runs ({time.time() - t0:.0f} s).",
            "",
            *lines,
            "",
        ]
    )
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
