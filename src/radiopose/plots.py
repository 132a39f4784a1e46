"""Figures of the localisation pipeline (matplotlib lives here only).

Every function takes ``ax=None`` (a new figure is made) and returns the Axes,
except :func:`mse_map_figure`, which lays out several Axes and returns the Figure.

* :func:`plot_mse_map` — one packet's MSE over the area, best orientation per
  position, for one receiver or combined (paper, Figure 2 style);
* :func:`mse_map_figure` — one panel per receiver and the combined map;
* :func:`plot_trajectory` — true vs estimated positions with orientation arrows;
* :func:`plot_orientation_error` — orientation error over time per method;
* :func:`plot_track_uncertainty` — a tracker's track with its stated position
  uncertainty (a band of discs of radius ``position_std_m``) and azimuth
  wedges (± ``azimuth_std_deg``), beside sparse estimates and the truth;
* :func:`plot_azimuth_over_time` — true and estimated azimuth over time, the
  tracker's with a ± ``azimuth_std_deg`` band;
* :func:`plot_error_over_time` — one error (position or orientation) over
  time per method, coverage in the legend, a tracker's stated σ dashed;
* :func:`track_figure` — the four above in one figure (``radiopose demo``'s
  ``filter_track.png``);
* :func:`pose3d_figure` — a 3-D track: the top view with its uncertainty,
  height, azimuth, pitch and roll over time against the truth, and the
  position and rotation-angle errors (``radiopose demo --pose 3d``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from radiopose.estimates import Estimates
from radiopose.likelihood.candidates import CandidateSpace, HeardRss
from radiopose.likelihood.maps import position_mse_db2
from radiopose.likelihood.numpy_kernel import TableScorer
from radiopose.packets import PacketObservation
from radiopose.plot_site import orientation_arrows
from radiopose.units import FloatArray, angle_diff_deg

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
    (a scorer of the same space that offers ``position_mse_db2``: the
    :class:`~radiopose.likelihood.TableScorer` or the compiled scorer) the map is
    read from its float32 tables — fast; otherwise computed exactly in float64
    (:func:`radiopose.likelihood.maps.position_mse_db2` either way).
    """
    heard = space.heard(packet)
    if receiver_id is not None:
        r = space.receiver_ids.index(receiver_id)
        sel = heard.receiver_index == r
        if not sel.any():
            raise ValueError(f"receiver {receiver_id!r} did not hear packet {packet.packet_id!r}")
        heard = HeardRss(heard.receiver_index[sel], heard.rss_dbm[sel])
    xs = np.unique(space.positions_m[:, 0])
    return position_mse_db2(space, heard, table).reshape(xs.size, -1)


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
        _, ax = plt.subplots(figsize=(6, 6), layout="constrained")
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
    """Orientation error (degrees) over time, one series per method: ``{name: (t_s, err_deg)}``.

    The series with fewer points are drawn on top (a sparse method stays visible
    over a dense one).
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.5), layout="constrained")
    for name, (t, e) in errors.items():
        ax.plot(
            np.asarray(t),
            np.asarray(e),
            ".",
            ms=3,
            label=f"{name} ({len(e)})",
            zorder=3 + 1.0 / (1.0 + len(e)),
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("orientation error (°)")
    ax.set_ylim(bottom=0)
    ax.legend(loc="best", fontsize="small")
    ax.set_title("orientation error over time")
    return ax


# ----------------------------------------------------------------------------- tracks
_TRACK_COLOUR = "#1f77b4"
"""The tracker's colour (line, band, wedges)."""
_BAND_COLOUR = "#c6dbef"
"""The azimuth band of :func:`plot_azimuth_over_time`."""
_DISC_COLOUR = "#9ecae1"
"""The position band of :func:`plot_track_uncertainty` (light: the track stays visible)."""
_BAND_REF_M = 0.3
"""Discs of :func:`plot_track_uncertainty` up to this radius are drawn at full
band opacity, wider ones fainter (∝ 1/r²), metres."""
_WEDGE_COLOUR = "#08306b"
"""The azimuth wedges of :func:`plot_track_uncertainty`."""
_SPARSE_COLOURS = ("#ff7f0e", "#2ca02c", "#d62728", "#9467bd")
"""Colours of the sparse methods, in order."""


