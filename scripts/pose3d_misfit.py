"""The 3-D refinement's misfit per run → ``docs/pose3d.md``, "A misfit test, measured".

For each seed the hand-held scenario is simulated (6 receivers, σ 1 dB, 4 s by
default) and tracked by the default offline ``locate`` (``--pose3d-set``
overrides :class:`~radiopose.filtering.particle3d.Pose3dConfig` fields); the
refined track that ``refine_smoothed`` keeps is read as it returns, and its
data term (:func:`radiopose.filtering.refine3d.packet_costs`, ½ Σ ρ(r²/σ²) at
the filter's final σ, the refinement's soft-L1 loss) is expressed as the
residuals' RMS, ``σ √(2 · data / m)`` dB over the run's ``m`` readings, beside
the run's errors and the normalised score ``(2 · data − m) / √(2m)``. A run
whose track misses the truth's basin fits worse than the readings' noise; a
tie between modes does not. One track per run is assumed (no gap longer than
the filter's re-acquisition gap; the last track's term is printed otherwise).

``--segment-s S`` adds a σ-free misfit: the data term per reading in segments
of ``S`` seconds of the track, its largest over its median (a track wrong over
part of its length fits worse there than elsewhere).

``--oracle`` adds the truth's basin: the refinement started at the true poses
(offset 0 dB) with the kept track's σ and the constant-rate prior of the
polish, and compares objectives (σ² units ≈ nats, each with the heading cost
of the mode choice when ``refine_heading_deg`` > 0 and the hand-held band's
when it is set): ``kept − truth`` > 0 means
the truth's basin is lower and no start reached it (a *search* failure); ≤ 0
means the kept track is at least as likely as the truth's (an *objective* tie
or error, which no search fixes). The kept track's objective is evaluated at
its poses and offset without moving them.

``--sim-set`` overrides the simulated scenario's
:class:`~radiopose.simulate.handheld.HandheldConfig` (e.g. a truth outside the
hand-held ranges, to measure what a hand-held prior costs when its assumption
is wrong: docs/pose3d.md, "A hand-held band, 2026-11-28").

Usage (tuning seeds only, or seeds already spent, for diagnosis)::

    python scripts/pose3d_misfit.py --seeds 7104-7124 9100-9139 [--oracle]
        [--pose3d-set FIELD=VALUE ...] [--sim-set FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from typing import Any

import numpy as np

import radiopose.filtering.refine3d as refine3d
from radiopose.errors import InputError
from radiopose.evaluate.pose3d import axis_errors, axis_errors_of
from radiopose.filtering.config import overrides_or_exit
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.scripting import (
    non_negative_float,
    positive_float,
    positive_int,
    run_script,
    usage_errors,
)
from radiopose.simulate import seed_range
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=seed_range, nargs="+", default=[range(7104, 7105)],
        help="seeds or ranges FIRST-LAST",
    )  # fmt: skip
    ap.add_argument("--receivers", type=positive_int, default=6)
    ap.add_argument("--sigma", type=positive_float, default=1.0, help="simulated σ, dB")
    ap.add_argument("--duration-s", type=positive_float, default=4.0)
    ap.add_argument("--pose3d-set", nargs="*", default=[], metavar="FIELD=VALUE")
    ap.add_argument(
        "--sim-set", nargs="*", default=[], metavar="FIELD=VALUE",
        help="HandheldConfig overrides of the simulated scenario (e.g. a truth outside the "
        "hand-held ranges: pitch_range_deg=(0,85))",
    )  # fmt: skip
    ap.add_argument("--oracle", action="store_true", help="compare with the truth's basin")
    ap.add_argument(
        "--segment-s", type=non_negative_float, default=0.0,
        help="also the largest over the median segment's data term per reading, segments "
        "of this many seconds (σ-free: a track wrong over part of its length fits worse there)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    over = overrides_or_exit(ap, args.pose3d_set, "--pose3d-set", Pose3dConfig)
    sim_over = overrides_or_exit(ap, args.sim_set, "--sim-set", HandheldConfig)
    try:
        replace(HandheldConfig(), **sim_over).validate()
    except InputError as exc:
        ap.error(f"--sim-set {exc}")
    options = {"n_receivers": "--receivers", "noise_db": "--sigma", "duration_s": "--duration-s"}
    for name in sim_over.keys() & options.keys():
        ap.error(f"--sim-set {name}: give {options[name]} instead")
    with usage_errors(ap):  # the scenario's ranges (3 receivers at least), before the runs
        replace(HandheldConfig(), n_receivers=args.receivers, noise_db=args.sigma,
                duration_s=args.duration_s, **sim_over).validate()  # fmt: skip
    kept: dict[str, Any] = {}
    original = refine3d.refine_smoothed

    def keeping(model, records, smoothed, config, *a, **kw):  # type: ignore[no-untyped-def]
        out = original(model, records, smoothed, config, *a, **kw)
        got = dict(out)
        rows = [r for r in records if r[2] in got and r[1].n_heard > 0]
        ests = [got[r[2]] for r in rows]
        sigma = refine3d.track_sigma_db(ests, config)
        heard = [r[1] for r in rows]
        data = refine3d.packet_costs(
            model, heard, np.array([e.position_m for e in ests]),
            np.array([e.orientation_deg for e in ests]), ests[0].offset_db, sigma,
        )  # fmt: skip
        kept.update(data=float(data.sum()), m=sum(h.n_heard for h in heard), sigma=sigma)
        if args.segment_s > 0:
            ratio = refine3d.segment_misfit_ratio(model, records, out, config, args.segment_s)
            kept.update(segment_ratio=ratio)
        if args.oracle:
            kept.update(_versus_truth(model, rows, ests, sigma, config, a, kw, truth[0]))
        return out

    truth: list[Any] = [None]
    head = "| seed | position m | rotation ° | readings | σ̂ dB | residual RMS dB | score |"
    rule = "|---|---|---|---|---|---|---|"
    if args.oracle:
        head += " kept objective | truth's basin | its rotation ° | kept − truth |"
        rule += "---|---|---|---|"
    if args.segment_s > 0:
        head += " segment ratio |"
        rule += "---|"
    print(head)
    print(rule)
    refine3d.refine_smoothed = keeping  # the tracker imports it from the module when it runs
    try:
        for seed in (s for r in args.seeds for s in r):
            cfg = replace(HandheldConfig(), n_receivers=args.receivers, noise_db=args.sigma,
                          duration_s=args.duration_s, **sim_over)  # fmt: skip
            sim = simulate_handheld(cfg, seed=seed)
            tcfg = TrackerConfig()
            tcfg = replace(tcfg, pose3d=replace(tcfg.pose3d, **over))
            kept.clear()
            truth[0] = sim.truth
            e = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", tcfg).estimates)
            if not kept:
                print(f"| {seed} | {e.position_m.mean():.3f} | {e.rotation_deg.mean():.1f} "
                      "| – | – | – | (not refined) |")  # fmt: skip
                continue
            m, data, sigma = kept["m"], kept["data"], kept["sigma"]
            rms = sigma * math.sqrt(2.0 * data / m)
            score = (2.0 * data - m) / math.sqrt(2.0 * m)
            row = (f"| {seed} | {e.position_m.mean():.3f} | {e.rotation_deg.mean():.1f} | {m} "
                   f"| {sigma:.2f} | {rms:.3f} | {score:.2f} |")  # fmt: skip
            if args.oracle:
                k, o = kept["kept_objective"], kept["truth_objective"]
                row += f" {k:.1f} | {o:.1f} | {kept['truth_rotation_deg']:.1f} | {k - o:+.1f} |"
            if args.segment_s > 0:
                row += f" {kept['segment_ratio']:.3f} |"
            print(row, flush=True)
    finally:
        refine3d.refine_smoothed = original
    return 0


def _versus_truth(model, rows, ests, sigma, config, a, kw, truth) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """The kept track's objective and the truth's basin's (see the module docstring);
    ``a``/``kw`` are ``refine_smoothed``'s own arguments after ``config``."""
    height_noise, tilt_noise, max_nfev = a[0], a[1], a[2]
    prior = refine3d.MotionPrior.of_filter(
        config, height_noise, tilt_noise,
        kw.get("height_accel_noise_mps2", 0.0), kw.get("tilt_accel_noise_dps2", 0.0),
    )  # fmt: skip
    t = np.array([r[0] for r in rows])
    heard = [r[1] for r in rows]
    pos = np.array([e.position_m for e in ests])
    ori = np.array([e.orientation_deg for e in ests])
    common = {"offset_prior_db": 0.0, "offset_prior_sd_db": config.offset_prior_sd_db,
              "band": kw.get("band")}  # fmt: skip
    at_kept = refine3d.refine_track(
        model, t, heard, pos, ori, ests[0].offset_db, sigma, prior, max_nfev=1, **common
    )
    idx = np.searchsorted(truth.timestamp_s, t)
    tp, to = truth.position_m[idx], truth.orientation_deg[idx]
    basin = refine3d.refine_track(
        model, t, heard, tp, to, 0.0, sigma, prior, max_nfev=max_nfev, **common
    )
    heading = kw.get("heading")

    def extra(p: np.ndarray, o: np.ndarray) -> float:
        return refine3d.heading_cost(t, p, o, *heading) if heading is not None else 0.0

    rot = axis_errors_of(basin.position_m, basin.orientation_deg, tp, to).rotation_deg
    return {
        "kept_objective": at_kept.initial_cost + extra(pos, ori),
        "truth_objective": basin.cost + extra(basin.position_m, basin.orientation_deg),
        "truth_rotation_deg": float(rot.mean()),
    }


if __name__ == "__main__":
    raise SystemExit(run_script(main))
