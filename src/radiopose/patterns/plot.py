"""Plots of radiation patterns (the only module of ``patterns`` that uses matplotlib).

* :func:`plot_polar` — one polar slice as a polar plot in dBi, pattern azimuth
  0° to the right and counter-clockwise (as the body ``x``/``y`` axes lie when
  the screen faces the reader), like the paper's pattern figures.
* :func:`plot_sphere` — a full-sphere pattern as an azimuth × polar heat map.
* :func:`save_pattern_figure` — the figure the CLI writes (``--plot``).

Every plot function takes ``ax=None`` (a new figure is made) and returns the Axes.
"""

from __future__ import annotations

import io
import os
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.projections.polar import PolarAxes

from radiopose.patterns.pattern import Pattern
from radiopose.tables import atomic_writer


def plot_polar(
    pattern: Pattern,
    polar_deg: float = 90.0,
    ax: Axes | None = None,
    *,
    floor_dbi: float | None = None,
    label: str | None = None,
    **line_kwargs: Any,
) -> Axes:
    """Polar plot of the directivity at one polar angle.

    Parameters
    ----------
    pattern
        The pattern (a slice pattern gives its only row whatever ``polar_deg``).
    polar_deg
        Polar angle of the cut, degrees (90 = plane of the screen).
    ax
        A polar Axes to draw on; ``None`` makes a new figure.
    floor_dbi
        Radial axis minimum, dBi (default: a little under the cut's minimum).
    label
        Legend label (default: the pattern name).
    **line_kwargs
        Passed to ``Axes.plot``.

    Returns
    -------
    Axes
        The polar Axes drawn on.
    """
    if ax is None:
        _, ax = plt.subplots(subplot_kw={"projection": "polar"}, figsize=(5, 5))
    if not isinstance(ax, PolarAxes):
        raise ValueError("plot_polar needs a polar Axes (subplot_kw={'projection': 'polar'})")
    had_lines = len(ax.lines) > 0
    d_dbi = pattern.slice_dbi(polar_deg)
    az = np.append(pattern.azimuth_deg, pattern.azimuth_deg[0] + 360.0)
    d_dbi = np.append(d_dbi, d_dbi[0])  # close the curve
    ax.plot(np.deg2rad(az), d_dbi, label=label or pattern.name, **line_kwargs)
    ax.set_theta_zero_location("E")
    ax.set_theta_direction(1)
    lo = float(np.floor(d_dbi.min() - 1.0)) if floor_dbi is None else float(floor_dbi)
    hi = float(np.ceil(d_dbi.max() + 1.0))
    if had_lines:  # keep earlier curves in view
        lo, hi = min(lo, ax.get_ylim()[0]), max(hi, ax.get_ylim()[1])
    ax.set_ylim(lo, hi)
    ax.set_rlabel_position(100)
    where = "slice" if pattern.is_slice else f"polar {polar_deg:g}°"
    ax.set_title(f"{pattern.name} ({where}), directivity dBi", fontsize=10)
    return ax


def plot_sphere(pattern: Pattern, ax: Axes | None = None, *, cmap: str = "viridis") -> Axes:
    """Heat map of a pattern: azimuth (x, degrees) × polar angle (y, degrees), colour dBi.

    A slice pattern is drawn as a single band at its polar angle.

    Returns
    -------
    Axes
        The Axes drawn on.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.6))
    d = pattern.directivity_dbi.T  # (n_polar, n_azimuth)
    half_az = pattern.azimuth_step_deg / 2.0
    az0 = pattern.azimuth_deg[0] - half_az
    if pattern.is_slice:
        po = float(pattern.polar_deg[0])
        extent = (az0, az0 + 360.0, min(po + 2.0, 180.0), max(po - 2.0, 0.0))
    else:
        half_po = pattern.polar_step_deg / 2.0
        extent = (az0, az0 + 360.0, 180.0 + half_po, -half_po)
    im = ax.imshow(d, aspect="auto", extent=extent, cmap=cmap, interpolation="nearest")
    ax.figure.colorbar(im, ax=ax, label="directivity (dBi)")
    ax.set_xlabel("pattern azimuth φ (deg)")
    ax.set_ylabel("polar angle θ (deg)")
    ax.set_xticks(np.arange(0, 361, 45))
    ax.set_title(pattern.name, fontsize=10)
    return ax


def pattern_png(pattern: Pattern, *, dpi: int = 120) -> bytes:
    """PNG bytes of the standard pattern figure (see :func:`save_pattern_figure`)."""
    buf = io.BytesIO()
    _standard_figure(pattern, buf, dpi)
    return buf.getvalue()


def save_pattern_figure(pattern: Pattern, path: str | os.PathLike[str], *, dpi: int = 120) -> None:
    """Write a PNG (atomically): the 90° polar cut, plus the heat map for a full sphere."""
    data = pattern_png(pattern, dpi=dpi)
    with atomic_writer(path, "wb") as fh:
        fh.write(data)


def _standard_figure(pattern: Pattern, out: io.BytesIO, dpi: int) -> None:
    # a bare Figure (no pyplot state, no GUI backend): safe in a CLI or server
    if pattern.is_slice:
        fig = Figure(figsize=(5, 5))
        plot_polar(pattern, ax=fig.add_subplot(projection="polar"))
    else:
        fig = Figure(figsize=(11, 4.5))
        plot_polar(pattern, 90.0, ax=fig.add_subplot(1, 2, 1, projection="polar"))
        plot_sphere(pattern, ax=fig.add_subplot(1, 2, 2))
    fig.tight_layout()
    fig.savefig(out, dpi=dpi, format="png")


__all__ = ["pattern_png", "plot_polar", "plot_sphere", "save_pattern_figure"]
