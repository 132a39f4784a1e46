"""Evaluation figures like the paper's: errors with 95 % CIs, reductions, ratios.

Every plotting function takes the tidy results table (:mod:`radiopose.evaluate.runner`)
and a :class:`~radiopose.evaluate.experiments.FigureSpec`, draws on ``ax`` (a
new figure when ``None``) and returns the Axes. The numbers come from
:func:`radiopose.evaluate.statistics.figure_table`, so the report's tables and
its figures agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes

from radiopose.evaluate.experiments import FigureSpec, Quantity
from radiopose.evaluate.statistics import AXIS_SUMMARY, figure_table

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

AXIS_LABELS = {
    "noise_db": "packet RSS noise σ (dB)",
    "n_receivers": "number of receivers",
    "interval_ms": "packet interval (ms)",
    "rotation": "rotation",
    "duration_s": "trace length (s)",
    "method": "method",
}
METHOD_STYLE = {
    "full": ("C0", "o"),
    "location": ("C1", "s"),
    "orientation": ("C2", "^"),
    "top": ("C3", "v"),
    "lms": ("C7", "D"),
    "filter": ("C5", "o"),  # its colour in the shipped reports (it was the sixth method)
    "textbook": ("C6", "X"),  # issue 15's anchor (evaluation only)
}

_OTHER_STYLES = (("C4", "P"), ("C8", "*"), ("C9", "h"), ("k", "d"), ("C4", "x"), ("C8", "<"))
"""Styles of methods :data:`METHOD_STYLE` does not know (a plugin's): colours and
markers no built-in method uses, in turn."""


def method_style(name: str, others: list[str]) -> tuple[str, str]:
    """The colour and marker of method ``name``: its own, else the next of
    :data:`_OTHER_STYLES` by its place among ``others`` (the unknown methods of
    the figure, in order)."""
    if name in METHOD_STYLE:
        return METHOD_STYLE[name]
    if name not in others:
        others.append(name)
    return _OTHER_STYLES[others.index(name) % len(_OTHER_STYLES)]


def _label(name: str) -> str:
    return AXIS_LABELS.get(name, name)


def _ylabel(spec: FigureSpec) -> str:
    unit = "m" if spec.quantity == "position" else "°"
    if spec.kind == "error":
        return f"mean {spec.quantity} error ({unit})"
    if spec.kind == "reduction":
        return f"{spec.quantity} error reduction vs {spec.baseline_method} (%)"
    ref = (
        "first"
        if spec.reference is None
        else f"{spec.reference:g}"
        if isinstance(spec.reference, float)
        else str(spec.reference)
    )
    return f"{spec.quantity} error relative to {_label(spec.x).split(' (')[0]} = {ref}"


def _title(spec: FigureSpec) -> str:
    if spec.title:
        return spec.title
    what = {"error": "Mean error", "reduction": "Error reduction", "relative": "Relative error"}
    t = f"{what[spec.kind]}, {spec.quantity}, vs {_label(spec.x).split(' (')[0]}"
    if spec.hue != "method" and spec.methods:
        t += f" ({spec.methods[0]})"
    if spec.where:
        t += " — " + ", ".join(f"{k} = {_fmt(v)}" for k, v in spec.where)
    return t


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _numeric(xs: list[Any]) -> bool:
    return all(
        isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)
        for x in xs
    )


def plot_spec(
    results: pd.DataFrame,
    spec: FigureSpec,
    ax: Axes | None = None,
    rng: np.random.Generator | None = None,
    column: str | None = None,
) -> Axes:
    """Draw one figure: a line (with 95 % CI error bars) per method or per hue value.

    Parameters
    ----------
    results
        Tidy results of one experiment.
    spec
        What to draw.
    ax
        Axes to draw on (a new 6.4 × 4 in figure when ``None``).
    rng
        Random generator of the bootstrap intervals (``reduction``, ``relative``);
        default ``np.random.default_rng(0)``.
    column
        Per-run error column to draw instead of the quantity's (:func:`figure_table`).
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    rng = rng if rng is not None else np.random.default_rng(0)
    table = figure_table(results, spec, rng, column)
    xs = list(dict.fromkeys(table["x"].tolist()))
    hues = list(dict.fromkeys(table["hue"].tolist()))
    numeric = _numeric(xs)
    log_x = numeric and min(xs) > 0 and max(xs) / min(xs) >= 20
    pos = {x: (float(x) if numeric else i) for i, x in enumerate(xs)}
    gaps = np.diff(sorted(pos.values()))
    spacing = float(gaps.min()) if gaps.size else 1.0
    others: list[str] = []
    for j, h in enumerate(hues):
        t = table[table["hue"] == h]
        x = np.array([pos[v] for v in t["x"]], dtype=float)
        # Dodge the hues a little so that their error bars do not overlap.
        offset = j - (len(hues) - 1) / 2
        x = x * 10 ** (0.012 * offset) if log_x else x + 0.05 * offset * spacing
        y = t["value"].to_numpy(float)
        err = np.vstack([y - t["low"].to_numpy(float), t["high"].to_numpy(float) - y])
        err = np.where(np.isfinite(err), err, 0.0)
        colour, marker = (
            method_style(str(h), others) if spec.hue == "method" else (f"C{j % 10}", "o")
        )
        label = str(h) if spec.hue == "method" else f"{_label(spec.hue).split(' (')[0]} = {_fmt(h)}"
        ax.errorbar(
            x,
            y,
            yerr=err,
            color=colour,
            marker=marker,
            capsize=3,
            lw=1.4,
            ms=5,
            label=label,
            linestyle="-" if numeric else "none",
        )
    if log_x:
        ax.set_xscale("log")
    if not numeric:
        ax.set_xlim(-0.6, len(xs) - 0.4)
    ax.set_xticks([pos[x] for x in xs], [_fmt(x) for x in xs])
    if log_x:
        ax.minorticks_off()
    if spec.kind == "reduction":
        ax.axhline(0.0, color="0.5", lw=0.8)
    if spec.kind == "relative":
        ax.axhline(1.0, color="0.5", lw=0.8)
    ax.set_xlabel(_label(spec.x))
    ax.set_ylabel(_ylabel(spec))
    ax.set_title(_title(spec), fontsize=10)
    ax.grid(True, alpha=0.3)
    if hues:
        ax.legend(fontsize=8)
    return ax


def plot_axis_errors(
    results: pd.DataFrame,
    method: str,
    x: str = "n_receivers",
    hue: str = "noise_db",
    axes: Sequence[Axes] | None = None,
) -> list[Axes]:
    """The per-axis errors of 3-D runs (height, azimuth, pitch, roll), one panel each:
    mean over runs of each run's mean absolute error against ``x``, a line per
    ``hue`` value, 95 % CI error bars (as :func:`plot_spec` draws an ``error`` figure).

    Parameters
    ----------
    results
        Tidy results of one 3-D experiment (with ``height_mean_m`` ... columns).
    method
        The method drawn.
    x, hue
        Swept parameters on the horizontal axis and as lines.
    axes
        Four Axes to draw on (a new 1 × 4 figure when ``None``).

    Returns
    -------
    The four Axes.
    """
    if axes is None:
        fig, grid = plt.subplots(1, 4, figsize=(14.0, 3.6), layout="constrained")
        axes = list(grid)
        fig.suptitle(f"Per-axis mean errors of {method} (3-D pose)", fontsize=11)
    out: list[Axes] = []
    for ax, (col, _name, label) in zip(axes, AXIS_SUMMARY, strict=True):
        quantity: Quantity = "position" if col.endswith("_m") else "orientation"
        spec = FigureSpec("error", x, quantity, hue=hue, methods=(method,), title=label)
        plot_spec(results, spec, ax=ax, column=col)
        ax.set_ylabel(f"mean {label.replace(' (', ' error (')}")
        ax.set_ylim(bottom=0.0)
        legend = ax.get_legend()
        if out and legend is not None:  # one legend (the first panel's) is enough
            legend.remove()
        out.append(ax)
    return out
