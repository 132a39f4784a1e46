"""Statistics over runs: means with 95 % confidence intervals, reductions, ratios.

The unit of replication is a run (one seeded simulated trace). For each run and
method the results table holds the mean error over that run's valid estimates;
here those per-run means are summarised across the runs of a condition:

* :func:`mean_ci` — mean with a Student-t 95 % confidence interval;
* :func:`ratio_ci` — ``mean(a) / mean(b)`` over runs paired by seed, with a
  percentile bootstrap interval (resampling runs, ``rng`` passed in);
* :func:`figure_table` — the numbers behind one :class:`FigureSpec`: mean error,
  relative reduction ``100 (1 − mean / mean_baseline)`` or relative error
  ``mean(x) / mean(x_ref)``, each with its interval.

Runs where a method produced no estimate (NaN mean) are left out of that
method's statistics; ``n`` says how many runs remain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from radiopose.evaluate.experiments import FigureSpec
from radiopose.tracker import METHODS
from radiopose.units import FloatArray

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

METRIC_COLUMN = {"position": "position_mean_m", "orientation": "orientation_mean_deg"}
"""Per-run mean error column of each quantity."""


@dataclass(frozen=True)
class Estimate:
    """A statistic with its 95 % confidence interval (NaN when undefined) and runs used."""

    value: float
    low: float
    high: float
    n: int


def mean_ci(values: FloatArray, confidence: float = 0.95) -> Estimate:
    """Mean of the finite ``values`` with a Student-t confidence interval.

    One value gives an interval of NaN; none gives NaN throughout.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return Estimate(np.nan, np.nan, np.nan, 0)
    m = float(v.mean())
    if n == 1:
        return Estimate(m, np.nan, np.nan, 1)
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * v.std(ddof=1) / np.sqrt(n))
    return Estimate(m, m - half, m + half, n)


