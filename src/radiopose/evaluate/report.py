"""The evaluation report: figures, tables, the paper's numbers beside ours, timing.

:func:`write_report` turns the tidy results of :func:`radiopose.evaluate.runner.run_experiments`
into ``report.md`` (figures as PNG files in ``figures/``) and a self-contained
``report.html`` (figures embedded), both built from the same blocks. The
report opens with the exact command and version, compares the ``noise``
experiment with the paper's headline numbers (:data:`PAPER`) and says where
they differ, then gives every experiment's figures and per-condition tables,
and ends with measured run times and the estimated time of a full run.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from radiopose.evaluate.blocks import Block, render_html, render_markdown
from radiopose.evaluate.experiments import Experiment, is_3d
from radiopose.evaluate.statistics import (
    AXIS_SUMMARY,
    condition_summary,
    figure_table,
    mean_ci,
    ratio_ci,
)

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd
    from matplotlib.figure import Figure

    from radiopose.evaluate.runner import RunTask


@dataclass(frozen=True)
class PaperPoint:
    """The paper's headline numbers at one noise level (4 receivers, 5 ms)."""

    noise_db: float
    orientation_mean_deg: float
    position_reduction_pct: float


PAPER: tuple[PaperPoint, ...] = (
    PaperPoint(0.5, 7.6, 82.28),
    PaperPoint(3.0, 61.8, 35.94),
)
"""Mean orientation error of the full pipeline and its mean position error
reduction versus LMS, as reported in the paper at σ = 0.5 and 3.0 dB."""


@dataclass(frozen=True)
class Invocation:
    """One ``radiopose evaluate`` invocation on an output directory.

    Attributes
    ----------
    elapsed_s
        Its wall time, seconds.
    n_computed
        Runs it computed (the others were resumed).
    workers
        Dask workers (0 = in process).
    scheduler
        ``"local"``, ``"serial"`` or the scheduler's address.
    """

    elapsed_s: float
    n_computed: int
    workers: int
    scheduler: str


def record_invocation(out_dir: str | Path, inv: Invocation) -> None:
    """Append an invocation to ``out_dir/invocations.jsonl``."""
    path = Path(out_dir) / "invocations.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(asdict(inv)) + "\n")


def read_invocations(out_dir: str | Path) -> tuple[Invocation, ...]:
    """The invocations recorded in ``out_dir`` (unreadable lines skipped)."""
    path = Path(out_dir) / "invocations.jsonl"
    if not path.exists():
        return ()
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(Invocation(**json.loads(line)))
        except (ValueError, TypeError):
            continue
    return tuple(out)


@dataclass(frozen=True)
class RunInfo:
    """How the results were produced (the report's header).

    Attributes
    ----------
    command
        The exact command line.
    version
        radiopose version (and commit, when known).
    quick
        Whether ``--quick`` was in effect.
    n_tasks
        Runs in the plan.
    invocations
        The invocations that produced the results, oldest first.
    """

    command: str
    version: str
    quick: bool
    n_tasks: int
    invocations: tuple[Invocation, ...]

    @property
    def workers(self) -> int:
        """Workers of the last invocation that computed runs (else of the last one)."""
        busy = [i for i in self.invocations if i.n_computed] or list(self.invocations)
        return busy[-1].workers if busy else 0


# ----------------------------------------------------------------------------- numbers
def _f(x: float, digits: int) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _pm(value: float, low: float, high: float, digits: int) -> str:
    if not math.isfinite(value):
        return "—"
    if not (math.isfinite(low) and math.isfinite(high)):
        return _f(value, digits)
    return f"{value:.{digits}f} ± {(high - low) / 2:.{digits}f}"


