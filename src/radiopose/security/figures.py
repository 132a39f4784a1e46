"""Figures of the spoofing experiments (matplotlib lives here only).

Every ``plot_*`` function takes ``ax=None`` (a new figure is made) and returns
the Axes; :func:`make_figures` draws every figure the tables allow and saves PNGs.

* :func:`plot_match_probability` — P(at least one match) with 95 % CIs beside the paper's;
* :func:`plot_match_example` — one target and every pose matching it;
* :func:`plot_path_failure` — packets until the path attack fails, per limit scale;
* :func:`plot_end_to_end` — spoofed path, the attacker's real positions and the tracker's output.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes

from radiopose.plot_site import axes_or_new
from radiopose.security.experiments import Row
from radiopose.security.report import PAPER


def _receivers(ax: Axes, sites: list[Row], run: int) -> None:
    rx = [r for r in sites if r["run"] == run]
    if rx:
        ax.scatter(
            [r["x_m"] for r in rx],
            [r["y_m"] for r in rx],
            marker="^",
            s=60,
            color="black",
            label="receivers",
            zorder=5,
        )


def _plot_xy(ax: Axes, rows: list[Row], prefix: str, fmt: str, **style: Any) -> None:
    """Plot the ``{prefix}_x_m``, ``{prefix}_y_m`` columns (metres) of ``rows``."""
    ax.plot([r[f"{prefix}_x_m"] for r in rows], [r[f"{prefix}_y_m"] for r in rows], fmt, **style)


def plot_match_probability(summary: list[Row], ax: Axes | None = None) -> Axes:
    """Bars of P(at least one match) per experiment with 95 % CIs, the paper's beside them."""
    ax = axes_or_new(ax, (5.0, 4.0), layout=None)
    rows = [r for r in summary if r["metric"] == "p_at_least_one_match"]
    x = np.arange(len(rows))
    ours = [r["value"] for r in rows]
    ci = [0.0 if not np.isfinite(r["ci95"]) else r["ci95"] for r in rows]
    paper = [PAPER[r["experiment"]]["value"] for r in rows]
    paper_ci = [PAPER[r["experiment"]]["ci95"] for r in rows]
    ax.bar(x - 0.2, ours, 0.4, yerr=ci, capsize=4, label="radiopose")
    ax.bar(x + 0.2, paper, 0.4, yerr=paper_ci, capsize=4, label="paper", alpha=0.6)
    ax.set_xticks(x, [f"{r['experiment']}\n(n={r['n_runs']} runs)" for r in rows])
    ax.set_ylim(0, 1)
    ax.set_ylabel("P(at least one match)")
    ax.set_title("Targets with a spoofing location ≥ d away")
    ax.legend()
    return ax


def plot_match_example(
    example: list[Row], sites: list[Row], experiment: str = "match", ax: Axes | None = None
) -> Axes:
    """The example target (most matching positions in run 0) and its matching poses."""
    ax = axes_or_new(ax, (5.0, 5.0), layout=None)
    rows = [r for r in example if r["experiment"] == experiment]
    _receivers(ax, sites, 0)
    if rows:
        t = rows[0]
        x = np.array([r["x_m"] for r in rows])
        y = np.array([r["y_m"] for r in rows])
        az = np.deg2rad([r["azimuth_deg"] for r in rows])
        ax.quiver(
            x,
            y,
            -np.sin(az),
            np.cos(az),
            color="tab:red",
            alpha=0.5,
            width=0.004,
            scale=25,
            label=f"matching poses ({len(rows)})",
        )
        ta = np.deg2rad(t["target_azimuth_deg"])
        ax.quiver(
            [t["target_x_m"]],
            [t["target_y_m"]],
            [-np.sin(ta)],
            [np.cos(ta)],
            color="tab:blue",
            scale=10,
            width=0.01,
            label="target",
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Experiment {experiment}: matches of one target (run 0)")
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_path_failure(paths: list[Row], ax: Axes | None = None) -> Axes:
    """Packets until the path attack failed, one marker per run, per limit scale."""
    ax = axes_or_new(ax, (5.0, 4.0), layout=None)
    scales = sorted({r["limit_scale"] for r in paths}, reverse=True)
    for i, s in enumerate(scales):
        v = np.array([r["packets_until_failure"] for r in paths if r["limit_scale"] == s])
        jitter = np.linspace(-0.15, 0.15, v.size) if v.size > 1 else np.zeros(1)
        ax.scatter(np.full(v.size, i) + jitter, v, label=f"limits × {s:g}")
    ax.axhline(100, color="grey", ls="--", label="paper: all failed within 100")
    ax.set_xticks(range(len(scales)), [f"× {s:g}" for s in scales])
    ax.set_xlabel("attacker's movement/rotation limits (fraction of the tracker's)")
    ax.set_ylabel("packets until the attack fails")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize="small")
    return ax


