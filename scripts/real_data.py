"""Localise every track of the real BLE site and write the tables of docs/real-data.md.

    python scripts/real_data.py [--dataset DIR] [--out docs/real-data-results.md] [--quick]

Reads the dataset (default: the copy shipped in the package), localises every
track with nothing learnt from itself (radiopose.realdata.experiment) with
``filter`` (offline and causal), ``full``, ``top``, ``lms`` and the grid-HMM
anchor, on the held-out map and on the survey-only map, checks for a body-frame
pattern, and writes a Markdown file of tables (and the same numbers as JSON
beside it). ``--quick`` tries two filter settings instead of six (a smoke run: acceleration
0.2 with each likelihood).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from radiopose.realdata import experiment as X  # noqa: N812 - read as X.run_track
from radiopose.realdata.build import ImportSettings
from radiopose.realdata.tetam import read_dataset, shipped_dataset_dir
from radiopose.scripting import check_output, run_script

PUBLISHED = (
    ("best neural-network fingerprinting (2025 study)", 1.90, 1.55),
    ("earlier state of the art, as cited there", 3.06, 2.22),
    ("trilateration, as cited there", 3.73, None),
)


def _value(v: float | str) -> str:
    return v if isinstance(v, str) else f"{v:g}"


def _stats(e: np.ndarray) -> tuple[float, float, float]:
    return float(e.mean()), float(np.median(e)), float(np.percentile(e, 95))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, default=shipped_dataset_dir())
    ap.add_argument("--out", type=Path, default=Path("docs/real-data-results.md"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--tracks", nargs="+", default=None, help="Only these tracks (names).")
    args = ap.parse_args(argv)
    if not args.dataset.is_dir():
        ap.error(f"--dataset {args.dataset}: no such directory")
    if args.out.suffix == ".json":
        ap.error(f"--out {args.out}: the results' JSON is written beside it as .json; give a .md")
    # checked before the ~10 min run, not after it
    check_output(ap, "--out", files=[args.out, args.out.with_suffix(".json")])
    if args.quick:
        X.FILTER_CANDIDATES = X.FILTER_CANDIDATES[1:2] + X.FILTER_CANDIDATES[4:5]
    t0 = time.perf_counter()
    ds = read_dataset(args.dataset)
    settings = ImportSettings()
    tracks = X.load_tracks(ds, settings)
    names = [t.name for t in tracks]
    unknown = sorted(set(args.tracks or ()) - set(names))
    if unknown:  # before the tracks are localised
        ap.error(f"--tracks: no track {', '.join(map(repr, unknown))} (tracks: {', '.join(names)})")
    chosen = [t for t in tracks if args.tracks is None or t.name in args.tracks]
    results, checks, headings = [], {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        cache = X.SiteCache(ds, Path(tmp), settings)
        survey_only = cache.site(names)  # every track left out: the histograms alone
        for i, tr in enumerate(chosen, 1):
            print(f"[{i}/{len(chosen)}] {tr.name}", file=sys.stderr, flush=True)
            r = X.run_track(cache, tracks, tr)
            r.errors_m["filter, survey only"] = X.position_errors_m(
                tr.truth, X.run_filter(survey_only, tr, r.filter_settings, X.OFFLINE_LAG_S)
            )
            r.errors_m["hmm-fb, survey only"] = X.position_errors_m(
                tr.truth, X.grid_hmm(survey_only, tr.packets, smooth=True)
            )
            r.errors_m["hmm, survey only"] = X.position_errors_m(
                tr.truth, X.grid_hmm(survey_only, tr.packets)
            )
            results.append(r)
            checks[tr.name] = X.pattern_check(cache, tracks, tr.name)
            others = [t for t in tracks if t.name != tr.name]
            mode = X.most_common_heading_deg(others)
            headings[tr.name] = (mode, float(X.heading_errors_deg(tr, mode).mean()))
    variants = list(results[0].errors_m)
    lines = [
        "# Real data: results",
        "",
        "Produced by (do not edit by hand):",
        "",
        "```",
        shlex.join(["python", "scripts/real_data.py", *(sys.argv[1:] if argv is None else argv)]),
        "```",
        "",
        f"{len(results)} tracks, {sum(r.n_packets for r in results)} packets (advertisements); "
        f"{time.perf_counter() - t0:.0f} s. Position error: Euclidean distance to the camera "
        "truth (the contract's scoring), metres. Every track is localised on its held-out "
        "map (other tracks' readings added to the survey) unless the row says 'survey only'; "
        "the filter's settings for a track are chosen on the other tracks.",
        "",
        "## All tracks (pooled over packets)",
        "",
        "| method | mean (m) | median (m) | p95 (m) | coverage |",
        "|:---|---:|---:|---:|---:|",
    ]
    pooled = {}
    for v in variants:
        e = np.concatenate([r.errors_m[v] for r in results])
        n = sum(r.n_packets for r in results)
        pooled[v] = (*_stats(e), e.size / n)
        m, md, p = pooled[v][:3]
        lines.append(f"| {v} | {m:.2f} | {md:.2f} | {p:.2f} | {100 * e.size / n:.1f} % |")
    for name, m, md in PUBLISHED:
        med = "—" if md is None else f"{md:.2f}"
        lines.append(f"| published: {name} | {m:.2f} | {med} | — | — |")
    lines += [
        "",
        "## Per track (mean / median / p95, metres)",
        "",
        "| track | packets | " + " | ".join(variants) + " |",
        "|:---|---:|" + "---:|" * len(variants),
    ]
    for r in results:
        cells = []
        for v in variants:
            m, md, p = _stats(r.errors_m[v])
            cells.append(f"{m:.2f} / {md:.2f} / {p:.2f}")
        lines.append(f"| {r.name} | {r.n_packets} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Filter settings chosen per track (on the other tracks)",
        "",
        "| track | settings |",
        "|:---|:---|",
    ]
    lines += [
        f"| {r.name} | {', '.join(f'{k} {_value(v)}' for k, v in r.filter_settings)} |"
        for r in results
    ]
    lines += [
        "",
        "## Orientation: what the data allow",
        "",
        "Residual of each reading against the held-out map at the true position; the "
        "pattern is learnt from the other tracks (mean residual per 45° bin of the sensor's "
        "bearing in the beacon's frame). Heading: always answering the most common heading "
        "of the other tracks (chance: 90°).",
        "",
        "| track | residual sd (dB) | after the learnt pattern (dB) | pattern range (dB) | "
        "most common heading of the others (°) | its heading error (°) |",
        "|:---|---:|---:|---:|---:|---:|",
    ]
    for name, c in checks.items():
        mode, err = headings[name]
        lines.append(
            f"| {name} | {c.residual_sd_db:.2f} | {c.after_pattern_sd_db:.2f} | "
            f"{c.pattern_range_db:.2f} | {mode:.0f} | {err:.1f} |"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    data = {
        "pooled": {
            v: dict(zip(("mean_m", "median_m", "p95_m", "coverage"), s, strict=True))
            for v, s in pooled.items()
        },
        "tracks": {
            r.name: {
                v: dict(zip(("mean_m", "median_m", "p95_m"), _stats(e), strict=True))
                for v, e in r.errors_m.items()
            }
            for r in results
        },
        "filter_settings": {r.name: dict(r.filter_settings) for r in results},
        "pattern": {k: vars(c) for k, c in checks.items()},
        "heading": {k: {"mode_deg": m, "error_deg": e} for k, (m, e) in headings.items()},
    }
    args.out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