def _ci(value: float, low: float, high: float, digits: int) -> str:
    if not math.isfinite(value):
        return "—"
    if not (math.isfinite(low) and math.isfinite(high)):
        return _f(value, digits)
    return f"{value:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _one_run(results: pd.DataFrame) -> bool:
    """Whether ``results`` hold at most one run of each method per condition
    (``radiopose evaluate --runs 1``): no confidence interval exists, and the
    report says so instead of promising "± half the 95 % CI"."""
    return bool(len(results)) and int(results.groupby(["condition", "method"]).size().max()) <= 1


def _no_ci(low: float, high: float) -> bool:
    return not (math.isfinite(low) and math.isfinite(high))


COMPARED: tuple[str, ...] = ("full", "filter")
"""Methods set beside the paper's numbers: the paper's pipeline and the Bayesian tracker."""


def _method_point(
    at: pd.DataFrame, method: str, lms: pd.DataFrame, rng: np.random.Generator
) -> dict[str, float]:
    """One method's orientation (mean of run means, 95 % CI), its reduction of ``lms``'s
    mean position error (paired bootstrap 95 % CI), coverage and mean position error."""
    runs = at[at["method"] == method].set_index("seed")
    o = mean_ci(runs["orientation_mean_deg"].to_numpy(float))
    a, b = runs["position_mean_m"].align(lms["position_mean_m"], join="inner")
    r = ratio_ci(a.to_numpy(float), b.to_numpy(float), rng)
    return {
        "orientation_deg": o.value,
        "orientation_low_deg": max(o.low, 0.0),  # errors are >= 0
        "orientation_high_deg": o.high,
        "orientation_runs": o.n,
        "reduction_pct": 100 * (1 - r.value),
        "reduction_low_pct": 100 * (1 - r.high),
        "reduction_high_pct": 100 * (1 - r.low),
        "reduction_runs": r.n,
        "coverage": float(runs["coverage"].mean()) if len(runs) else np.nan,
        "position_m": float(a.mean()) if len(a) else np.nan,
        "position_lms_m": float(b.mean()) if len(b) else np.nan,
    }