def ratio_ci(
    a: FloatArray,
    b: FloatArray,
    rng: np.random.Generator,
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> Estimate:
    """``mean(a) / mean(b)`` over paired runs, with a percentile bootstrap interval.

    Parameters
    ----------
    a, b
        ``(n,)`` per-run values paired by index; pairs with a non-finite value are dropped.
    rng
        Random generator of the bootstrap.
    n_boot
        Bootstrap resamples.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = int(a.size)
    if n == 0 or b.mean() == 0:
        return Estimate(np.nan, np.nan, np.nan, n)
    r = float(a.mean() / b.mean())
    if n == 1:
        return Estimate(r, np.nan, np.nan, 1)
    idx = rng.integers(0, n, size=(n_boot, n))
    bb = b[idx].mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = a[idx].mean(axis=1) / bb
    boot = boot[np.isfinite(boot)]
    lo, hi = np.percentile(boot, [50 * (1 - confidence), 50 * (1 + confidence)])
    return Estimate(r, float(lo), float(hi), n)


def _select(results: pd.DataFrame, where: tuple[tuple[str, Any], ...]) -> pd.DataFrame:
    sel = np.ones(len(results), dtype=bool)
    for k, v in where:
        col = results[k]
        if isinstance(v, int | float) and not isinstance(v, bool):
            sel &= np.isclose(col.astype(float).to_numpy(), float(v))
        else:
            sel &= (col.astype(str) == str(v)).to_numpy()
    return results[sel]


def _ordered(values: Any) -> list[Any]:
    """Distinct values in order of first appearance (the sweep's order)."""
    return list(dict.fromkeys(values.tolist()))


def spec_methods(spec: FigureSpec, methods: list[str]) -> list[str]:
    """The methods a figure shows (position-only methods dropped for orientation)."""
    chosen = list(spec.methods) if spec.methods else list(methods)
    if spec.quantity == "orientation":
        chosen = [m for m in chosen if m not in METHODS or METHODS[m].estimates_orientation]
    if spec.kind == "reduction" and spec.hue == "method":
        chosen = [m for m in chosen if m != spec.baseline_method]
    return chosen


def figure_table(
    results: pd.DataFrame,
    spec: FigureSpec,
    rng: np.random.Generator,
    column: str | None = None,
) -> pd.DataFrame:
    """The numbers behind a figure: one row per (x, hue).

    Columns ``x, hue, value, low, high, n``: mean error (``error``; the
    interval's lower end clipped at 0), reduction in percent (``reduction``)
    or error ratio (``relative``) with its 95 % interval and the runs used.
    ``column`` replaces the quantity's per-run error column (e.g. a 3-D run's
    ``height_mean_m``, :data:`AXIS_SUMMARY`).
    """
    import pandas as pd

    col = column or METRIC_COLUMN[spec.quantity]
    df = _select(results, spec.where)
    methods = spec_methods(spec, _ordered(df["method"]))
    rows = []
    hues = methods if spec.hue == "method" else _ordered(df[spec.hue])
    xs = _ordered(df[spec.x])
    for h in hues:
        if spec.hue == "method":
            sub, method = df, h
        else:
            sub, method = _select(df, ((spec.hue, h),)), methods[0]
        ref_runs = None
        if spec.kind == "relative":
            ref_x = spec.reference if spec.reference is not None else xs[0]
            ref_runs = _runs(_select(sub, ((spec.x, ref_x),)), method, col)
        for x in xs:
            at = _select(sub, ((spec.x, x),))
            runs = _runs(at, method, col)
            if spec.kind == "error":
                e = mean_ci(runs.to_numpy())
                e = Estimate(e.value, max(e.low, 0.0), e.high, e.n)  # errors are >= 0
            elif spec.kind == "reduction":
                base = _runs(at, spec.baseline_method, col)
                a, b = runs.align(base, join="inner")
                r = ratio_ci(a.to_numpy(), b.to_numpy(), rng)
                e = Estimate(100 * (1 - r.value), 100 * (1 - r.high), 100 * (1 - r.low), r.n)
            else:
                assert ref_runs is not None
                a, b = runs.align(ref_runs, join="inner")
                e = ratio_ci(a.to_numpy(), b.to_numpy(), rng)
            rows.append(
                {"x": x, "hue": h, "value": e.value, "low": e.low, "high": e.high, "n": e.n}
            )
    return pd.DataFrame(rows, columns=["x", "hue", "value", "low", "high", "n"])


def _runs(df: pd.DataFrame, method: str, col: str) -> pd.Series:
    """Per-run values of one method, indexed by seed."""
    sub = df[df["method"] == method]
    return sub.set_index("seed")[col].astype(float)


AXIS_SUMMARY: tuple[tuple[str, str, str], ...] = (
    ("height_mean_m", "height_m", "height (m)"),
    ("azimuth_mean_deg", "azimuth_deg", "azimuth (°)"),
    ("pitch_mean_deg", "pitch_deg", "pitch (°)"),
    ("roll_mean_deg", "roll_deg", "roll (°)"),
)
"""A 3-D run's per-axis error columns (:data:`radiopose.evaluate.runner.AXIS_COLUMNS`):
``(per-run column, summary column, label)``."""


def condition_summary(results: pd.DataFrame) -> pd.DataFrame:
    """Per experiment, condition and method: runs, coverage and mean errors with 95 % CIs
    (and, where the results have them, the per-axis errors of 3-D runs:
    ``height_m``, ``height_low_m``, ``height_high_m``, ... as :data:`AXIS_SUMMARY`)."""
    import pandas as pd

    rows = []
    keys = ["experiment", "condition_index", "condition", "method"]
    for (exp, ci, cond, m), g in results.groupby(keys, sort=False):
        p = mean_ci(g["position_mean_m"].to_numpy(float))
        o = mean_ci(g["orientation_mean_deg"].to_numpy(float))
        rows.append(
            {
                "experiment": exp,
                "condition_index": ci,
                "condition": cond,
                "method": m,
                "runs": len(g),
                "coverage": float(g["coverage"].mean()),
                "position_m": p.value,
                "position_low_m": p.low,
                "position_high_m": p.high,
                "position_runs": p.n,
                "orientation_deg": o.value,
                "orientation_low_deg": o.low,
                "orientation_high_deg": o.high,
                "orientation_runs": o.n,
                "run_time_s": float(g["run_time_s"].mean()),
                **_axis_summary(g),
            }
        )
    return pd.DataFrame(rows)


def _axis_summary(g: pd.DataFrame) -> dict[str, float]:
    """Mean and 95 % CI of each per-axis error column present in ``g`` (runs of one
    condition and method)."""
    out: dict[str, float] = {}
    for col, name, _label in AXIS_SUMMARY:
        if col not in g.columns:
            continue
        e = mean_ci(g[col].to_numpy(float))
        base, unit = name.rsplit("_", 1)
        out |= {name: e.value, f"{base}_low_{unit}": e.low, f"{base}_high_{unit}": e.high}
    return out
