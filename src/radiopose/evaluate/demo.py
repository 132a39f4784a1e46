"""Running every method on a simulation, error tables, and the demo pipeline.

:func:`~radiopose.evaluate.method_runs.run_methods` (re-exported here, its old
home) runs the methods on one :class:`Simulation`.
:func:`summarise` turns pooled errors into table rows (mean / median / p95 of
position and orientation error, with coverage). :func:`run_demo_pipeline` is
what ``radiopose demo`` calls: every method on the demo's walk, the table, the
``filter``'s calibration, and the figures of :mod:`radiopose.plots`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from radiopose.estimates import write_estimates_csv
from radiopose.evaluate.method_runs import MethodRun, build_scorer, run_methods
from radiopose.evaluate.scoring import ErrorStats, error_stats
from radiopose.likelihood import TableScorer
from radiopose.packets import group_packets
from radiopose.simulate import Simulation
from radiopose.tracker import METHOD_NAMES, METHODS, TrackerConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "Calibration",
    "MethodRun",
    "TableRow",
    "build_scorer",
    "calibration",
    "format_table",
    "run_demo_pipeline",
    "run_methods",
    "summarise",
]


@dataclass(frozen=True)
class TableRow:
    """One row of an accuracy table (errors pooled over runs).

    Attributes
    ----------
    method
        Method name.
    noise_db
        Packet RSS noise σ, dB (NaN when not applicable).
    coverage
        Estimates ÷ packets over all runs.
    position_m, orientation_deg
        Error statistics (orientation ``n = 0`` for position-only methods).
    n_runs
        Runs pooled.
    """

    method: str
    noise_db: float
    coverage: float
    position_m: ErrorStats
    orientation_deg: ErrorStats
    n_runs: int


def summarise(runs: Iterable[MethodRun], noise_db: float = float("nan")) -> TableRow:
    """Pool one method's runs into a table row."""
    runs = list(runs)
    if not runs:
        raise ValueError("no runs to summarise")
    n_pk = sum(r.n_packets for r in runs)
    n_est = sum(len(r.estimates) for r in runs)
    pos = np.concatenate([r.position_error_m for r in runs])
    ori = np.concatenate([r.orientation_error_deg for r in runs])
    return TableRow(
        runs[0].method,
        noise_db,
        n_est / n_pk if n_pk else 0.0,
        error_stats(pos),
        error_stats(ori),
        len(runs),
    )


def _fmt(x: float | None, digits: int) -> str:
    return "—" if x is None else f"{x:.{digits}f}"


