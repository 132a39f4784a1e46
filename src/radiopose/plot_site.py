"""Figures of a site: the scene (receivers, survey, trajectory) and survey maps.

matplotlib lives only in plotting modules; every function takes ``ax=None``
and returns the Axes it drew on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from radiopose.site import Site
from radiopose.units import FloatArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes


def axes_or_new(
    ax: Axes | None,
    figsize: tuple[float, float] = (6.0, 6.0),
    layout: str | None = "constrained",
) -> Axes:
    """``ax``, or the Axes of a new figure of ``figsize`` inches (the one helper
    behind every plot function's ``ax=None``)."""
    if ax is not None:
        return ax
    import matplotlib.pyplot as plt

    _, new = plt.subplots(figsize=figsize, layout=layout)
    return new


def orientation_arrows(
    ax: Axes,
    xy_m: FloatArray,
    azimuth_deg: FloatArray,
    length_m: float = 0.8,
    n_arrows: int | None = None,
    **kwargs,
) -> None:
    """Draw arrows along the device's top (body ``+y``) for azimuth-only poses.

    At azimuth 0 the top points to world ``+y``; positive azimuth turns
    anticlockwise seen from above, so the arrow is ``(−sin az, cos az)``.
    ``length_m`` is the arrow length in metres; with ``n_arrows`` only that
    many poses, evenly spaced along the rows, get an arrow (none if there are
    no rows).
    """
    a = np.deg2rad(np.asarray(azimuth_deg, float))
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    if n_arrows is not None:
        if xy.shape[0] == 0:
            return
        idx = np.unique(np.linspace(0, xy.shape[0] - 1, min(n_arrows, xy.shape[0])).astype(int))
        a, xy = a[idx], xy[idx]
    ax.quiver(
        xy[:, 0],
        xy[:, 1],
        -np.sin(a) * length_m,
        np.cos(a) * length_m,
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.004,
        **kwargs,
    )


def plot_scene(
    site: Site,
    truth_xy_m: FloatArray | None = None,
    truth_azimuth_deg: FloatArray | None = None,
    ax: Axes | None = None,
    n_arrows: int = 12,
) -> Axes:
    """The site from above: area, survey points, receivers with their facing,
    and (optionally) the true trajectory with orientation arrows."""
    ax = axes_or_new(ax)
    a = site.area
    from matplotlib.patches import Rectangle

    ax.add_patch(
        Rectangle(
            (a.x_min_m, a.y_min_m),
            a.x_max_m - a.x_min_m,
            a.y_max_m - a.y_min_m,
            fill=False,
            lw=1.0,
            ec="0.4",
        )
    )
    sxy = np.unique(np.round(site.survey_rows.xyz_m[:, :2], 6), axis=0)
    ax.plot(sxy[:, 0], sxy[:, 1], ".", ms=2, color="0.6", label="survey points")
    rx = site.receiver_positions_m()
    ax.plot(rx[:, 0], rx[:, 1], "^", ms=10, color="tab:red", label="receivers")
    rx_az = np.array([r.azimuth_deg for r in site.receivers])
    orientation_arrows(ax, rx[:, :2], rx_az, 1.2, color="tab:red")
    for r in site.receivers:
        ax.annotate(r.receiver_id, (r.x_m, r.y_m), xytext=(6, 6), textcoords="offset points")
    if truth_xy_m is not None:
        t = np.asarray(truth_xy_m, float).reshape(-1, 2)
        ax.plot(t[:, 0], t[:, 1], "-", color="tab:blue", lw=1.5, label="true path")
        ax.plot(t[0, 0], t[0, 1], "o", color="tab:blue", ms=5)
        if truth_azimuth_deg is not None:
            orientation_arrows(ax, t, truth_azimuth_deg, 0.8, n_arrows, color="tab:blue")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"site '{site.name}'")
    ax.legend(loc="upper right", fontsize="small", framealpha=0.8)
    return ax


def plot_survey_map(site: Site, receiver_id: str, ax: Axes | None = None) -> Axes:
    """Interpolated channel map ``M_r`` (dB) of one receiver over the candidate grid."""
    ax = axes_or_new(ax, (6.5, 5.5))
    smap = site.survey_map
    i = smap.receiver_index(receiver_id)
    x, y = smap.x_m, smap.y_m
    im = ax.imshow(
        smap.m_db[i].T,
        origin="lower",
        extent=(x[0], x[-1], y[0], y[-1]),
        cmap="viridis",
        aspect="equal",
    )
    pts = smap.points[i]
    ax.plot(pts.xy_m[:, 0], pts.xy_m[:, 1], ".", ms=2, color="w", alpha=0.6)
    r = site.receivers[i]
    ax.plot(r.x_m, r.y_m, "^", ms=10, color="tab:red")
    ax.figure.colorbar(im, ax=ax, label="M (dB) = RSS − P_tx − D_tx")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"survey map of {receiver_id}")
    return ax
