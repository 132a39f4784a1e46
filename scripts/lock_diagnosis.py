"""Wrong locks of the offline ``filter``: search failure or likelihood failure?

Issue 15, docs/filter.md "Accuracy round 5: wrong locks offline". For each
seed, the offline ``filter`` (batch ``locate``, 1 s smoother, offset
selection) is run on the standard scenario and the log-likelihood of the whole
file is computed under two tracks of poses, one pose per packet:

* the truth's poses, with the best single device offset (profiled over the
  file) and σ as simulated;
* the filter's estimated track, likewise (its own best single offset).

Both use the filter's per-receiver Gaussian-plus-uniform mixture
(``FilterConfig.outlier_probability``, ``outlier_range_db``). If the truth is
the more likely (``Δ = truth − estimate > 0``), the wrong lock is a search
failure that an offline method can fix; if the estimate is, no estimator on
this likelihood fixes it. ``Δ bad`` is the same difference over the packets
whose orientation error exceeds 15° only. With ``--reverse`` the combined
track of the reversed pass (``FilterConfig.offline_reverse_pass``) is run too,
with ``--arbiter`` the reversed pass with round 6's batch MAP arbiter
(``FilterConfig.offline_refine``).

With ``--candidates`` (round 7, +6 dB tails) the offline default (forward
pass, offset selection, reversed pass, MAP arbiter) is run with its insides
recorded, one block per run: each offset pass (its prior centre, dB, and its
whole-file evidence, nats), then each candidate the arbiter saw (its track's
errors before and after the refinement, its refined offset and objective, σ²
units) and the truth's poses refined the same way. A truth objective below the
chosen candidate's is a search failure (no candidate in the truth's basin);
above it, an objective failure (the arbiter's objective prefers a wrong pair).
Each line also gives the candidate's Laplace width term (½ log det of the
objective's Hessian at its optimum, nats; ``FilterConfig.arbiter_laplace``).

Usage (tuning seeds 7000–7099 only)::

    python scripts/lock_diagnosis.py --seeds 7030 --sigma 3
    python scripts/lock_diagnosis.py --seeds 7010 --sigma 0.5 --loud --reverse
    python scripts/lock_diagnosis.py --seeds 7061 --sigma 3 --loud --candidates
    python scripts/lock_diagnosis.py --quick
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from typing import Any

import numpy as np

import radiopose.filtering.offset_refit as offset_refit
import radiopose.tracker.filter as tracker_filter
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig, FilterEstimate, FilterModel
from radiopose.filtering.config import overrides_or_exit
from radiopose.filtering.reverse import pose_residuals_db, profile_offset
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import HeardRss, MemoScorer, candidate_space
from radiopose.packets import Packets, group_packets
from radiopose.scripting import non_negative_int, positive_float, run_script, usage_errors
from radiopose.simulate import ScenarioConfig, Simulation, simulate
from radiopose.tracker import TrackerConfig


def _loud(sim: Simulation) -> Simulation:
    """The device sending 6 dB above its enrolled power (every reading +6 dB)."""
    p = sim.packets
    packets = Packets(p.packet_id, p.timestamp_s, p.transmitter, p.receiver_id, p.rss_dbm + 6.0)
    return replace(sim, packets=packets)


def _track_loglik(
    model: FilterModel, heards: list[HeardRss], pos_m: np.ndarray, ori_deg: np.ndarray,
    sigma_db: float, cfg: FilterConfig,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """Per-packet log-likelihood (nats) of one pose per packet at the track's best
    single offset, and that offset (dB)."""
    res, idx = pose_residuals_db(model, heards, pos_m, ori_deg)
    mix = (sigma_db, cfg.outlier_probability, cfg.outlier_range_db)
    off = profile_offset(res, *mix)
    z = (res - off) / sigma_db
    p = cfg.outlier_probability
    ll = np.log(
        (1 - p) * np.exp(-0.5 * z * z) / (np.sqrt(2 * np.pi) * sigma_db) + p / cfg.outlier_range_db
    )
    return np.bincount(idx, weights=ll, minlength=len(heards)), off


def diagnose(
    seeds: list[int], sigma_db: float, loud: bool, reverse: bool, quick: bool,
    arbiter: bool = False,
) -> list[str]:  # fmt: skip
    """One table row per seed (see the module docstring)."""
    base = ScenarioConfig.smoke() if quick else ScenarioConfig()
    # the forward pass alone (the offline default before round 6)
    cfg = TrackerConfig()
    cfg = replace(cfg, filter=replace(cfg.filter, offline_reverse_pass=False, offline_refine=False))
    variants = {"filter": cfg}
    if reverse:
        variants["+ reversed pass"] = replace(
            cfg, filter=replace(cfg.filter, offline_reverse_pass=True)
        )
    if arbiter:
        variants["+ reversed pass, MAP arbiter"] = replace(
            cfg, filter=replace(cfg.filter, offline_reverse_pass=True, offline_refine=True)
        )
    rows = [
        "| seed | σ (dB) | device | track | ori mean (°) | pos mean (m) | offset (dB) "
        "| log L truth | log L track | Δ (truth − track) | Δ bad (packets > 15°) |",
        "|---:|---:|:---|:---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for seed in seeds:
        sim = simulate(replace(base, noise_db=sigma_db), seed)
        if loud:
            sim = _loud(sim)
        tx = sim.site.devices[0].transmitter
        space = candidate_space(sim.site, tx)
        scorer = build_scorer(sim, "numba")
        model = FilterModel.build(sim.site, space, MemoScorer(scorer))
        obs = group_packets(sim.packets)
        by_id = {o.packet_id: space.heard(o) for o in obs}
        for name, tcfg in variants.items():
            run = run_methods(sim, ("filter",), tcfg, scorer)["filter"]
            est = run.estimates
            heards = [by_id[str(pid)] for pid in est.packet_id]
            truth_pos = sim.truth.position_m[run.truth_index]
            truth_ori = sim.truth.orientation_deg[run.truth_index]
            ll_true, off_true = _track_loglik(
                model, heards, truth_pos, truth_ori, sigma_db, tcfg.filter
            )
            ll_est, off_est = _track_loglik(
                model, heards, est.position_m, est.orientation_deg, sigma_db, tcfg.filter
            )
            bad = run.orientation_error_deg > 15.0
            d_bad = float(ll_true[bad].sum() - ll_est[bad].sum()) if bad.any() else 0.0
            rows.append(
                f"| {seed} | {sigma_db:g} | {'+6 dB' if loud else 'matched'} | {name} | "
                f"{run.orientation_error_deg.mean():.2f} | {run.position_error_m.mean():.3f} | "
                f"{off_true:+.1f} / {off_est:+.1f} | {ll_true.sum():.1f} | {ll_est.sum():.1f} | "
                f"{ll_true.sum() - ll_est.sum():+.1f} | {d_bad:+.1f} ({int(bad.sum())}) |"
            )
            print(rows[-1], flush=True)
    return rows


def _errors(
    track: dict[object, FilterEstimate], truth: dict[object, tuple[np.ndarray, np.ndarray]]
) -> tuple[float, float]:
    """Mean position (m) and orientation (°) error of ``track`` against ``truth`` by key."""
    keys = [k for k in track if k in truth]
    if not keys:
        return math.nan, math.nan
    pos = np.array([track[k].position_m for k in keys])
    ori = np.array([track[k].orientation_deg for k in keys])
    tp = np.array([truth[k][0] for k in keys])
    to = np.array([truth[k][1] for k in keys])
    return (
        float(np.linalg.norm(pos - tp, axis=1).mean()),
        float(orientation_error_deg(ori, to).mean()),
    )


def _candidate_labels(
    passes: list[Any],
    n_candidates: int,
    reverses: bool,
    keep_profile: bool = False,
    coarse: int = 0,
) -> list[str]:
    """The arbiter's candidates in :meth:`FilterMethod.flush`'s order (pass 1 is
    the filter's own pass, wide offset prior; passes 2… the offset selection's
    tight ones, as in docs/filter.md "Accuracy round 4"; round 8's profile pass,
    marked ``(profile)``, only if it won unless ``keep_profile``)."""
    best = max(range(len(passes)), key=lambda i: (passes[i].log_evidence, -i))
    centre = ["wide"] + [f"{p.centre_db:+.1f}" for p in passes[1:]]
    labels = [f"forward (pass {best + 1} @ {centre[best]})"]
    if reverses:
        labels += ["combined", "reversed"]
    if best > 0:
        labels.append("pass 1 @ wide")
    labels += [
        f"pass {i + 1} @ {centre[i]}{' (profile)' if passes[i].from_profile else ''}"
        for i in range(1, len(passes))
        if i != best and (keep_profile or not passes[i].from_profile)
    ]
    # session 13: the coarse-grid HMM's paths are the last candidates (``coarse``
    # of them; session 14: more than one with ``coarse_track_paths``)
    tail = [f"coarse HMM path {i + 1}" for i in range(coarse)]
    tail = ["coarse HMM path"] if coarse == 1 else tail
    tail = tail if n_candidates >= len(labels) + len(tail) else []
    labels += [f"candidate {i}" for i in range(len(labels), n_candidates - len(tail))] + tail
    return labels[:n_candidates]


def _run_recorded(sim: Simulation, tcfg: TrackerConfig, scorer: Any) -> tuple[Any, dict[str, Any]]:
    """The offline ``filter`` on ``sim`` with the offset selection's passes, every
    arbitration's inputs and log, and a refit pass's offset recorded."""
    seen: dict[str, Any] = {"passes": [], "arb": []}
    select0, arbitrate0 = tracker_filter.select_offset, offset_refit.arbitrate
    run_pass0 = offset_refit.run_pass

    def select(*a: Any, **kw: Any) -> Any:
        chosen, passes = select0(*a, **kw)
        seen["passes"] = list(passes)
        return chosen, passes

    def arbitrate(model, records, candidates, sigma, cfg, max_nfev, *a: Any, **kw: Any):  # type: ignore[no-untyped-def]
        out = arbitrate0(model, records, candidates, sigma, cfg, max_nfev, *a, **kw)
        pen = kw.get("offset_penalty")
        # the coarse paths: the trailing candidates with the margin (with a
        # margin of 0 the number asked for, which a file may not reach)
        hand = list(kw.get("handicaps_nats") or ())
        n = 0
        while n < len(hand) and hand[len(hand) - 1 - n] > 0:
            n += 1
        seen["coarse"] = n if cfg.coarse_track_margin > 0 else cfg.coarse_track_paths
        seen["arb"].append((model, list(records), list(candidates), sigma, cfg, max_nfev, out, pen))
        return out

    def run_pass(pf: Any, seed_: int, records: Any, centre_db: float, *a: Any) -> Any:
        seen["refit"] = centre_db
        return run_pass0(pf, seed_, records, centre_db, *a)

    tracker_filter.select_offset = select  # type: ignore[assignment]
    offset_refit.arbitrate = arbitrate  # type: ignore[assignment]
    offset_refit.run_pass = run_pass  # type: ignore[assignment]
    try:
        run = run_methods(sim, ("filter",), tcfg, scorer)["filter"]
    finally:
        tracker_filter.select_offset, offset_refit.arbitrate = select0, arbitrate0
        offset_refit.run_pass = run_pass0
    return run, seen


def diagnose_candidates(
    seeds: list[int], sigma_db: float, loud: bool, quick: bool, config: TrackerConfig | None = None
) -> list[str]:
    """Per run, the offset passes and the arbiter's candidates (module docstring)."""
    base = ScenarioConfig.smoke() if quick else ScenarioConfig()
    tcfg = config or TrackerConfig()
    lines: list[str] = []
    for seed in seeds:
        sim = simulate(replace(base, noise_db=sigma_db), seed)
        if loud:
            sim = _loud(sim)
        scorer = build_scorer(sim, "numba")
        t_truth = sim.truth.timestamp_s
        run, seen = _run_recorded(sim, tcfg, scorer)
        start = len(lines)
        head = (
            f"seed {seed} σ {sigma_db:g} {'+6 dB' if loud else 'matched'}: "
            f"{run.position_error_m.mean():.3f} m / {run.orientation_error_deg.mean():.2f}°"
        )
        lines.append(head)
        passes = seen["passes"]
        lines.append(
            "  passes (centre dB: evidence nats): "
            + ", ".join(
                f"{'wide' if math.isnan(p.centre_db) else f'{p.centre_db:+.2f}'}: "
                f"{p.log_evidence:.1f}"
                for p in passes
            )
        )
        for n_arb, (model, records, candidates, sigma, cfg, max_nfev, (_, log), pen) in enumerate(
            seen["arb"]
        ):
            truth: dict[object, tuple[np.ndarray, np.ndarray]] = {}
            for _, _, key in records:
                i = int(np.argmin(np.abs(t_truth - key[1])))
                truth[key] = (sim.truth.position_m[i], sim.truth.orientation_deg[i])
            ref = candidates[0]
            truth_track = {
                k: replace(ref[k], position_m=tuple(p), orientation_deg=tuple(o))
                for k, (p, o) in truth.items()
                if k in ref
            }
            labels = _candidate_labels(
                passes,
                len(candidates),
                tcfg.filter.offline_reverse_pass,
                tcfg.filter.offset_profile_track == "always",
                int(seen.get("coarse", 0)) if tcfg.filter.offline_coarse_track else 0,
            )
            if n_arb:  # round 7's refit: the first arbitration's output against the new pass
                kinds = {"forward": ["forward"], "reversed": ["reversed"]}
                kinds["both"] = ["forward", "reversed"]
                labels = ["first arbitration"] + [
                    f"refit {k}" for k in kinds[tcfg.filter.offset_refit_passes]
                ]
            chosen = [a.chosen for a in log]
            for label, cand in [*zip(labels, candidates, strict=True), ("truth", truth_track)]:
                refined, arb = offset_refit.arbitrate(
                    model, records, [cand], sigma, replace(cfg, arbiter_laplace=True), max_nfev,
                    offset_penalty=pen,
                )  # fmt: skip
                pe0, oe0 = _errors(cand, truth)
                pe1, oe1 = _errors(dict(refined), truth)
                offs = {round(e.offset_db, 2) for _, e in refined}
                idx = labels.index(label) if label in labels else -1
                mark = " *" if idx in chosen else ""
                lines.append(
                    f"  {label:<24} {pe0:7.3f} m {oe0:7.2f}° → {pe1:7.3f} m {oe1:7.2f}°  "
                    f"offset {'/'.join(f'{o:+.2f}' for o in sorted(offs))} dB  "
                    f"objective {' / '.join(f'{a.costs[0]:.1f}' for a in arb)}"
                    f" + {' / '.join(f'{a.penalties[0]:.1f}' for a in arb)}"
                    f"  Laplace {' / '.join(f'{a.log_volumes[0]:.1f}' for a in arb)}{mark}"
                )
        if "refit" in seen:
            lines.append(f"  refit pass at {seen['refit']:+.2f} dB")
        for line in lines[start:]:
            print(line, flush=True)
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=non_negative_int, nargs="+", default=[7030], help="tuning seeds only"
    )
    ap.add_argument("--sigma", type=positive_float, default=3.0, help="simulated σ, dB")
    ap.add_argument("--loud", action="store_true", help="the device 6 dB above its enrolled power")
    ap.add_argument("--reverse", action="store_true", help="also the reversed pass's track")
    ap.add_argument(
        "--arbiter", action="store_true", help="also the reversed pass with the MAP arbiter"
    )
    ap.add_argument(
        "--candidates", action="store_true",
        help="the offline default's offset passes and arbiter candidates, the truth refined too",
    )  # fmt: skip
    ap.add_argument(
        "--set", nargs="*", default=[], metavar="FIELD=VALUE",
        help="FilterConfig overrides of the offline default (with --candidates)",
    )  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    args = ap.parse_args(argv)
    if args.set and not args.candidates:
        ap.error("--set overrides the offline default of --candidates: give --candidates")
    if args.candidates and (args.reverse or args.arbiter):
        ap.error("--candidates runs the offline default: --reverse and --arbiter do not apply")
    with usage_errors(ap):  # σ within the scenario's range, before the runs
        replace(ScenarioConfig(), noise_db=args.sigma).validate()
    seeds = [5] if args.quick else args.seeds
    if args.candidates:
        tcfg = TrackerConfig()
        overrides = overrides_or_exit(ap, args.set)
        with usage_errors(ap, "--set"):
            tcfg = replace(tcfg, filter=replace(tcfg.filter, **overrides))
        diagnose_candidates(seeds, args.sigma, args.loud, args.quick, tcfg)
        return 0
    rows = diagnose(seeds, args.sigma, args.loud, args.reverse, args.quick, args.arbiter)
    print("\n".join(rows[:2]))
    print("\n".join(rows[2:]))
    print("offset: the truth's best single offset / the track's, dB")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
