"""Numbers of the spoofing detector (issue 19): tuning grid and held-out ROC.

Runs a :class:`radiopose.security.detect_experiment.DetectPlan` (attack runs and
genuine chunks through the causal filter), keeps the residual tracks in
``OUT/tracks.pkl`` (a second call with the same ``--out`` reuses them) and
writes ``OUT/summary.md``: the detection table at the shipped detector
settings, the ROC over thresholds, and — with ``--grid`` — the design grid
(inflation ``k`` × clip ``c``; the CUSUM on the residual changes, as shipped,
and on the residuals themselves) with each variant's largest score on genuine
traffic and its attack scores within 0.5 s.

    python scripts/spoof_detection.py --plan tuning --grid --out /tmp/det-tuning
    python scripts/spoof_detection.py --plan quick --out /tmp/det-quick

``tuning``: seeds 7000–7011 (σ 0.5, 1, 3 dB; 8 runs per attack; 6 genuine
chunks of 30 s per σ); ``quick``: what ``radiopose spoof detect --quick`` runs
(σ = 1 dB, seeds from 20000); ``sigmas``: the same at σ = 0.5 and 3 dB;
``full``: the full plan (hours).
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from radiopose.security.detect_experiment import (
    DetectPlan,
    Track,
    detection_rows,
    genuine_hours,
    roc_rows,
    run_tracks,
)
from radiopose.security.detection import DetectorConfig, score_track

PLANS = {
    "tuning": DetectPlan(
        sigmas_db=(1.0, 3.0, 0.5), attack_runs=8, genuine_chunks=6, chunk_s=30.0, seed=7000
    ),
    "quick": DetectPlan.quick(),
    "sigmas": DetectPlan(
        sigmas_db=(0.5, 3.0), attack_runs=10, genuine_chunks=20, chunk_s=30.0, seed=20_000
    ),
    "full": DetectPlan(),
}


def _levels(track: Track) -> Track:
    """The same CUSUM on the residuals themselves: their running sum's changes are them."""
    r = np.where(np.isfinite(track.residuals_db), track.residuals_db, 0.0)
    c = np.cumsum(r, axis=0)
    c[~np.isfinite(track.residuals_db)] = np.nan
    return replace(track, residuals_db=c)


def _scores(tracks: list[Track], config: DetectorConfig) -> tuple[dict, dict]:
    genuine: dict[float, float] = {}
    attack: dict[tuple[str, float], list[float]] = {}
    for t in tracks:
        s = score_track(t.t_s, t.residuals_db, config, t.new_track).score_nats
        pre = t.t_s < t.t_attack_s
        if pre.any():
            genuine[t.sigma_db] = max(genuine.get(t.sigma_db, 0.0), float(s[pre].max()))
        if t.kind != "genuine":
            w = (t.t_s >= t.t_attack_s) & (t.t_s <= t.t_attack_s + 0.5)
            attack.setdefault((t.kind, t.sigma_db), []).append(float(s[w].max()))
    return genuine, attack


def grid_table(tracks: list[Track]) -> list[str]:
    """Markdown: per variant the largest genuine score and the attacks' medians."""
    sigmas = sorted({t.sigma_db for t in tracks})
    kinds = ("fixed", "moving", "clone", "replay")
    head = "| input | k | c | " + " | ".join(f"max genuine σ={s:g}" for s in sigmas)
    head += " | " + " | ".join(f"{k} median (min) σ={s:g}" for s in sigmas for k in kinds) + " |"
    lines = [head, "|" + "---|" * (3 + len(sigmas) * (1 + len(kinds)))]
    for name, tr in (("changes", tracks), ("levels", [_levels(t) for t in tracks])):
        for k in (1.5, 2.0, 4.0):
            for c in (2.0, 3.0, 5.0):
                cfg = DetectorConfig(inflation=k, clip_sigma=c, threshold_nats=1e12)
                gen, att = _scores(tr, cfg)
                cells = [f"{gen.get(s, float('nan')):.1f}" for s in sigmas]
                for s in sigmas:
                    for kind in kinds:
                        v = att.get((kind, s), [])
                        cells.append(f"{np.median(v):.0f} ({min(v):.0f})" if v else "–")
                lines.append(f"| {name} | {k:g} | {c:g} | " + " | ".join(cells) + " |")
    return lines


def rows_table(rows: list[dict]) -> list[str]:
    cols = list(rows[0])
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append(
            "| "
            + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r.values())
            + " |"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", choices=sorted(PLANS), default="quick")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--grid", action="store_true", help="also the design grid")
    args = ap.parse_args(argv)
    plan = PLANS[args.plan]
    args.out.mkdir(parents=True, exist_ok=True)
    cache = args.out / "tracks.pkl"
    t0 = time.perf_counter()
    if cache.exists():
        tracks = pickle.loads(cache.read_bytes())
    else:
        tracks = run_tracks(plan, args.workers)
        cache.write_bytes(pickle.dumps(tracks))
    wall = time.perf_counter() - t0
    config = DetectorConfig()
    rows = detection_rows(tracks, config, plan.window_s)
    h = config.threshold_nats
    roc = roc_rows(tracks, config, [h * f for f in (0.5, 0.75, 1.0, 1.5, 2.0)], plan.window_s)
    minutes = {s: genuine_hours(tracks, s) * 60 for s in plan.sigmas_db}
    text = [
        f"# Spoofing detector, plan `{args.plan}`",
        "",
        f"{len(tracks)} tracks, {wall:.0f} s to simulate (0 if cached); genuine traffic: "
        + ", ".join(f"σ {s:g} dB: {m:.1f} min" for s, m in minutes.items()),
        "",
        f"## At the shipped settings ({config})",
        "",
        *rows_table(rows),
        "",
        "## ROC over the threshold",
        "",
        *rows_table(roc),
    ]
    if args.grid:
        text += ["", "## Design grid (scores in nats, attacks within 0.5 s)", ""]
        text += grid_table(tracks)
    (args.out / "summary.md").write_text("\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
