"""Tidy tables, summary statistics and the Markdown report of the spoofing experiments.

Confidence intervals: the 95 % CI of a mean over ``n`` runs is
``mean ± t_{0.975, n−1} · s / √n`` (Student's t, ``s`` the sample standard
deviation of the per-run values); with one run it is undefined (NaN). For
experiments 1 and 2 the per-run value is the fraction of that run's targets
with at least one match — the paper's "P(at least one match) ± CI over 20 runs".
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from radiopose.security.experiments import EXPERIMENTS, Row, RunOutput, SpoofConfig
from radiopose.tables import atomic_writer, outputs_manifest, write_table

PAPER: dict[str, dict[str, Any]] = {
    "match": {"value": 0.522, "ci95": 0.040, "text": "0.522 ± 0.040"},
    "pattern": {"value": 0.547, "ci95": 0.039, "text": "0.547 ± 0.039"},
    "path": {"value": 100.0, "ci95": math.nan, "text": "every attack failed within 100 packets"},
    "e2e": {"value": math.nan, "ci95": math.nan, "text": "not in the paper"},
}
"""The paper's reported numbers ("Security Analysis")."""

TABLE_ORDER = (
    "targets",
    "example_matches",
    "paths",
    "end_to_end",
    "end_to_end_summary",
    "sites",
    "timings",
)


def output_names() -> list[str]:
    """Every file name ``radiopose spoof`` (the experiments) may write into its directory,
    its manifest (:func:`radiopose.tables.replace_outputs`) last."""
    from radiopose.security.figures import FIGURES  # imports this module: not at the top

    return [
        "report.md",
        "summary.csv",
        *(f"{name}.csv" for name in TABLE_ORDER),
        *(f"{name}.png" for name in FIGURES),
        outputs_manifest("spoof"),
    ]


def mean_ci95(values: Sequence[float]) -> tuple[float, float]:
    """Mean and 95 % CI half-width (Student's t) of per-run values; NaN half-width if n < 2."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    if v.size < 2:
        return float(v.mean()), math.nan
    half = float(stats.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return float(v.mean()), half


def collect(outputs: Sequence[RunOutput]) -> dict[str, list[Row]]:
    """Concatenate every run's rows by table (sites once per run), plus a ``timings`` table."""
    tables: dict[str, list[Row]] = {}
    seen_sites: set[int] = set()
    for out in outputs:
        for name, rows in out.tables.items():
            if name == "sites":
                if out.run in seen_sites:
                    continue
                seen_sites.add(out.run)
            tables.setdefault(name, []).extend(rows)
        tables.setdefault("timings", []).append(
            {"experiment": out.experiment, "run": out.run, "elapsed_s": out.elapsed_s}
        )
    return tables


def _rows_of(rows: list[Row], **eq: Any) -> list[Row]:
    return [r for r in rows if all(r.get(k) == v for k, v in eq.items())]


def summarise(tables: dict[str, list[Row]], experiments: Sequence[str]) -> list[Row]:
    """One row per (experiment, metric): value, CI half-width, runs, and the paper's number."""
    out: list[Row] = []

    def add(
        exp: str, metric: str, values: Sequence[float], paper: bool = False, agg: str = "mean"
    ) -> None:
        if agg == "mean":
            value, ci = mean_ci95(values)
        else:
            finite = [x for x in values if np.isfinite(x)]
            value, ci = (float(max(finite)) if finite else math.nan), math.nan
        out.append(
            {
                "experiment": exp,
                "metric": metric,
                "value": value,
                "ci95": ci,
                "n_runs": len(values),
                "paper_value": PAPER[exp]["value"] if paper else math.nan,
                "paper_ci95": PAPER[exp]["ci95"] if paper else math.nan,
            }
        )

    targets = tables.get("targets", [])
    for exp in ("match", "pattern"):
        if exp not in experiments:
            continue
        rows = _rows_of(targets, experiment=exp)
        runs = sorted({r["run"] for r in rows})
        per_run = [float(np.mean([r["matched"] for r in _rows_of(rows, run=j)])) for j in runs]
        add(exp, "p_at_least_one_match", per_run, paper=True)
        add(
            exp,
            "match_positions_per_target",
            [float(np.mean([r["n_match_positions"] for r in _rows_of(rows, run=j)])) for j in runs],
        )
        add(
            exp,
            "threshold_db2",
            [float(np.median([r["threshold_db2"] for r in _rows_of(rows, run=j)])) for j in runs],
        )
    paths = tables.get("paths", [])
    if paths and ("path" in experiments or "e2e" in experiments):
        for scale in sorted({r["limit_scale"] for r in paths}, reverse=True):
            rows = _rows_of(paths, limit_scale=scale)
            tag = f"limits_x{scale:g}"
            puf = [float(r["packets_until_failure"]) for r in rows]
            add("path", f"packets_until_failure_{tag}", puf)
            add("path", f"max_packets_until_failure_{tag}", puf, paper=True, agg="max")
            add(
                "path",
                f"failed_within_100_fraction_{tag}",
                [float(r["failed"] and r["packets_until_failure"] <= 100) for r in rows],
            )
            add("path", f"spoofed_packets_{tag}", [float(r["spoofed_packets"]) for r in rows])
    summ = tables.get("end_to_end_summary", [])
    if summ and "e2e" in experiments:
        for source in ("attack", "genuine"):
            rows = _rows_of(summ, source=source)
            for metric in (
                "followed_s",
                "followed_m",
                "within_radius_fraction",
                "median_error_to_spoofed_m",
                "median_error_to_sender_m",
            ):
                add("e2e", f"{source}_{metric}", [float(r[metric]) for r in rows])
    return out


