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

Usage (tuning seeds 7000–7099 only)::

    python scripts/lock_diagnosis.py --seeds 7030 --sigma 3
    python scripts/lock_diagnosis.py --seeds 7010 --sigma 0.5 --loud --reverse
    python scripts/lock_diagnosis.py --quick
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig, FilterModel
from radiopose.filtering.reverse import pose_residuals_db, profile_offset
from radiopose.likelihood import HeardRss, MemoScorer, candidate_space
from radiopose.packets import Packets, group_packets
from radiopose.simulate import ScenarioConfig, Simulation, simulate
from radiopose.tracker import TrackerConfig

QUICK: dict[str, float] = {
    "size_m": 10.0,
    "step_m": 0.25,
    "duration_s": 0.2,
    "min_receiver_spacing_m": 3.0,
}
"""``--quick``: a small site and a short trace, to check that the script runs (its numbers
mean nothing)."""


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
    base = replace(ScenarioConfig(), **QUICK) if quick else ScenarioConfig()
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[7030], help="tuning seeds only")
    ap.add_argument("--sigma", type=float, default=3.0, help="simulated σ, dB")
    ap.add_argument("--loud", action="store_true", help="the device 6 dB above its enrolled power")
    ap.add_argument("--reverse", action="store_true", help="also the reversed pass's track")
    ap.add_argument(
        "--arbiter", action="store_true", help="also the reversed pass with the MAP arbiter"
    )
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    args = ap.parse_args(argv)
    seeds = [5] if args.quick else args.seeds
    rows = diagnose(seeds, args.sigma, args.loud, args.reverse, args.quick, args.arbiter)
    print("\n".join(rows[:2]))
    print("\n".join(rows[2:]))
    print("offset: the truth's best single offset / the track's, dB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