def plot_end_to_end(
    trace: list[Row], sites: list[Row], run: int | None = None, ax: Axes | None = None
) -> Axes:
    """Spoofed path vs where the attacker really was vs what the tracker reported.

    ``run=None`` picks the run with the most spoofed packets.
    """
    ax = axes_or_new(ax, (5.5, 5.0), layout=None)
    attack = [r for r in trace if r["source"] == "attack"]
    if run is None:
        runs = sorted({r["run"] for r in trace})
        counts = {j: sum(r["run"] == j for r in attack) for j in runs}
        run = max(runs, key=lambda j: counts[j]) if runs else 0
    _receivers(ax, sites, run)
    gen = [r for r in trace if r["run"] == run and r["source"] == "genuine"]
    att = [r for r in attack if r["run"] == run]
    if gen:
        _plot_xy(
            ax,
            gen,
            "spoofed",
            "-",
            color="tab:blue",
            lw=3,
            alpha=0.5,
            label="spoofed (target) path",
        )
        ge = [r for r in gen if r["estimated"]]
        _plot_xy(ax, ge, "est", ".", ms=3, color="tab:green", label="tracker, genuine device")
    if att:
        _plot_xy(ax, att, "sender", "s", color="tab:red", ms=4, label="attacker's real position")
        ae = [r for r in att if r["estimated"]]
        _plot_xy(ax, ae, "est", "x", color="tab:purple", ms=5, label="tracker, attack")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"End-to-end attack through the full tracker (run {run})")
    ax.legend(loc="best", fontsize="small")
    return ax


def _figures(
    tables: dict[str, list[Row]], summary: list[Row]
) -> dict[str, Callable[[Axes], object] | None]:
    """Every figure by name (``<name>.png``), in order: how to draw it, or None when the
    tables hold nothing for it. :data:`FIGURES` is its keys."""
    sites = tables.get("sites", [])
    examples = tables.get("example_matches", [])
    figures: dict[str, Callable[[Axes], object] | None] = {
        "match-probability": (lambda ax: plot_match_probability(summary, ax))
        if any(r["metric"] == "p_at_least_one_match" for r in summary)
        else None
    }
    for exp in ("match", "pattern"):
        figures[f"{exp}-example"] = (
            functools.partial(plot_match_example, examples, sites, exp)
            if any(r["experiment"] == exp for r in examples)
            else None
        )
    figures["path-failure"] = (
        (lambda ax: plot_path_failure(tables["paths"], ax)) if tables.get("paths") else None
    )
    figures["end-to-end"] = (
        (lambda ax: plot_end_to_end(tables["end_to_end"], sites, None, ax))
        if tables.get("end_to_end")
        else None
    )
    return figures


FIGURES = tuple(_figures({}, []))
"""The figures :func:`make_figures` can draw (``<name>.png``): the names ``radiopose spoof``
checks before its runs (:func:`radiopose.security.report.output_names`)."""


def make_figures(
    tables: dict[str, list[Row]], summary: list[Row], directory: str | os.PathLike[str]
) -> list[Path]:
    """Draw and save (PNG, 120 dpi) every figure the tables allow; return the paths."""
    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    out = []
    for name, draw in _figures(tables, summary).items():
        if draw is None:
            continue
        fig, ax = plt.subplots(figsize=(6.0, 5.0))
        draw(ax)
        fig.tight_layout()
        path = root / f"{name}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        out.append(path)
    return out