def write_tables(
    directory: str | os.PathLike[str], tables: dict[str, list[Row]], summary: list[Row]
) -> list[Path]:
    """Write every non-empty table as ``DIR/<name>.csv`` and ``DIR/summary.csv``."""
    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    written = []
    for name in (*TABLE_ORDER, *sorted(set(tables) - set(TABLE_ORDER))):
        rows = tables.get(name) or []
        if not rows:
            continue
        written.append(_write_rows(root / f"{name}.csv", rows))
    written.append(_write_rows(root / "summary.csv", summary))
    return written


def _write_rows(path: Path, rows: list[Row]) -> Path:
    names: list[str] = []
    for r in rows:
        names += [k for k in r if k not in names]
    cols = {}
    for n in names:
        vals = [r.get(n, math.nan) for r in rows]
        if all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in vals):
            cols[n] = np.asarray(vals, dtype=np.int64)
        elif all(isinstance(v, (int, float, np.integer, np.floating)) for v in vals):
            cols[n] = np.asarray(vals, dtype=np.float64)
        else:
            cols[n] = np.asarray([str(v) for v in vals], dtype=object)
    write_table(path, cols)
    return path


def _fmt(value: float, ci: float, digits: int = 3) -> str:
    if not np.isfinite(value):
        return "–"
    if np.isfinite(ci):
        return f"{value:.{digits}f} ± {ci:.{digits}f}"
    return f"{value:.{digits}f}"


def render_report(
    summary: list[Row],
    tables: dict[str, list[Row]],
    config: SpoofConfig,
    experiments: Sequence[str],
    runs: int,
    command: str,
    figures: Sequence[str] = (),
    wall_s: float | None = None,
    where: str = "serial",
) -> str:
    """The Markdown report: numbers beside the paper's, settings, timings and figures."""
    s = config.scenario
    a = config.attacker
    lines = [
        "# Spoofing experiments — results",
        "",
        f"Command: `{command}`",
        "",
        f"Runs: {runs} per experiment; {config.n_targets} targets per run (experiments 1–2); "
        f"target paths of at most {config.path_packets} packets every {s.interval_ms:g} ms "
        f"(experiments 3–4). Site per run: simulated, {s.n_receivers} receivers at random "
        f"positions, {s.size_m:g} m × {s.size_m:g} m, {s.step_m:g} m × {s.azimuth_step_deg:g}° "
        f"candidate grid, seed {config.seed} + run.",
        f"Attacker: d = {a.min_distance_m:g} m, power P_tx ± {a.power_range_db:g} dB, "
        f"top-k = {a.k}; target RSS "
        + (
            "noise-free (the system's expected RSS)"
            if config.target_noise_db == 0
            else f"with σ = {config.target_noise_db:g} dB noise"
        )
        + f"; end-to-end packets with σ = {config.packet_noise_db:g} dB noise, "
        f"followed = within {config.follow_radius_m:g} m of the spoofed position.",
        "See [docs/security.md](../security.md) for the definitions.",
        "",
        "| experiment | metric | radiopose | paper |",
        "|---|---|---|---|",
    ]
    for r in summary:
        paper = ""
        if np.isfinite(r["paper_value"]):
            paper = PAPER[r["experiment"]]["text"]
        lines.append(
            f"| {r['experiment']} | {r['metric']} | {_fmt(r['value'], r['ci95'])} "
            f"(n={r['n_runs']}) | {paper} |"
        )
    timings = tables.get("timings", [])
    lines += [
        "",
        "## Time per run",
        "",
        "| experiment | runs | mean s/run | estimated 20 runs, 1 core (min) |",
        "|---|---|---|---|",
    ]
    for exp in EXPERIMENTS:
        el = [r["elapsed_s"] for r in timings if r["experiment"] == exp]
        if el:
            m = float(np.mean(el))
            lines.append(f"| {exp} | {len(el)} | {m:.1f} | {20 * m / 60:.1f} |")
    if wall_s is not None:
        lines.append(f"\nWall time of this command: {wall_s:.0f} s ({where}).")
    if "e2e" in experiments:
        lines += ["", "`e2e` runs include their `path` search (timed together)."]
    if figures:
        lines += ["", "## Figures", ""]
        lines += [f"![{Path(f).stem}]({Path(f).name})" for f in figures]
    lines.append("")
    return "\n".join(lines)


def write_report(path: str | os.PathLike[str], text: str) -> Path:
    """Write the report atomically."""
    with atomic_writer(path) as fh:
        fh.write(text)
    return Path(path)
