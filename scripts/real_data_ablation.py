"""Diagnostic: the ``filter`` on every track of the real BLE site with *fixed*
settings, one part of the filter switched at a time.

    python scripts/real_data_ablation.py [--variants NAME ...] [--jobs N]

Each track is localised on its held-out site (the survey plus the other tracks'
readings). This is a diagnostic only: the settings of the reported results are
chosen per track by the cross-validation of ``scripts/real_data.py``
(docs/real-data.md), never from these numbers.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from radiopose.realdata import experiment as X  # noqa: N812 - read as X.run_filter
from radiopose.realdata.build import ImportSettings
from radiopose.realdata.tetam import read_dataset, shipped_dataset_dir
from radiopose.scripting import non_negative_int, positive_int, run_script, usage_errors
from radiopose.tracker import TrackerConfig, locate

BASE: tuple[tuple[str, object], ...] = (
    ("huber_c", 1.0),
    ("sigma_prior_db", 5.0),
    ("sigma_floor_db", 5.0),
    ("offset_prior_sd_db", 1.0),
    ("accel_noise_mps2", 0.2),
    ("outlier_probability", 0.3),
    ("outlier_range_db", 20.0),
)
"""The settings most tracks chose with the current filter (docs/real-data.md)."""

VARIANTS: dict[str, tuple[tuple[str, object], ...]] = {
    "base": (),
    "huber": (("likelihood", "huber"),),
    "inherit": (("jump_own_past", False),),
    "jump0.01": (("jump_probability", 0.01),),
    "no-scans": (("offset_scans_per_reentry", 0),),
    "no-diff": (("difference_memory", 0),),
    "old": (
        ("likelihood", "huber"),
        ("jump_own_past", False),
        ("jump_probability", 0.01),
        ("offset_scans_per_reentry", 0),
        ("difference_memory", 0),
    ),
    "huber+inherit": (("likelihood", "huber"), ("jump_own_past", False)),
    "mixture5-60": (("outlier_probability", 0.05), ("outlier_range_db", 60.0)),
}


def _run(
    name: str, extra: tuple[tuple[str, object], ...], seed: int
) -> tuple[str, list[np.ndarray], float]:
    t0 = time.perf_counter()
    ds = read_dataset(shipped_dataset_dir())
    settings = ImportSettings()
    tracks = X.load_tracks(ds, settings)
    errs = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = X.SiteCache(ds, Path(tmp), settings)
        overrides = tuple(dict(BASE + extra).items())
        for tr in tracks:
            site = cache.site({tr.name})
            cfg = replace(X.filter_config(overrides, X.OFFLINE_LAG_S), seed=seed)
            est = locate(site, tr.packets, "filter", cfg).estimates
            errs.append(X.position_errors_m(tr.truth, est))
    return name, errs, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--jobs", type=positive_int, default=1)
    ap.add_argument(
        "--seed", type=non_negative_int, default=0, help="TrackerConfig.seed (0: as scored)"
    )
    args = ap.parse_args(argv)
    with usage_errors(ap):  # the seed within TrackerConfig's range, before the runs
        TrackerConfig(seed=args.seed)
    with ProcessPoolExecutor(args.jobs) as pool:
        futs = [pool.submit(_run, v, VARIANTS[v], args.seed) for v in args.variants]
        for f in futs:
            name, errs, dt = f.result()
            e = np.concatenate(errs)
            per = " ".join(f"{x.mean():.2f}" for x in errs)
            print(
                f"{name:16s} seed {args.seed} mean {e.mean():.3f} median {np.median(e):.3f} "
                f"p95 {np.percentile(e, 95):.3f} | {per} | {dt:.0f} s",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