def format_table(rows: Sequence[TableRow]) -> str:
    """A Markdown table of rows: σ, method, coverage, position and orientation stats."""
    head = (
        "| σ (dB) | method | coverage | pos mean (m) | pos median (m) | pos p95 (m) "
        "| ori mean (°) | ori median (°) | ori p95 (°) |\n"
        "|---:|:---|---:|---:|---:|---:|---:|---:|---:|"
    )
    lines = [head]
    for r in rows:
        p, o = r.position_m, r.orientation_deg
        lines.append(
            f"| {r.noise_db:g} | {r.method} | {100 * r.coverage:.1f} % | {_fmt(p.mean, 2)} "
            f"| {_fmt(p.median, 2)} | {_fmt(p.p95, 2)} | {_fmt(o.mean, 1)} "
            f"| {_fmt(o.median, 1)} | {_fmt(o.p95, 1)} |"
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class Calibration:
    """How often a tracker's stated uncertainty covers its actual error.

    Attributes
    ----------
    method
        Method name.
    position_within_2sd, orientation_within_2sd
        Fraction of estimates whose position (orientation) error is at most
        twice the stated ``position_std_m`` (``azimuth_std_deg``).
    median_position_std_m, median_azimuth_std_deg
        Median stated uncertainties.
    """

    method: str
    position_within_2sd: float
    orientation_within_2sd: float
    median_position_std_m: float
    median_azimuth_std_deg: float


def calibration(run: MethodRun) -> Calibration | None:
    """:class:`Calibration` of a run whose estimates state an uncertainty, else ``None``."""
    est = run.estimates
    if est.position_std_m is None or est.azimuth_std_deg is None or len(est) == 0:
        return None
    ori = run.orientation_error_deg
    return Calibration(
        run.method,
        float(np.mean(run.position_error_m <= 2.0 * est.position_std_m)),
        float(np.mean(ori <= 2.0 * est.azimuth_std_deg)) if ori.size else float("nan"),
        float(np.median(est.position_std_m)),
        float(np.median(est.azimuth_std_deg)),
    )


def run_demo_pipeline(
    sim: Simulation,
    out_dir: str | Path,
    *,
    config: TrackerConfig | None = None,
    echo: Callable[[str], None] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> tuple[list[TableRow], list[Path]]:
    """Every method on a simulation, an error table and the figures.

    Writes ``estimates_<method>.csv``, ``mse_map.png`` (first packet: each
    receiver's and the combined MSE over the area, best orientation per
    position), ``trajectory.png`` (truth vs ``full`` and ``top`` with
    orientation arrows), ``orientation_error.png`` (over time, every method
    that estimates orientation) and ``filter_track.png`` (the ``filter``'s
    track with its stated uncertainty beside ``full``'s estimates and the
    truth, azimuth and errors over time: :func:`radiopose.plots.track_figure`)
    into ``out_dir``, and prints the table and the ``filter``'s calibration.
    ``progress(method, done, total)`` follows each method's packets.

    Returns
    -------
    The table rows (one per method) and the paths written.
    """
    import matplotlib.pyplot as plt

    from radiopose import plots

    say = echo or (lambda _s: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scorer = build_scorer(sim, (config or TrackerConfig()).kernel)
    # every registered method: the built-in six, then any plugin's (docs/methods.md)
    names = (*METHOD_NAMES, *(m for m in METHODS if m not in METHOD_NAMES))
    runs = run_methods(sim, names, config, scorer, progress)
    rows = [summarise([runs[m]], sim.config.noise_db) for m in names]
    say(format_table(rows))
    cal = calibration(runs["filter"])
    if cal is not None:
        say(
            "filter's stated uncertainty: median position_std_m "
            f"{cal.median_position_std_m:.2f} m, azimuth_std_deg "
            f"{cal.median_azimuth_std_deg:.1f}°; the error is within twice it "
            f"for {100 * cal.position_within_2sd:.0f} % (position) and "
            f"{100 * cal.orientation_within_2sd:.0f} % (orientation) of the packets"
        )
    written: list[Path] = []
    for m, r in runs.items():
        p = out / f"estimates_{m}.csv"
        write_estimates_csv(r.estimates, p)
        written.append(p)

    first = group_packets(sim.packets)[0]
    inner = getattr(scorer, "inner", scorer)
    fast = isinstance(inner, TableScorer) or inner.supports_position_mse
    table = inner if fast else None
    fig = plots.mse_map_figure(
        scorer.space, first, truth_xy_m=sim.truth.position_m[0, :2], table=table
    )
    written.append(_save(fig, out / "mse_map.png"))
    plt.close(fig)

    rx_xy = sim.site.receiver_positions_m()[:, :2]
    ax = plots.plot_trajectory(
        sim.truth.position_m,
        sim.truth.orientation_deg[:, 0],
        {m: runs[m].estimates for m in ("full", "top")},
        receivers_xy_m=rx_xy,
    )
    written.append(_save(ax.figure, out / "trajectory.png"))
    plt.close(cast("Figure", ax.figure))

    ax = plots.plot_orientation_error(
        {
            m: (runs[m].estimates.timestamp_s, runs[m].orientation_error_deg)
            for m in runs
            if METHODS[m].estimates_orientation
        }
    )
    written.append(_save(ax.figure, out / "orientation_error.png"))
    plt.close(cast("Figure", ax.figure))

    f, full = runs["filter"], runs["full"]
    if f.estimates.position_std_m is not None:
        fig = plots.track_figure(
            sim.truth.timestamp_s,
            sim.truth.position_m,
            sim.truth.orientation_deg[:, 0],
            f.estimates,
            (f.position_error_m, f.orientation_error_deg),
            {"full": (full.estimates, full.position_error_m, full.orientation_error_deg)},
            n_packets=f.n_packets,
            receivers_xy_m=rx_xy,
            title=_scenario_title(sim),
        )
        written.append(_save(fig, out / "filter_track.png"))
        plt.close(fig)
    for p in written:
        say(f"wrote {p}")
    return rows, written


def _scenario_title(sim: Simulation) -> str:
    c = sim.config
    return (
        f"filter vs full: {c.duration_s:g} s, a packet every {c.interval_ms:g} ms, "
        f"{len(sim.site.receivers)} receivers, σ = {c.noise_db:g} dB (seed {sim.seed})"
    )


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    return path
