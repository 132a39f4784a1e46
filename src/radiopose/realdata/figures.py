"""Figures of the real-data demo: truth vs estimates per track, error over time."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

    from radiopose.site import Site


def plot_track(
    site: Site,
    truth_xy_m: np.ndarray,
    estimates_xy_m: Mapping[str, np.ndarray],
    title: str = "",
    ax: Axes | None = None,
) -> Axes:
    """One track: the receivers, the camera truth and each method's estimates (metres)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5.0, 4.5))
    rx = site.receiver_positions_m()
    ax.plot(rx[:, 0], rx[:, 1], "^", color="tab:blue", ms=6, label="sensors")
    ax.plot(truth_xy_m[:, 0], truth_xy_m[:, 1], "-", color="black", lw=2.0, label="camera truth")
    styles = {"filter": ("tab:red", ".-", 1.0), "lms": ("tab:gray", ".", 0.5)}
    for name, xy in estimates_xy_m.items():
        colour, fmt, alpha = styles.get(name, ("tab:green", ".-", 0.8))
        ax.plot(xy[:, 0], xy[:, 1], fmt, color=colour, lw=1.2, ms=2.5, alpha=alpha, label=name)
    a = site.area
    ax.set_xlim(a.x_min_m, a.x_max_m)
    ax.set_ylim(a.y_min_m, a.y_max_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    return ax


def plot_errors_over_time(
    tracks: Sequence[tuple[str, np.ndarray, np.ndarray]], ax: Axes | None = None
) -> Axes:
    """Position error (m) against time since the track's start (s), one line per track;
    ``tracks`` holds ``(name, time_s, error_m)``."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8.0, 3.5))
    for name, t, e in tracks:
        ax.plot(t - t[0], e, lw=1.0, label=name)
    ax.set_xlabel("time since the track's start (s)")
    ax.set_ylabel("position error (m)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    return ax
