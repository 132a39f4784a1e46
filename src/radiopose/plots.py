"""Figures of the localisation pipeline (matplotlib lives here only).

Every function takes ``ax=None`` (a new figure is made) and returns the Axes,
except :func:`mse_map_figure`, which lays out several Axes and returns the Figure.

* :func:`plot_mse_map` — one packet's MSE over the area, best orientation per
  position, for one receiver or combined (paper, Figure 2 style);
* :func:`mse_map_figure` — one panel per receiver and the combined map;
* :func:`plot_trajectory` — true vs estimated positions with orientation arrows;
* :func:`plot_orientation_error` — orientation error over time per method.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from radiopose.estimates import Estimates
from radiopose.likelihood.candidates import CandidateSpace, HeardRss, expected_rss_dbm
from radiopose.likelihood.numpy_kernel import TableScorer
from radiopose.packets import PacketObservation
from radiopose.plot_site import orientation_arrows
from radiopose.units import FloatArray

_ARROW_M = 0.5
"""Length of the orientation arrows of :func:`plot_trajectory`, metres."""


def mse_map_db2(
    space: CandidateSpace,
    packet: PacketObservation,
    receiver_id: str | None = None,
    table: TableScorer | Any = None,
) -> FloatArray:
    """MSE over the area ``(nx, ny)``, dB², minimised over orientations.

    ``receiver_id=None`` combines every receiver that heard the packet; a
    receiver id uses that receiver alone (its squared error). With ``table``
    (a :class:`~radiopose.likelihood.TableScorer` of the same space, or the
    compiled scorer, which offers ``position_mse_db2``) the map is read from its
    float32 tables — fast; otherwise computed exactly in float64.
    """
    heard = space.heard(packet)
    if receiver_id is not None:
        r = space.receiver_ids.index(receiver_id)
        sel = heard.receiver_index == r
        if not sel.any():
            raise ValueError(f"receiver {receiver_id!r} did not hear packet {packet.packet_id!r}")
        heard = HeardRss(heard.receiver_index[sel], heard.rss_dbm[sel])
    n_pos, n_o = space.n_positions, space.n_orientations
    xs = np.unique(space.positions_m[:, 0])
    if table is not None and table.supports_position_mse:  # the compiled scorer's tables
        return np.asarray(table.position_mse_db2(heard), np.float64).reshape(xs.size, -1)
    if table is not None:
        acc = np.zeros(space.n_candidates, dtype=np.float32)
        for r, rss in zip(heard.receiver_index, heard.rss_dbm, strict=True):
            d = np.float32(rss - table.centre_db[r]) - table.table[:, r]
            acc += d * d
        per_pos = (acc / heard.n_heard).reshape(n_pos, n_o).min(axis=1).astype(np.float64)
        per_pos[~np.all(table.valid[:, heard.receiver_index], axis=1)] = np.inf
        return per_pos.reshape(xs.size, -1)
    best = np.full(n_pos, np.inf)
    chunk = max(1, 1_000_000 // max(n_o * space.n_receivers, 1))
    for start in range(0, n_pos, chunk):
        stop = min(start + chunk, n_pos)
        pos = np.repeat(np.arange(start, stop), n_o)
        ori = np.tile(np.arange(n_o), stop - start)
        exp = expected_rss_dbm(space, pos, ori)
        acc = np.zeros(pos.size)
        for r, rss in zip(heard.receiver_index, heard.rss_dbm, strict=True):
            acc += (rss - exp[:, r]) ** 2
        best[start:stop] = (acc / heard.n_heard).reshape(-1, n_o).min(axis=1)
    return best.reshape(xs.size, -1)


def plot_mse_map(
    space: CandidateSpace,
    packet: PacketObservation,
    receiver_id: str | None = None,
    *,
    truth_xy_m: FloatArray | None = None,
    table: TableScorer | Any = None,
    ax: Axes | None = None,
) -> Axes:
    """Image of :func:`mse_map_db2` (dB², log colour scale), receivers as triangles."""
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4.5))
    m = mse_map_db2(space, packet, receiver_id, table)
    xs = np.unique(space.positions_m[:, 0])
    ys = np.unique(space.positions_m[:, 1])
    img = ax.pcolormesh(xs, ys, np.log10(m.T + 1e-3), shading="auto", cmap="viridis_r")
    ax.figure.colorbar(img, ax=ax, label="log10 MSE (dB²)")
    rx = space.receiver_positions_m
    ax.scatter(rx[:, 0], rx[:, 1], marker="^", c="w", edgecolors="k", s=60, label="receivers")
    if truth_xy_m is not None:
        ax.plot(truth_xy_m[0], truth_xy_m[1], "r*", ms=12, label="truth")
    ax.set_title("combined" if receiver_id is None else f"receiver {receiver_id}")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    return ax


def mse_map_figure(
    space: CandidateSpace,
    packet: PacketObservation,
    *,
    truth_xy_m: FloatArray | None = None,
    table: TableScorer | Any = None,
) -> Figure:
    """One MSE map per receiver that heard the packet, and the combined map."""
    ids = [space.receiver_ids[r] for r in space.heard(packet).receiver_index]
    n = len(ids) + 1
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.0 * rows), squeeze=False)
    for ax, rid in zip(axes.flat, [*ids, None], strict=False):
        plot_mse_map(space, packet, rid, truth_xy_m=truth_xy_m, table=table, ax=ax)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    fig.suptitle(f"MSE of packet {packet.packet_id} (best orientation per position)")
    fig.tight_layout()
    return fig


def plot_trajectory(
    truth_position_m: FloatArray,
    truth_azimuth_deg: FloatArray,
    estimates: Mapping[str, Estimates],
    *,
    receivers_xy_m: FloatArray | None = None,
    arrows: int = 12,
    ax: Axes | None = None,
) -> Axes:
    """True vs estimated positions, with azimuth arrows at ``arrows`` evenly spaced points."""
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 6))
    tp = np.asarray(truth_position_m, dtype=np.float64)
    ax.plot(tp[:, 0], tp[:, 1], "k-", lw=2, label="truth")
    orientation_arrows(ax, tp[:, :2], truth_azimuth_deg, _ARROW_M, arrows, color="k")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, est) in enumerate(estimates.items()):
        c = colours[i % len(colours)]
        ax.plot(
            est.position_m[:, 0],
            est.position_m[:, 1],
            ".",
            ms=3,
            color=c,
            label=f"{name} ({len(est)} estimates)",
        )
        orientation_arrows(
            ax, est.position_m[:, :2], est.orientation_deg[:, 0], _ARROW_M, arrows, color=c
        )
    if receivers_xy_m is not None:
        ax.scatter(
            receivers_xy_m[:, 0],
            receivers_xy_m[:, 1],
            marker="^",
            s=70,
            c="grey",
            label="receivers",
        )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize="small")
    ax.set_title("trajectory: truth vs estimates (arrows: body +y)")
    return ax


def plot_orientation_error(
    errors: Mapping[str, tuple[FloatArray, FloatArray]], *, ax: Axes | None = None
) -> Axes:
    """Orientation error (degrees) over time, one series per method: ``{name: (t_s, err_deg)}``."""
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.5))
    for name, (t, e) in errors.items():
        ax.plot(np.asarray(t), np.asarray(e), ".", ms=3, label=f"{name} ({len(e)})")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("orientation error (°)")
    ax.set_ylim(bottom=0)
    ax.legend(loc="best", fontsize="small")
    ax.set_title("orientation error over time")
    return ax
