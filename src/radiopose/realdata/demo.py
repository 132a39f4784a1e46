"""``radiopose demo --real``: the shipped BLE tracking site, imported, localised, drawn.

No network and no ``../shared``: the dataset ships inside the package
(``radiopose/data/ble-tetam``, CC0). The demo imports it (``radiopose import
tetam``), localises every track with ``filter`` on the track's held-out site
(the survey plus the *other* tracks' readings; the site's ``tracker.toml``
settings) and with ``lms``, prints the error table, and draws truth vs
estimates per track and the error over time. The strictly cross-validated
numbers (settings chosen per track on the other tracks, every anchor) come from
``scripts/real_data.py`` (docs/real-data.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def run_real_demo(out_dir: str | Path, *, echo: Callable[[str], None] = print) -> list[Path]:
    """Run the real-data demo into ``out_dir``; return the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radiopose.estimates import write_estimates_csv
    from radiopose.packets import read_packets_csv, read_truth_csv
    from radiopose.realdata.build import import_tetam, shipped_import_settings
    from radiopose.realdata.experiment import position_errors_m
    from radiopose.realdata.figures import plot_errors_over_time, plot_track
    from radiopose.realdata.tetam import shipped_dataset_dir
    from radiopose.site_io import load_site
    from radiopose.tables import staged_directory, staged_echo
    from radiopose.tracker import TrackerConfig, locate
    from radiopose.tracker_settings import load_site_tracker_settings

    t0 = time.perf_counter()
    out = Path(out_dir)
    with staged_directory(out) as stage:
        say = staged_echo(echo, stage, out)

        summary = import_tetam(shipped_dataset_dir(), stage / "data", shipped_import_settings())
        say(f"imported the BLE tracking site (CC0): {summary.lines()[1]}")
        rows, over_time, written = [], [], []
        names = sorted(summary.packets)
        fig, axes = plt.subplots(
            2, (len(names) + 1) // 2, figsize=(4.2 * ((len(names) + 1) // 2), 8)
        )
        for ax, name in zip(axes.ravel(), names, strict=False):
            d = stage / "data" / "tracks" / name
            site = load_site(d / "heldout-site")
            overrides, lag_s, _ = load_site_tracker_settings(d / "heldout-site")
            base = TrackerConfig()
            cfg = replace(base, filter=replace(base.filter, **overrides), smoothing_lag_s=lag_s)
            packets, truth = read_packets_csv(d / "packets.csv"), read_truth_csv(d / "truth.csv")
            est = {m: locate(site, packets, m, cfg).estimates for m in ("filter", "lms")}
            for m, e in est.items():
                write_estimates_csv(e, d / f"estimates-{m}.csv")
            err = {m: position_errors_m(truth, e) for m, e in est.items()}
            rows.append((name, len(truth), err["filter"], err["lms"]))
            over_time.append((name, est["filter"].timestamp_s, err["filter"]))
            plot_track(
                site,
                truth.position_m[:, :2],
                {m: e.position_m[:, :2] for m, e in est.items()},
                f"{name}: filter {err['filter'].mean():.2f} m, lms {err['lms'].mean():.2f} m",
                ax=ax,
            )
        for ax in axes.ravel()[len(names) :]:
            ax.set_visible(False)
        axes.ravel()[0].legend(fontsize=7, loc="upper left")
        fig.tight_layout()
        fig.savefig(stage / "real-tracks.png", dpi=90)
        plt.close(fig)
        ax = plot_errors_over_time(over_time)
        ax.set_title("filter (offline), position error over time")
        fig = cast("Figure", ax.figure)
        fig.tight_layout()
        fig.savefig(stage / "real-error-over-time.png", dpi=100)
        plt.close(fig)
        written = [stage / "real-tracks.png", stage / "real-error-over-time.png"]
        say("")
        say(f"{'track':30s} {'packets':>7s}   filter mean / median / p95 (m)   lms mean (m)")
        for name, n, ef, el in rows:
            say(
                f"{name:30s} {n:7d}   {ef.mean():5.2f} / {np.median(ef):5.2f} / "
                f"{np.percentile(ef, 95):5.2f}        {el.mean():5.2f}"
            )
        ef = np.concatenate([r[2] for r in rows])
        el = np.concatenate([r[3] for r in rows])
        say(
            f"{'all tracks':30s} {ef.size:7d}   {ef.mean():5.2f} / {np.median(ef):5.2f} / "
            f"{np.percentile(ef, 95):5.2f}        {el.mean():5.2f}"
        )
        say(
            "each track on its held-out site (its own readings never in the map); settings "
            "from the site's tracker.toml. docs/real-data.md: the cross-validated table."
        )
        for p in written:
            say(f"wrote {p}")
    echo(f"real-data demo finished in {time.perf_counter() - t0:.1f} s")
    return [out / p.relative_to(stage) for p in written]
