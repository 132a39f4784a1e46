"""The ``3d`` experiment's evaluation: per-axis errors in the result rows, the 3-D
scenario described in the report, the per-axis table with 95 % CIs and its figure
(docs/pose3d.md, "The `3d` experiment").

* a run of a small 3-D experiment records height, azimuth, pitch and roll errors
  equal to :func:`radiopose.evaluate.pose3d.axis_errors` of the same run done by
  hand; a 2-D experiment's rows have no such columns;
* the report of 3-D results says what was simulated (heights, pitches, rolls; not
  the 2-D grid) and gives the per-axis means ± half the Student-t 95 % interval;
* the shipped ``3d`` experiment draws error against receivers, a line per σ.

Seed 18218 (the small experiment) is used here only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from radiopose.evaluate.experiments import is_3d, load_experiment, parse_experiment
from radiopose.evaluate.pose3d import axis_errors
from radiopose.evaluate.report import Invocation, RunInfo, scenario_text, write_report
from radiopose.evaluate.runner import AXIS_COLUMNS, columns_for, plan, run_task
from radiopose.evaluate.statistics import condition_summary, mean_ci
from radiopose.simulate import simulate
from radiopose.tracker import locate

pd = pytest.importorskip("pandas")  # the eval extra

SMALL = {
    "name": "small3d",
    "seed": 18218,
    "runs": 1,
    "methods": ["filter", "lms"],
    "scenario": {"pose": "3d", "duration_s": 0.15, "interval_ms": 10.0},
    "sweep": {"scenario": {"n_receivers": [6]}},
}


def test_a_3d_run_records_the_per_axis_errors():
    exp = parse_experiment(SMALL, "small3d.toml")
    assert is_3d(exp)
    assert list(AXIS_COLUMNS) == [c for c in columns_for(exp) if c in AXIS_COLUMNS]
    (task,) = plan([exp])
    rows = {r["method"]: r for r in run_task(task)}
    assert all(np.isnan(rows["lms"][c]) for c in AXIS_COLUMNS)  # no orientation
    sim = simulate(task.scenario, task.seed)
    est = locate(sim.site, sim.packets, "filter", task.tracker).estimates
    means = axis_errors(sim.truth, est).means()
    got = [rows["filter"][c] for c in AXIS_COLUMNS]
    want = [means[k] for k in ("height_m", "azimuth_deg", "pitch_deg", "roll_deg")]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert rows["filter"]["position_mean_m"] == pytest.approx(means["position_m"])
    assert rows["filter"]["orientation_mean_deg"] == pytest.approx(means["rotation_deg"])


def test_a_2d_experiment_has_no_axis_columns():
    exp = load_experiment("noise", quick=True)
    assert not is_3d(exp)
    assert not set(AXIS_COLUMNS) & set(columns_for(exp))
    text = scenario_text(exp)
    assert text.startswith("20 m area, 0.1 m / 1° candidates")


def _results3d(exp) -> pd.DataFrame:  # type: ignore[no-untyped-def]
    """Synthetic rows of the 3-D experiment: known per-axis errors per condition."""
    rows = []
    for c in exp.conditions:
        n_rx = dict(c.params)["n_receivers"]
        for run in range(exp.runs):
            rows.append({
                "experiment": exp.name, "condition": c.label, "condition_index": c.index,
                "run": run, "seed": 100 * c.index + run, "method": "filter",
                "noise_db": 1.0, "n_receivers": n_rx, "interval_ms": 5.0, "duration_s": 1.0,
                "rotation": "linear", "n_packets": 200, "n_estimates": 200, "coverage": 1.0,
                "position_mean_m": 2.0 / n_rx + 0.01 * run, "position_median_m": 0.1,
                "position_p95_m": 0.2, "orientation_mean_deg": 60.0 / n_rx + run,
                "orientation_median_deg": 5.0, "orientation_p95_deg": 9.0,
                "height_mean_m": 0.3 - 0.02 * n_rx + 0.01 * run,
                "azimuth_mean_deg": 40.0 / n_rx + run, "pitch_mean_deg": 20.0 / n_rx + 0.5 * run,
                "roll_mean_deg": 30.0 / n_rx + 2.0 * run, "run_time_s": 1.0, "scoring_s": 0.0,
                "task_s": 2.0, "kernel": "", "task_key": f"{c.index}-{run}",
            })  # fmt: skip
    return pd.DataFrame(rows)


def test_the_report_describes_the_3d_scenario_and_its_axes(tmp_path: Path):
    exp = load_experiment("3d", quick=True).with_runs(3)
    results = _results3d(exp)
    info = RunInfo(
        "radiopose evaluate 3d --quick", "0.1.0", True, 9, (Invocation(9.0, 9, 1, "local"),)
    )
    written = write_report(results, [exp], tmp_path, info)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "3-D hand-held phone" in md and "heights 0.6–1.8 m every 0.2 m" in md
    assert "pitches 0…90° every 15°" in md and "rolls -45…45° every 15°" in md
    assert "° candidates" not in md  # not the 2-D grid
    assert "**Per-axis mean errors of `filter`**" in md
    # each cell is the mean over runs ± half the Student-t 95 % interval
    summary = condition_summary(results)
    for c in exp.conditions:
        runs = results[results["condition"] == c.label]
        for col, digits in (("height_mean_m", 2), ("roll_mean_deg", 1)):
            e = mean_ci(runs[col].to_numpy())
            cell = f"{e.value:.{digits}f} ± {(e.high - e.low) / 2:.{digits}f}"
            row = next(line for line in md.splitlines() if line.startswith(f"| {c.label} |")
                       and cell in line)  # fmt: skip
            assert row
        s = summary[summary["condition"] == c.label].iloc[0]
        assert s["pitch_deg"] == pytest.approx(runs["pitch_mean_deg"].mean())
    fig = tmp_path / "figures" / "3d-axis-errors-filter.png"
    assert fig in written and fig.stat().st_size > 10_000
    assert "figures/3d-axis-errors-filter.png" in md
    # the shipped figures: error against receivers, a line per σ
    assert {(f.x, f.hue) for f in exp.figures} == {("n_receivers", "noise_db")}


def test_plot_axis_errors_draws_four_panels_with_the_means():
    from radiopose.evaluate.figures import plot_axis_errors

    exp = load_experiment("3d", quick=True).with_runs(2)
    results = _results3d(exp)
    axes = plot_axis_errors(results, "filter")
    assert [ax.get_title() for ax in axes] == ["height (m)", "azimuth (°)", "pitch (°)", "roll (°)"]
    xs, ys = axes[0].lines[0].get_data()
    want = results.groupby("n_receivers")["height_mean_m"].mean()
    np.testing.assert_allclose(ys, want.loc[list(xs)].to_numpy())
    import matplotlib.pyplot as plt

    plt.close(axes[0].figure)


def test_the_shipped_3d_quick_run_is_small():
    exp = load_experiment("3d", quick=True)
    assert [dict(c.params)["n_receivers"] for c in exp.conditions] == [4, 6, 8]
    assert exp.runs == 2 and exp.conditions[0].scenario.duration_s == 1.0
    assert is_3d(exp) and is_3d(load_experiment("3d"))


def test_a_one_run_3d_report_promises_no_ci(tmp_path: Path):
    """``--runs 1``: the per-axis tables say one run and no CI (they promised
    "± half the 95 % CI", which one run does not have)."""
    exp = load_experiment("3d", quick=True).with_runs(1)
    info = RunInfo("radiopose evaluate 3d --quick --runs 1", "0.1.0", True, 3, ())
    write_report(_results3d(exp), [exp], tmp_path, info)
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "**Per-axis mean errors of `filter`**, one run, no CI (the run's mean" in md
    assert "95 % CI" not in md and " ± " not in md  # (the scenario's roll "within ±25°" stays)
