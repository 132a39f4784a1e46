"""Statistics over runs, figures and the report (with the paper's numbers beside ours)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from radiopose.evaluate.experiments import FigureSpec, parse_experiment
from radiopose.evaluate.figures import plot_spec
from radiopose.evaluate.report import (
    PAPER,
    Invocation,
    RunInfo,
    paper_comparison,
    write_report,
)
from radiopose.evaluate.runner import plan
from radiopose.evaluate.statistics import figure_table, mean_ci, ratio_ci

pd = pytest.importorskip("pandas")  # the eval extra

SEEDS = [11, 12, 13, 14]


def _results() -> pd.DataFrame:
    """Synthetic per-run results of a 'noise' experiment (known means)."""
    rows = []
    for s in (0.5, 3.0):
        for i, seed in enumerate(SEEDS):
            for m, pos, ori in (
                ("full", 0.2 * s, 5.0 * s + i),
                ("top", 0.3 * s, 8.0 * s),
                ("lms", 1.0 + 0 * s, np.nan),
            ):
                rows.append(
                    {
                        "experiment": "noise",
                        "condition": f"noise_db={s:g}",
                        "condition_index": int(s > 1),
                        "run": i,
                        "seed": seed,
                        "method": m,
                        "noise_db": s,
                        "n_receivers": 4,
                        "interval_ms": 5.0,
                        "duration_s": 0.05,
                        "rotation": "linear",
                        "n_packets": 10,
                        "n_estimates": 10,
                        "coverage": 1.0,
                        "position_mean_m": pos * (1 + 0.1 * i),
                        "position_median_m": pos,
                        "position_p95_m": pos,
                        "orientation_mean_deg": ori,
                        "orientation_median_deg": ori,
                        "orientation_p95_deg": ori,
                        "run_time_s": 0.1,
                        "scoring_s": 0.1,
                        "task_s": 0.5 + 0.01 * i,
                        "kernel": "numba",
                        "task_key": f"{s}-{seed}",
                    }
                )
    return pd.DataFrame(rows)


def test_mean_ci_is_the_student_t_interval():
    e = mean_ci(np.array([1.0, 2.0, 3.0, np.nan]))
    half = stats.t.ppf(0.975, 2) * 1.0 / np.sqrt(3)
    assert (e.value, e.n) == (2.0, 3)
    assert e.low == pytest.approx(2 - half) and e.high == pytest.approx(2 + half)
    assert mean_ci(np.array([np.nan])).n == 0
    assert np.isnan(mean_ci(np.array([4.0])).low)


def test_ratio_ci_of_a_constant_ratio_is_exact():
    rng = np.random.default_rng(5)
    a = np.array([1.0, 2.0, 3.0, 4.0])
    r = ratio_ci(a, 4 * a, rng)
    assert (r.value, r.low, r.high, r.n) == pytest.approx((0.25, 0.25, 0.25, 4))
    r = ratio_ci(np.array([1.0, np.nan]), np.array([2.0, 2.0]), rng)
    assert r.n == 1 and r.value == 0.5


def test_figure_table_reduction_and_relative():
    df = _results()
    rng = np.random.default_rng(0)
    red = figure_table(df, FigureSpec("reduction", "noise_db", "position"), rng)
    full = red[red["hue"] == "full"].set_index("x")["value"]
    # Run i scales every method's position error by (1 + 0.1 i): full / lms = 0.2 s.
    assert full[0.5] == pytest.approx(100 * (1 - 0.1))
    assert full[3.0] == pytest.approx(100 * (1 - 0.6))
    assert set(red["hue"]) == {"full", "top"}
    rel = figure_table(df, FigureSpec("relative", "noise_db", "position", reference=0.5), rng)
    top = rel[rel["hue"] == "top"].set_index("x")
    assert top.loc[0.5, "value"] == pytest.approx(1.0)
    assert top.loc[3.0, "value"] == pytest.approx(6.0)
    err = figure_table(df, FigureSpec("error", "noise_db", "orientation"), rng)
    assert set(err["hue"]) == {"full", "top"}  # lms has no orientation
    assert err.set_index(["x", "hue"]).loc[(3.0, "full"), "value"] == pytest.approx(16.5)


def test_plot_spec_draws_on_the_given_axes():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    out = plot_spec(_results(), FigureSpec("error", "noise_db", "position"), ax=ax)
    assert out is ax and len(ax.get_legend().get_texts()) == 3
    plt.close(fig)


def test_paper_comparison_and_report(tmp_path):
    df = _results()
    cmp = paper_comparison(df, np.random.default_rng(0)).set_index("noise_db")
    assert cmp.loc[0.5, "paper_orientation_deg"] == PAPER[0].orientation_mean_deg == 7.6
    assert cmp.loc[3.0, "paper_reduction_pct"] == 35.94
    assert cmp.loc[0.5, "orientation_deg"] == pytest.approx(2.5 + 1.5)
    exp = parse_experiment(
        {
            "name": "noise",
            "seed": 1,
            "runs": 4,
            "methods": ["full", "top", "lms"],
            "sweep": {"scenario": {"noise_db": [0.5, 3.0]}},
            "figure": [
                {"kind": "error", "x": "noise_db", "quantity": "orientation"},
                {"kind": "reduction", "x": "noise_db", "quantity": "position"},
            ],
        },
        "noise.toml",
    )
    runs = (Invocation(12.0, 5, 2, "local"), Invocation(8.0, 3, 2, "local"))
    idle = Invocation(1.0, 0, 2, "local")
    info = RunInfo("radiopose evaluate noise -o out", "0.1.0", True, 8, (*runs, idle))
    paths = write_report(df, [exp], tmp_path, info, full_tasks=plan([exp]))
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "radiopose evaluate noise -o out" in md
    assert "| 0.5 | 4.0 [" in md and "| 7.6 |" in md and "| 82.28 |" in md
    assert "8 runs: 5 runs in 12 s on 2 Dask workers (local); 3 runs in 8 s" in md
    assert "(resumed 1 times)" in md and "1 later invocation only regenerated" in md
    assert "Where the numbers differ" in md and "Estimated full run (8 runs)" in md
    assert all(p.exists() for p in paths)
    figs = sorted(p.name for p in (tmp_path / "figures").iterdir())
    assert figs == [
        "noise-error_orientation_vs_noise_db.png",
        "noise-reduction_position_vs_noise_db.png",
    ]
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert page.count("data:image/png;base64,") == 2 and 'src="figures/' not in page


def test_paper_comparison_sets_filter_beside_full(tmp_path):
    """The Bayesian tracker's numbers stand beside ``full``'s in the paper table."""
    df = _results()
    flt = df[df["method"] == "full"].copy()
    flt["method"] = "filter"
    flt["position_mean_m"] = flt["position_mean_m"] / 2  # half of full's: 95 % / 70 % below lms
    flt["orientation_mean_deg"] = 1.0
    both = pd.concat([df, flt], ignore_index=True)
    cmp = paper_comparison(both, np.random.default_rng(0)).set_index("noise_db")
    assert cmp.loc[0.5, "orientation_deg_filter"] == pytest.approx(1.0)
    assert cmp.loc[0.5, "reduction_pct_filter"] == pytest.approx(100 * (1 - 0.05))
    assert cmp.loc[3.0, "reduction_pct_filter"] == pytest.approx(100 * (1 - 0.3))
    assert cmp.loc[3.0, "coverage_filter"] == 1.0
    # full's numbers are what they were without filter runs
    alone = paper_comparison(df, np.random.default_rng(0)).set_index("noise_db")
    assert cmp.loc[3.0, "reduction_pct"] == pytest.approx(alone.loc[3.0, "reduction_pct"])
    assert np.isnan(alone.loc[3.0, "coverage_filter"])
    exp = parse_experiment(
        {
            "name": "noise",
            "seed": 1,
            "runs": 4,
            "methods": ["full", "top", "lms", "filter"],
            "sweep": {"scenario": {"noise_db": [0.5, 3.0]}},
            "figure": [{"kind": "error", "x": "noise_db", "quantity": "orientation"}],
        },
        "noise.toml",
    )
    info = RunInfo("radiopose evaluate noise -o out", "0.1.0", True, 8, ())
    write_report(both, [exp], tmp_path, info)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "orientation, filter (°)" in md and "coverage of filter (%)" in md
    assert "beyond the paper: `filter`" in md and "95.0 [" in md


def test_report_of_one_run_promises_no_ci(tmp_path):
    """``radiopose evaluate --runs 1``: one run per condition has no confidence
    interval, so the report says so instead of "± half the 95 % CI" (the tables
    already showed the bare means) or "outside our 95 % CI"."""
    df = _results()
    df = df[df["seed"] == SEEDS[0]]
    exp = parse_experiment(
        {
            "name": "noise",
            "seed": 1,
            "runs": 1,
            "methods": ["full", "top", "lms"],
            "sweep": {"scenario": {"noise_db": [0.5, 3.0]}},
            "figure": [{"kind": "reduction", "x": "noise_db", "quantity": "position"}],
        },
        "noise.toml",
    )
    info = RunInfo("radiopose evaluate noise -o out --runs 1", "0.1.0", True, 2, ())
    write_report(df, [exp], tmp_path, info)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "95 % CI" not in md and "±" not in md and "Brackets" not in md
    assert "2 conditions × 1 run (" in md and "One run per condition, so no confidence" in md
    assert "One run per σ, so no confidence intervals." in md
    assert "**Mean position error (m)**, one run (no CI):" in md
    assert "| noise_db | method | reduction (%) | runs |" in md
    assert "by 5.1° (0.33×), one run: no CI to compare with." in md