def _coverage_label(name: str, n_estimates: int, n_packets: int | None) -> str:
    if not n_packets:
        return f"{name} ({n_estimates} estimates)"
    return f"{name} ({100.0 * n_estimates / n_packets:.1f} % of packets)"


def _needs_std(track: Estimates) -> tuple[FloatArray, FloatArray]:
    if track.position_std_m is None or track.azimuth_std_deg is None:
        raise ValueError("the track has no position_std_m / azimuth_std_deg columns")
    return track.position_std_m, track.azimuth_std_deg


def plot_track_uncertainty(
    truth_t_s: FloatArray,
    truth_position_m: FloatArray,
    truth_azimuth_deg: FloatArray,
    track: Estimates,
    sparse: Mapping[str, Estimates] | None = None,
    *,
    n_packets: int | None = None,
    receivers_xy_m: FloatArray | None = None,
    n_wedges: int = 14,
    wedge_m: float = 1.0,
    ax: Axes | None = None,
) -> Axes:
    """A tracker's track with its uncertainty, beside sparse estimates and the truth.

    Parameters
    ----------
    truth_t_s
        ``(n,)`` times of the truth rows, seconds (increasing).
    truth_position_m
        ``(n, 3)`` true positions, metres (a black line).
    truth_azimuth_deg
        ``(n,)`` true azimuths, degrees (black arrows at the wedges' times).
    track
        The tracker's estimates (a line), with ``position_std_m`` drawn as a
        band of discs of that radius around every estimate and, at ``n_wedges``
        evenly spaced estimates, a wedge of ± ``azimuth_std_deg`` around its
        azimuth (radius ``wedge_m`` metres; the device's top, body ``+y``).
    sparse
        Other methods' estimates, drawn as dots (e.g. ``{"full": ...}``).
    n_packets
        Packets in the trace: the legend then gives each method's coverage.
    receivers_xy_m
        ``(n_rx, 2)`` receiver positions, metres (grey triangles).
    """
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import to_rgba
    from matplotlib.patches import Circle, Wedge

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 7))
    pos_sd, az_sd = _needs_std(track)
    tp = np.asarray(truth_position_m, dtype=np.float64)
    xy = track.position_m[:, :2]
    # the band: a disc of radius position_std_m around every estimate (thinned to
    # ~2,000), each holding the same ink, so its opacity falls as 1/r²: a wide,
    # uncertain stretch shows as a faint cloud, a confident one as a solid band
    step = max(1, len(track) // 2000)
    radius = np.maximum(pos_sd[::step], 1e-3)
    alpha = np.clip(0.3 * (_BAND_REF_M / radius) ** 2, 0.004, 0.3)
    discs = [
        Circle((float(x), float(y)), float(r)) for (x, y), r in zip(xy[::step], radius, strict=True)
    ]
    rgba = np.tile(np.array(to_rgba(_DISC_COLOUR)), (len(discs), 1))
    rgba[:, 3] = alpha
    ax.add_collection(
        PatchCollection(discs, facecolors=rgba, edgecolors="none", zorder=1), autolim=False
    )
    ax.fill([], [], color=_DISC_COLOUR, alpha=0.6, label="filter ± position_std_m (ink ∝ 1/σ²)")
    ax.plot(tp[:, 0], tp[:, 1], "-", color="k", lw=1.5, zorder=3, label="truth")
    ax.plot(
        xy[:, 0],
        xy[:, 1],
        "-",
        color=_TRACK_COLOUR,
        lw=1.2,
        zorder=4,
        label=_coverage_label(track_name(track), len(track), n_packets),
    )
    if len(track):
        idx = np.unique(np.linspace(0, len(track) - 1, min(n_wedges, len(track))).astype(int))
        up_deg = track.orientation_deg[idx, 0] + 90.0  # the top's direction from +x
        half = np.minimum(az_sd[idx], 180.0)
        wedges = [
            Wedge((float(x), float(y)), wedge_m, float(u - h), float(u + h))
            for (x, y), u, h in zip(xy[idx], up_deg, half, strict=True)
        ]
        ax.add_collection(
            PatchCollection(
                wedges, facecolor=_WEDGE_COLOUR, alpha=0.6, edgecolor=_WEDGE_COLOUR, zorder=5
            ),
            autolim=False,
        )
        orientation_arrows(
            ax, xy[idx], track.orientation_deg[idx, 0], wedge_m, color=_TRACK_COLOUR, zorder=6
        )
        ti = np.clip(np.searchsorted(truth_t_s, track.timestamp_s[idx]), 0, tp.shape[0] - 1)
        orientation_arrows(
            ax, tp[ti, :2], np.asarray(truth_azimuth_deg)[ti], wedge_m, color="k", zorder=6
        )
        ax.fill([], [], color=_WEDGE_COLOUR, alpha=0.6, label="filter azimuth ± azimuth_std_deg")
    for i, (name, est) in enumerate((sparse or {}).items()):
        ax.plot(
            est.position_m[:, 0],
            est.position_m[:, 1],
            "o",
            ms=2.5,
            color=_SPARSE_COLOURS[i % len(_SPARSE_COLOURS)],
            zorder=7,
            label=_coverage_label(name, len(est), n_packets),
        )
    if receivers_xy_m is not None:
        ax.scatter(
            receivers_xy_m[:, 0],
            receivers_xy_m[:, 1],
            marker="^",
            s=80,
            c="grey",
            edgecolors="k",
            zorder=8,
            label="receivers",
        )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.legend(loc="best", fontsize="small", framealpha=0.9)
    ax.set_title("track with uncertainty (arrows: the device's top)")
    return ax


def track_name(est: Estimates) -> str:
    """The method of a set of estimates (``"estimates"`` if empty or mixed)."""
    names = set(np.asarray(est.method).tolist()) if len(est) else set()
    return str(names.pop()) if len(names) == 1 else "estimates"


def plot_azimuth_over_time(
    truth_t_s: FloatArray,
    truth_azimuth_deg: FloatArray,
    track: Estimates,
    sparse: Mapping[str, Estimates] | None = None,
    *,
    ax: Axes | None = None,
) -> Axes:
    """True azimuth over time (black), the track's with a ± ``azimuth_std_deg``
    band, and sparse methods' azimuths as dots.

    Azimuth is drawn unwrapped along the truth (each estimate as the truth at
    its time plus the wrapped difference), so a turn through 0°/360° reads as
    one continuous curve and every error is the vertical distance to the truth.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    t = np.asarray(truth_t_s, dtype=np.float64)
    true_unwrapped = np.rad2deg(np.unwrap(np.deg2rad(np.asarray(truth_azimuth_deg, float))))

    def along_truth(est: Estimates) -> FloatArray:
        i = np.clip(np.searchsorted(t, est.timestamp_s), 0, t.size - 1)
        return true_unwrapped[i] + angle_diff_deg(
            est.orientation_deg[:, 0], np.asarray(truth_azimuth_deg)[i]
        )

    _, az_sd = _needs_std(track)
    a = along_truth(track)
    ax.fill_between(
        track.timestamp_s, a - az_sd, a + az_sd, color=_BAND_COLOUR, lw=0, label="± azimuth_std_deg"
    )
    ax.plot(t, true_unwrapped, "-", color="k", lw=1.5, label="truth")
    ax.plot(track.timestamp_s, a, "-", color=_TRACK_COLOUR, lw=1.0, label=track_name(track))
    for i, (name, est) in enumerate((sparse or {}).items()):
        ax.plot(
            est.timestamp_s,
            along_truth(est),
            "o",
            ms=2.5,
            color=_SPARSE_COLOURS[i % len(_SPARSE_COLOURS)],
            label=name,
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("azimuth (°, unwrapped)")
    ax.legend(loc="best", fontsize="small", ncol=4)
    ax.set_title("azimuth over time")
    return ax


def plot_error_over_time(
    errors: Mapping[str, tuple[FloatArray, FloatArray]],
    *,
    quantity: str = "position error (m)",
    coverage: Mapping[str, float] | None = None,
    stated: tuple[str, FloatArray, FloatArray] | None = None,
    ax: Axes | None = None,
) -> Axes:
    """One error over time per method: ``{name: (t_s, error)}``.

    The first method is drawn as a line (a tracker, one estimate per packet),
    the others as dots. ``coverage`` (``{name: estimates ÷ packets}``) and the
    mean error go into the legend; ``stated = (label, t_s, std)`` adds the
    tracker's own uncertainty as a dashed line (a calibrated tracker's error
    lies mostly below about twice it).
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    unit = quantity[quantity.rfind("(") + 1 : quantity.rfind(")")] if "(" in quantity else ""
    unit = "°" if unit == "°" else f" {unit}"
    for i, (name, (t, e)) in enumerate(errors.items()):
        e = np.asarray(e, dtype=np.float64)
        label = name
        if coverage is not None and name in coverage:
            label += f": {100.0 * coverage[name]:.1f} % coverage"
        if e.size:
            label += f", mean {e.mean():.2f}{unit}" if unit != "°" else f", mean {e.mean():.1f}°"
        if i == 0:
            ax.plot(np.asarray(t), e, "-", color=_TRACK_COLOUR, lw=1.0, label=label)
        else:
            c = _SPARSE_COLOURS[(i - 1) % len(_SPARSE_COLOURS)]
            ax.plot(np.asarray(t), e, "o", ms=2.5, color=c, label=label)
    if stated is not None:
        label, t, sd = stated
        ax.plot(np.asarray(t), np.asarray(sd), "--", color=_TRACK_COLOUR, lw=0.8, label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(quantity)
    ax.set_ylim(bottom=0)
    ax.legend(loc="upper right", fontsize="small")
    return ax


def track_figure(
    truth_t_s: FloatArray,
    truth_position_m: FloatArray,
    truth_azimuth_deg: FloatArray,
    track: Estimates,
    track_errors: tuple[FloatArray, FloatArray],
    sparse: Mapping[str, tuple[Estimates, FloatArray, FloatArray]],
    *,
    n_packets: int,
    receivers_xy_m: FloatArray | None = None,
    title: str | None = None,
) -> Figure:
    """The track map (:func:`plot_track_uncertainty`) on the left; azimuth over
    time and position and orientation error over time on the right.

    ``track_errors`` is ``(position_error_m, orientation_error_deg)`` of each
    of the track's estimates; ``sparse`` maps a method to ``(estimates,
    position_error_m, orientation_error_deg)``.
    """
    fig = plt.figure(figsize=(16, 8.5), layout="constrained")
    grid = fig.add_gridspec(3, 2, width_ratios=(1.0, 1.15))
    ax_map = fig.add_subplot(grid[:, 0])
    ax_az = fig.add_subplot(grid[0, 1])
    ax_pos = fig.add_subplot(grid[1, 1], sharex=ax_az)
    ax_ori = fig.add_subplot(grid[2, 1], sharex=ax_az)
    pos_sd, az_sd = _needs_std(track)
    name = track_name(track)
    sparse_est = {m: v[0] for m, v in sparse.items()}
    plot_track_uncertainty(
        truth_t_s,
        truth_position_m,
        truth_azimuth_deg,
        track,
        sparse_est,
        n_packets=n_packets,
        receivers_xy_m=receivers_xy_m,
        ax=ax_map,
    )
    plot_azimuth_over_time(truth_t_s, truth_azimuth_deg, track, sparse_est, ax=ax_az)
    cov = {name: len(track) / n_packets, **{m: len(v[0]) / n_packets for m, v in sparse.items()}}
    plot_error_over_time(
        {
            name: (track.timestamp_s, track_errors[0]),
            **{m: (v[0].timestamp_s, v[1]) for m, v in sparse.items()},
        },
        quantity="position error (m)",
        coverage=cov,
        stated=(f"{name}: position_std_m", track.timestamp_s, pos_sd),
        ax=ax_pos,
    )
    plot_error_over_time(
        {
            name: (track.timestamp_s, track_errors[1]),
            **{m: (v[0].timestamp_s, v[2]) for m, v in sparse.items()},
        },
        quantity="orientation error (°)",
        coverage=cov,
        stated=(f"{name}: azimuth_std_deg", track.timestamp_s, az_sd),
        ax=ax_ori,
    )
    ax_az.tick_params(labelbottom=False)
    ax_pos.tick_params(labelbottom=False)
    ax_az.set_xlabel("")
    ax_pos.set_xlabel("")
    if title:
        fig.suptitle(title)
    return fig


def pose3d_figure(
    truth_t_s: FloatArray,
    truth_position_m: FloatArray,
    truth_orientation_deg: FloatArray,
    track: Estimates,
    errors: tuple[FloatArray, FloatArray],
    *,
    n_packets: int,
    receivers_m: FloatArray | None = None,
    title: str | None = None,
) -> Figure:
    """A 3-D track against the truth (``radiopose demo --pose 3d``).

    Left: the top view (:func:`plot_track_uncertainty`), each receiver
    labelled with its height. Right, over time: height (m), azimuth, pitch and
    roll (degrees; truth black, the track coloured, azimuth with its
    ± ``azimuth_std_deg`` band), then the position error (m) and the
    rotation-angle error (the angle of the relative rotation, degrees).
    ``errors`` is ``(position_error_m, rotation_error_deg)`` per estimate.
    """
    fig = plt.figure(figsize=(16, 10), layout="constrained")
    grid = fig.add_gridspec(5, 2, width_ratios=(1.0, 1.15))
    ax_map = fig.add_subplot(grid[:, 0])
    rx = None if receivers_m is None else np.asarray(receivers_m, float).reshape(-1, 3)
    plot_track_uncertainty(
        truth_t_s, truth_position_m, np.asarray(truth_orientation_deg)[:, 0], track,
        n_packets=n_packets, receivers_xy_m=None if rx is None else rx[:, :2], ax=ax_map,
    )  # fmt: skip
    if rx is not None:
        for x, y, z in rx:
            ax_map.annotate(f"{z:.1f} m", (x, y), textcoords="offset points", xytext=(6, 6),
                            fontsize="small")  # fmt: skip
    t_est = track.timestamp_s
    tt = np.asarray(truth_t_s, float)
    tp = np.asarray(truth_position_m, float)
    to = np.asarray(truth_orientation_deg, float)
    first = fig.add_subplot(grid[0, 1])
    axes = [first] + [fig.add_subplot(grid[i, 1], sharex=first) for i in range(1, 5)]
    axes[0].plot(tt, tp[:, 2], "-", color="k", lw=1.2, label="truth")
    axes[0].plot(t_est, track.position_m[:, 2], "-", color=_TRACK_COLOUR, lw=1.0,
                 label=track_name(track))  # fmt: skip
    axes[0].set_ylabel("height (m)")
    axes[0].legend(loc="upper right", fontsize="small")
    # azimuth unwrapped along the truth, with its ± azimuth_std_deg band
    plot_azimuth_over_time(tt, to[:, 0], track, ax=axes[1])
    axes[1].set_title("")
    axes[1].set_xlabel("")
    colours = {"pitch": "tab:green", "roll": "tab:purple"}
    for ax, col, name in ((axes[2], 1, "pitch"), (axes[3], 2, "roll")):
        true_deg, est_deg = to[:, col], track.orientation_deg[:, col]
        if name == "roll":  # both in (−180, 180]: the stored truth may be in [0, 360)
            true_deg, est_deg = angle_diff_deg(true_deg, 0.0), angle_diff_deg(est_deg, 0.0)
        ax.plot(tt, true_deg, "-", color="k", lw=1.2)
        ax.plot(t_est, est_deg, "-", color=colours[name], lw=1.0)
        ax.set_ylabel(f"{name} (°)")
    pos_err, rot_err = (np.asarray(e, float) for e in errors)
    ax_e = axes[4]
    ax_e.plot(
        t_est,
        pos_err,
        "-",
        color=_TRACK_COLOUR,
        lw=1.0,
        label=f"position, mean {pos_err.mean():.2f} m" if pos_err.size else "position",
    )
    ax_e.set_ylabel("position error (m)")
    ax_e.set_ylim(bottom=0)
    ax_r = ax_e.twinx()
    ax_r.plot(
        t_est,
        rot_err,
        "-",
        color="tab:red",
        lw=0.8,
        label=f"rotation, mean {rot_err.mean():.1f}°" if rot_err.size else "rotation",
    )
    ax_r.set_ylabel("rotation error (°)")
    ax_r.set_ylim(bottom=0)
    handles = ax_e.get_legend_handles_labels()[0] + ax_r.get_legend_handles_labels()[0]
    ax_e.legend(handles=handles, loc="upper left", fontsize="small")
    ax_e.set_xlabel("time (s)")
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    if title:
        fig.suptitle(title)
    return fig