def paper_comparison(results: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """Ours beside the paper's, per σ of the ``noise`` experiment.

    Columns: ``noise_db``, the full pipeline's mean orientation error (mean of
    per-run means, with 95 % CI), its mean position error reduction versus
    ``lms`` (ratio of means over runs paired by seed, bootstrap 95 % CI), the
    coverage of ``full`` and ``lms``, the runs used, and the paper's values
    where it gives them (NaN elsewhere). The same numbers for ``filter`` (the
    Bayesian tracker, beyond the paper) carry the suffix ``_filter``; they are
    NaN where the results have no ``filter`` runs.
    """
    import pandas as pd

    df = results[results["experiment"] == "noise"]
    paper = {p.noise_db: p for p in PAPER}
    rows = []
    for s in dict.fromkeys(df["noise_db"].tolist()):
        at = df[np.isclose(df["noise_db"].astype(float), float(s))]
        lms = at[at["method"] == "lms"].set_index("seed")
        full = _method_point(at, "full", lms, rng)
        p = next((v for k, v in paper.items() if abs(k - float(s)) < 1e-9), None)
        row = {
            "noise_db": float(s),
            **{k: v for k, v in full.items() if k not in ("coverage", "position_m")},
            "paper_orientation_deg": p.orientation_mean_deg if p else np.nan,
            "paper_reduction_pct": p.position_reduction_pct if p else np.nan,
            "coverage_full": full["coverage"],
            "coverage_lms": float(lms["coverage"].mean()) if len(lms) else np.nan,
            "position_full_m": full["position_m"],
        }
        flt = _method_point(at, "filter", lms, rng)
        row |= {f"{k}_filter": v for k, v in flt.items() if k != "position_lms_m"}
        rows.append(row)
    return pd.DataFrame(rows)


_NO_CI = "one run: no CI to compare with"
"""The verdict's ending where a point has a single run (no confidence interval)."""


def differences(cmp: pd.DataFrame) -> list[str]:
    """Plain statements of where the numbers differ from the paper's (one per point)."""
    out = []
    for _, r in cmp.iterrows():
        s = r["noise_db"]
        if math.isfinite(r["paper_orientation_deg"]):
            ours, paper = r["orientation_deg"], r["paper_orientation_deg"]
            lo, hi = r["orientation_low_deg"], r["orientation_high_deg"]
            inside = lo <= paper <= hi
            if not math.isfinite(ours):
                out.append(
                    f"σ = {s:g} dB: `full` gave no orientation estimate in any run "
                    f"(paper {paper:g}°)."
                )
            else:
                verdict = (
                    "within our 95 % CI"
                    if inside
                    else f"{'higher' if ours > paper else 'lower'} than the paper's by "
                    f"{abs(ours - paper):.1f}° ({ours / paper:.2g}×), "
                    + (_NO_CI if _no_ci(lo, hi) else "outside our 95 % CI")
                )
                out.append(
                    f"σ = {s:g} dB: mean orientation error of `full` "
                    f"{_ci(ours, r['orientation_low_deg'], r['orientation_high_deg'], 1)}° "
                    f"vs the paper's {paper:g}°: {verdict}."
                )
        if math.isfinite(r["paper_reduction_pct"]):
            ours, paper = r["reduction_pct"], r["paper_reduction_pct"]
            lo, hi = r["reduction_low_pct"], r["reduction_high_pct"]
            inside = lo <= paper <= hi
            if math.isfinite(ours):
                verdict = (
                    "within our 95 % CI"
                    if inside
                    else f"{'more' if ours > paper else 'less'} than the paper's by "
                    f"{abs(ours - paper):.1f} points, "
                    + (_NO_CI if _no_ci(lo, hi) else "outside our 95 % CI")
                )
                out.append(
                    f"σ = {s:g} dB: `full` reduces the mean position error of `lms` "
                    f"({_f(r['position_lms_m'], 2)} m → {_f(r['position_full_m'], 2)} m) "
                    f"by {_ci(ours, r['reduction_low_pct'], r['reduction_high_pct'], 1)} "
                    f"% vs the paper's {paper:g} %: {verdict}."
                )
        if math.isfinite(r["paper_orientation_deg"]) and math.isfinite(r["coverage_full"]):
            out.append(
                f"σ = {s:g} dB: `full` produced an estimate for "
                f"{100 * r['coverage_full']:.1f} % of packets (`lms` "
                f"{100 * r['coverage_lms']:.1f} %); errors are over those estimates only."
            )
        if math.isfinite(r.get("coverage_filter", math.nan)):
            f = {k[: -len("_filter")]: v for k, v in r.items() if k.endswith("_filter")}
            ori = _ci(f["orientation_deg"], f["orientation_low_deg"], f["orientation_high_deg"], 1)
            red = _ci(f["reduction_pct"], f["reduction_low_pct"], f["reduction_high_pct"], 1)
            out.append(
                f"σ = {s:g} dB, beyond the paper: `filter` (the Bayesian tracker) has a mean "
                f"orientation error of {ori}° and a mean position error "
                f"({_f(f['position_m'], 2)} m) {red} % below `lms`'s, at "
                f"{100 * f['coverage']:.1f} % coverage."
            )
    return out


WHY = [
    "**Scenario.** The paper does not state its path-loss parameters, its receivers' "
    "patterns or the exact trajectory distributions; radiopose's simulator uses log-distance "
    "path loss (40 dB at 1 m, exponent 3), seeded smartphone-like synthetic patterns "
    "(device range 14–20 dB) and the ranges in docs/simulation.md. Errors scale with how "
    "distinctive the device pattern is relative to σ, so a different pattern family moves "
    "every number.",
    "**Coverage.** The full pipeline only outputs an estimate when a position and an "
    "orientation cluster survive the motion models; our errors average over those packets "
    "only, and `lms`/`top` always answer. The paper does not report coverage, so a pipeline "
    "that rejects more packets (or fewer) is not compared like for like.",
    "**Averaging.** Our mean is the mean over runs of each run's mean error (each run counts "
    "once, which gives the confidence intervals); pooling all estimates, as "
    "docs/accuracy.md does, weights runs by their number of estimates.",
    "**Run length and runs.** A `--quick` report uses fewer runs and shorter traces "
    "(see the experiment's [quick] table); the trackers spend a larger share of a short trace "
    "acquiring the first estimate, and its confidence intervals are wide.",
]


def estimate_seconds(results: pd.DataFrame, tasks: Sequence[RunTask]) -> float:
    """Core-seconds the ``tasks`` would take, from the measured task times in ``results``.

    Fits ``task_s ≈ a + b·packets + c·packets·receivers`` (non-negative, least
    squares over the measured tasks; scoring grows with receivers, clustering
    with packets) and sums its prediction over ``tasks``.
    """
    from scipy.optimize import nnls

    t = results.drop_duplicates("task_key")
    if t.empty:
        return float("nan")
    n = t["n_packets"].to_numpy(float)
    rx = t["n_receivers"].to_numpy(float)
    A = np.column_stack([np.ones_like(n), n, n * rx])
    coef, _ = nnls(A, t["task_s"].to_numpy(float))
    pk = np.array([task.n_packets for task in tasks], float)
    prx = np.array([task.scenario.n_receivers for task in tasks], float)
    return float((np.column_stack([np.ones_like(pk), pk, pk * prx]) @ coef).sum())


def _hours(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "—"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


# ----------------------------------------------------------------------------- report
def _provenance(info: RunInfo) -> str:
    runs = [
        f"{i.n_computed} runs in {_hours(i.elapsed_s)} "
        f"{'in process' if i.workers == 0 else f'on {i.workers} Dask workers'} ({i.scheduler})"
        for i in info.invocations
        if i.n_computed
    ]
    idle = sum(1 for i in info.invocations if not i.n_computed)
    text = f"radiopose {info.version}; {info.n_tasks} runs: " + ("; ".join(runs) or "none computed")
    if len(runs) > 1:
        text += f" (resumed {len(runs) - 1} times)"
    if idle:
        text += f"; {idle} later invocation{'s' if idle > 1 else ''} only regenerated the report"
    return text + "."


def _method_table(
    summary: pd.DataFrame, value: str, digits: int, scale: float = 1.0, ci: bool = True
) -> tuple[list[str], list[list[str]]]:
    methods = list(dict.fromkeys(summary["method"].tolist()))
    conds = list(dict.fromkeys(summary["condition"].tolist()))
    head = ["condition", *methods]
    rows = []
    for c in conds:
        row = [c]
        for m in methods:
            g = summary[(summary["condition"] == c) & (summary["method"] == m)]
            if g.empty:
                row.append("—")
                continue
            r = g.iloc[0]
            if ci:
                base = value.rsplit("_", 1)
                low, high = f"{base[0]}_low_{base[1]}", f"{base[0]}_high_{base[1]}"
                row.append(_pm(r[value], r[low], r[high], digits))
            else:
                row.append(_f(scale * r[value], digits))
        rows.append(row)
    return head, rows


def _experiment_blocks(
    exp: Experiment, results: pd.DataFrame, out: Path, rng: np.random.Generator
) -> tuple[list[Block], list[Path]]:
    import matplotlib.pyplot as plt

    from radiopose.evaluate.figures import plot_spec

    blocks: list[Block] = [("h", 2, f"{exp.title} (`{exp.name}`)")]
    if exp.description:
        blocks.append(("p", exp.description))
    df = results[results["experiment"] == exp.name]
    single = _one_run(df)
    spread = (
        "One run per condition, so no confidence intervals: mean errors, reductions and "
        "ratios are that run's."
        if single
        else "Mean errors are means over runs of each run's mean error, ± half the 95 % "
        "confidence interval (Student t); reductions and ratios use a paired bootstrap over runs."
    )
    blocks.append(
        (
            "p",
            (
                f"{len(exp.conditions)} conditions × {exp.runs} run{'' if exp.runs == 1 else 's'} "
                f"(experiment seed {exp.seed}), methods {', '.join(exp.methods)}; "
                f"{scenario_text(exp)}{' ([quick] settings)' if exp.quick_applied else ''}. "
                f"{spread}"
            ),
        )
    )
    written: list[Path] = []
    if df.empty:
        blocks.append(("p", "No results yet."))
        return blocks, written
    for spec in exp.figures:
        ax = plot_spec(df, spec, rng=rng)
        rel = Path("figures") / f"{exp.name}-{spec.slug}.png"
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        fig = cast("Figure", ax.figure)
        fig.savefig(out / rel, dpi=110)
        plt.close(fig)
        written.append(out / rel)
        blocks.append(("img", rel.as_posix(), ax.get_title()))
        if spec.kind in ("reduction", "relative"):
            t = figure_table(df, spec, np.random.default_rng(0))
            unit = " (%)" if spec.kind == "reduction" else ""
            blocks.append(
                (
                    "table",
                    [
                        spec.x,
                        spec.hue,
                        f"{spec.kind}{unit}{'' if single else ' [95 % CI]'}",
                        "runs",
                    ],
                    [
                        [
                            str(r.x),
                            str(r.hue),
                            _ci(r.value, r.low, r.high, 2 if unit == "" else 1),
                            str(r.n),
                        ]
                        for r in t.itertuples()
                    ],
                )
            )
    summary = condition_summary(df)
    for title, value, digits in (
        ("Mean position error (m)", "position_m", 2),
        ("Mean orientation error (°)", "orientation_deg", 1),
    ):
        head, rows = _method_table(summary, value, digits)
        how = "one run (no CI)" if single else "± half the 95 % CI"
        blocks += [("p", f"**{title}**, {how}:"), ("table", head, rows)]
    head, rows = _method_table(summary, "coverage", 1, scale=100.0, ci=False)
    blocks += [
        ("p", "**Coverage (%)** — estimates ÷ packets, mean over runs:"),
        ("table", head, rows),
    ]
    if is_3d(exp):
        b, w = _axis_blocks(exp, df, summary, out, single)
        blocks += b
        written += w
    return blocks, written


def scenario_text(exp: Experiment) -> str:
    """The scenario of an experiment's first condition, in words: the 2-D grid, or for a
    3-D experiment the hand-held scenario's candidate heights, pitches and rolls."""
    sc = exp.conditions[0].scenario
    if sc.pose != "3d":
        return (
            f"{sc.size_m:g} m area, {sc.step_m:g} m / {sc.azimuth_step_deg:g}° candidates, "
            f"{sc.duration_s:g} s traces"
        )
    from radiopose.simulate.handheld import HandheldConfig

    h = HandheldConfig.from_scenario(sc)

    def span(v: tuple[float, ...]) -> str:
        step = f" every {v[1] - v[0]:g}°" if len(v) > 2 else ""
        return f"{v[0]:g}…{v[-1]:g}°{step}"

    return (
        f"3-D hand-held phone ({h.height_range_m[0]:g}–{h.height_range_m[1]:g} m high, pitch "
        f"{h.pitch_range_deg[0]:g}–{h.pitch_range_deg[1]:g}°, roll within "
        f"±{h.roll_amplitude_deg:g}°), receivers at mixed heights, {h.size_m:g} m area; site "
        f"candidates {h.step_m:g} m, heights {h.z_min_m:g}–{h.z_max_m:g} m every "
        f"{h.z_step_m:g} m, azimuths every {h.azimuth_step_deg:g}°, pitches "
        f"{span(h.pitch_deg)}, rolls {span(h.roll_deg)} (the `filter` tracks "
        f"continuously inside these ranges); a packet every {h.interval_ms:g} ms, "
        f"{h.duration_s:g} s traces"
    )


def _axis_blocks(
    exp: Experiment, df: pd.DataFrame, summary: pd.DataFrame, out: Path, single: bool = False
) -> tuple[list[Block], list[Path]]:
    """A 3-D experiment's per-axis errors: a table per method (± half the 95 % CI;
    ``single``: one run, no CI) and a figure (one panel per axis, error against
    receivers, a line per σ)."""
    import matplotlib.pyplot as plt

    from radiopose.evaluate.figures import plot_axis_errors

    blocks: list[Block] = []
    written: list[Path] = []
    names = [name for _col, name, _label in AXIS_SUMMARY]
    if not set(names) <= set(summary.columns):
        return blocks, written
    for m in dict.fromkeys(summary["method"].tolist()):
        g = summary[summary["method"] == m]
        if not np.isfinite(g["height_m"].to_numpy(float)).any():
            continue  # a method without orientation
        rows = []
        for r in g.itertuples():
            row = [str(r.condition)]
            for name in names:
                base, unit = name.rsplit("_", 1)
                digits = 2 if unit == "m" else 1
                row.append(
                    _pm(getattr(r, name), getattr(r, f"{base}_low_{unit}"),
                        getattr(r, f"{base}_high_{unit}"), digits)
                )  # fmt: skip
            rows.append(row)
        blocks += [
            (
                "p",
                f"**Per-axis mean errors of `{m}`**, "
                + (
                    "one run, no CI (the run's"
                    if single
                    else "± half the 95 % CI (mean over runs of each run's"
                )
                + " mean absolute error: height, and the wrapped azimuth, pitch and roll "
                "differences; the orientation error above is the angle of the relative rotation):",
            ),
            ("table", ["condition", *[label for _c, _n, label in AXIS_SUMMARY]], rows),
        ]
        axes = plot_axis_errors(df, m)
        rel = Path("figures") / f"{exp.name}-axis-errors-{m}.png"
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        fig = cast("Figure", axes[0].figure)
        fig.savefig(out / rel, dpi=110)
        plt.close(fig)
        written.append(out / rel)
        cis = "one run" if single else "95 % CIs"
        blocks.append(("img", rel.as_posix(), f"Per-axis mean errors of {m}, {cis}"))
    return blocks, written


def write_report(
    results: pd.DataFrame,
    experiments: Sequence[Experiment],
    out_dir: str | Path,
    info: RunInfo,
    full_tasks: Sequence[RunTask] | None = None,
    rng: np.random.Generator | None = None,
) -> list[Path]:
    """Write ``report.md``, ``report.html`` and ``figures/*.png`` into ``out_dir``.

    Parameters
    ----------
    results
        Tidy results of the experiments.
    experiments
        The experiments, in report order.
    out_dir
        Output directory.
    info
        Command, version and timing of the run.
    full_tasks
        The tasks of a full (non-quick) run, to estimate its time from the
        measured task times (omitted: no estimate).
    rng
        Random generator of the bootstrap intervals (default ``default_rng(0)``).

    Returns
    -------
    The paths written.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = rng if rng is not None else np.random.default_rng(0)
    title = "radiopose evaluation" + (" (quick)" if info.quick else "")
    blocks: list[Block] = [
        ("h", 1, title),
        ("p", "Produced by (do not edit by hand):"),
        ("code", info.command),
        ("p", _provenance(info)),
    ]
    if "noise" in set(results["experiment"]):
        cmp = paper_comparison(results, rng)
        rows = [
            [
                f"{r.noise_db:g}",
                _ci(r.orientation_deg, r.orientation_low_deg, r.orientation_high_deg, 1),
                _f(r.paper_orientation_deg, 1),
                _ci(r.reduction_pct, r.reduction_low_pct, r.reduction_high_pct, 1),
                _f(r.paper_reduction_pct, 2),
                _f(100 * r.coverage_full, 1),
                _ci(
                    r.orientation_deg_filter,
                    r.orientation_low_deg_filter,
                    r.orientation_high_deg_filter,
                    1,
                ),
                _ci(
                    r.reduction_pct_filter,
                    r.reduction_low_pct_filter,
                    r.reduction_high_pct_filter,
                    1,
                ),
                _f(100 * r.coverage_filter, 1),
                str(r.orientation_runs),
            ]
            for r in cmp.itertuples()
        ]
        blocks += [
            ("h", 2, "radiopose beside the paper"),
            (
                "p",
                "Experiment `noise` (4 receivers, a packet every 5 ms). Orientation: mean "
                "orientation error of the full pipeline. Reduction: how much lower the full "
                "pipeline's mean position error is than log-distance least squares (`lms`), "
                "100 (1 − full / lms). "
                + (
                    "One run per σ, so no confidence intervals. "
                    if _one_run(results[results["experiment"] == "noise"])
                    else "Brackets: 95 % confidence intervals over runs. "
                )
                + "The paper gives these numbers at σ = 0.5 and 3.0 dB only. The `filter` "
                "columns are the Bayesian tracker (beyond the paper, docs/filter.md), offline "
                "with its fixed-lag smoother, scored the same way.",
            ),
            (
                "table",
                [
                    "σ (dB)",
                    "orientation, radiopose (°)",
                    "orientation, paper (°)",
                    "reduction vs lms, radiopose (%)",
                    "reduction vs lms, paper (%)",
                    "coverage of full (%)",
                    "orientation, filter (°)",
                    "reduction vs lms, filter (%)",
                    "coverage of filter (%)",
                    "runs",
                ],
                rows,
            ),
            ("h", 3, "Where the numbers differ"),
            ("ul", differences(cmp)),
            ("h", 3, "Why they can differ"),
            ("ul", WHY),
        ]
    written: list[Path] = []
    for exp in experiments:
        b, w = _experiment_blocks(exp, results, out, rng)
        blocks += b
        written += w

    t = results.drop_duplicates("task_key") if len(results) else results
    timing = []
    if len(t):
        per_packet = 1000 * t["task_s"].sum() / max(float(t["n_packets"].sum()), 1.0)
        timing.append(
            f"Measured: {len(t)} runs took {t['task_s'].sum():.0f} s of worker time "
            f"(mean {t['task_s'].mean():.1f} s per run, {per_packet:.1f} ms per packet "
            "for all methods together, simulation and scoring included)."
        )
        for name, g in t.groupby("experiment", sort=False):
            timing.append(
                f"`{name}`: {len(g)} runs, mean {g['task_s'].mean():.1f} s per run "
                f"({g['n_packets'].mean():.0f} packets per run)."
            )
    if full_tasks is not None and len(t):
        core_s = estimate_seconds(results, full_tasks)
        n_workers = max(info.workers, 1)
        timing.append(
            f"Estimated full run ({len(full_tasks)} runs): {core_s / 3600:.1f} "
            f"core-hours, about {_hours(core_s / n_workers)} on {n_workers} worker"
            f"{'s' if n_workers > 1 else ''} (fitted to the measured run times above; "
            "measured on a shared machine, so an idle one is faster)."
        )
    blocks += [("h", 2, "Run time"), ("ul", timing or ["No runs."])]
    blocks += [
        ("h", 2, "Files"),
        (
            "ul",
            [
                "`results.csv`, `results.parquet`: one row per run and method (experiment, "
                "condition, seed, method, mean/median/p95 position and orientation error, "
                "coverage, run time).",
                "`parts/<experiment>.csv`: the rows as the runs finished (used to resume).",
                "`figures/`: the figures above.",
            ],
        ),
    ]

    md = out / "report.md"
    md.write_text(render_markdown(blocks), encoding="utf-8")
    page = out / "report.html"
    page.write_text(render_html(blocks, out, title), encoding="utf-8")
    return [md, page, *written]
