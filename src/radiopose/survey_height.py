"""The survey map extended to heights: path loss in 3-D distance (docs/pose3d.md).

The survey (:mod:`radiopose.survey`) measures the channel ``M_r(x, y)`` of each
receiver at the surveyed height ``z_s``. A device at another height ``z`` is
farther from (or nearer to) the receiver; the model moves the surveyed value
along the log-distance law in 3-D distance::

    M_r(x, y, z) = M_r(x, y; z_s) − 10 n log10( max(d(z), d0) / max(d(z_s), d0) )
    d(z) = |(x, y, z) − receiver r|,  d0 = 1 m                          (dB)

The exponent ``n`` is fitted to the survey itself (:func:`fit_exponent`): the
corrected survey values against ``10 log10 max(d, d0)`` by least squares with
one intercept per receiver. With several surveyed heights, each height has
its own map and a height between two surveyed ones blends the two corrected
values linearly in ``z``; outside them the nearest surveyed height is used.

Detrended maps (``build_height_model(..., detrend=True)``, the default): the survey is
interpolated onto the candidate grid with its path loss removed —
``R_r(x, y) = M_r(x, y; z_s) + 10 n log10(max(d(z_s), d0))`` at each surveyed
point — and the path loss is added back at the device's exact 3-D distance,
``M_r(x, y, z) = R_r(x, y) − 10 n log10(max(d(z), d0))``. Near a receiver the
log-distance law bends faster than a survey grid of a metre or so can follow,
and interpolating ``M`` itself flattens its peak (docs/pose3d.md, "Detrended
survey maps"); ``R`` is what remains after the law (the receiver's pattern,
the room), smoother wherever the law dominates.

The receiver's own gain (``build_height_model(..., receiver_gain=True)``):
each receiver's pattern and orientation are in the site (``receivers.csv``),
so the survey is interpolated with the receiver's directivity toward each
surveyed point removed, ``− G_r(r → (x, y, z_s))``, and the directivity is
added back toward the device's exact position, ``+ G_r(r → (x, y, z))``.
Near a receiver mounted above the device the direction from the receiver
changes fast with position and height; a map at one surveyed height cannot
follow that (docs/pose3d.md, "The receiver's gain in the height model").
Receivers with a constant pattern add nothing and are skipped.

What the model assumes (and a real survey must check): the receiver's own
pattern and the room change little with the device's height — true for a
receiver whose pattern depends only on the horizontal direction (a vertical
dipole, a slice pattern mounted level or upside down), or whose enrolled
pattern and orientation are known (``receiver_gain``); otherwise a survey at
two or more heights is needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from radiopose.errors import InputError
from radiopose.geometry import orientation_matrices, pattern_angles_deg
from radiopose.patterns.pattern import Pattern
from radiopose.site import (
    SURVEY_HEIGHT_DECIMALS,
    Site,
    correct_survey,
    missing_survey_height,
    survey_points_by_receiver,
)
from radiopose.survey import build_survey_map
from radiopose.units import FloatArray

REFERENCE_DISTANCE_M = 1.0
"""``d0``: distances below it count as ``d0`` (far field only), metres."""
EXPONENT_RANGE = (1.0, 6.0)
"""A fitted exponent is clipped to this range."""


@dataclass(frozen=True, eq=False)
class HeightModel:
    """Per-receiver channel maps at each surveyed height and the path-loss exponent.

    Attributes
    ----------
    exponent
        Path-loss exponent ``n`` (fitted, :func:`fit_exponent`).
    layers_z_m
        ``(L,)`` surveyed heights, increasing, metres.
    maps_db
        ``(L, n_rx, nx, ny)`` the survey map at each surveyed height, dB.
    x_m, y_m
        Grid axes of the maps, metres.
    receivers_m
        ``(n_rx, 3)`` receiver positions, metres.
    detrended
        ``maps_db`` hold ``R_r`` (the survey with its path loss in 3-D distance
        removed) rather than ``M_r`` (module docstring).
    receiver_gain
        The receivers' own patterns, removed from ``maps_db`` and added back
        toward each point (module docstring): one :class:`ReceiverGain`, or
        ``None`` (the maps hold the receivers' gain as surveyed).
    """

    exponent: float
    layers_z_m: FloatArray
    maps_db: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    receivers_m: FloatArray
    detrended: bool = False
    receiver_gain: ReceiverGain | None = None

    def channel_db(self, xyz_m: FloatArray) -> FloatArray:
        """``M_r(x, y, z)`` ``(n, n_rx)`` dB at points ``(n, 3)`` (bilinear in x, y).

        Raises
        ------
        InputError
            A point that is not finite (one check of the whole array: this runs
            once per packet in the 3-D filter).
        """
        p = np.asarray(xyz_m, float).reshape(-1, 3)
        if not np.isfinite(p).all():
            bad = int(np.argmin(np.isfinite(p).all(axis=1)))
            raise InputError(f"channel_db: point xyz_m[{bad}] = {p[bad]} is not finite")
        L = self.layers_z_m.size
        z = p[:, 2]
        if L == 1:
            lo = np.zeros(p.shape[0], np.int64)
            frac = np.zeros(p.shape[0])
        else:
            lo = np.clip(np.searchsorted(self.layers_z_m, z, side="right") - 1, 0, L - 2)
            frac = np.clip((z - self.layers_z_m[lo]) / np.diff(self.layers_z_m)[lo], 0.0, 1.0)
        out = np.zeros((p.shape[0], self.receivers_m.shape[0]))
        for k, wgt in ((lo, 1.0 - frac), (np.minimum(lo + 1, L - 1), frac)):
            zl = self.layers_z_m[k]
            m = np.empty_like(out)
            for layer in np.unique(k):
                sel = k == layer
                m[sel] = _bilinear_all(self.maps_db[layer], self.x_m, self.y_m, p[sel])
            out += wgt[:, None] * (m + self.correction_db(p, zl))
        if self.receiver_gain is not None:
            out += self.receiver_gain.gain_dbi(p)
        return out

    def correction_db(self, xyz_m: FloatArray, from_z_m: FloatArray | float) -> FloatArray:
        """``−10 n log10(max(d(z), d0) / max(d(z_s), d0))`` ``(n, n_rx)`` dB from height
        ``from_z_m`` (scalar or ``(n,)``) to each point's own height; for detrended
        maps the whole law ``−10 n log10(max(d(z), d0))`` (``from_z_m`` unused)."""
        p = np.asarray(xyz_m, float).reshape(-1, 3)
        zs = np.broadcast_to(np.asarray(from_z_m, float), (p.shape[0],))
        horiz2 = np.sum((p[:, None, :2] - self.receivers_m[None, :, :2]) ** 2, axis=-1)
        d = np.sqrt(horiz2 + (p[:, None, 2] - self.receivers_m[None, :, 2]) ** 2)
        d0 = REFERENCE_DISTANCE_M
        if self.detrended:
            return -10.0 * self.exponent * np.log10(np.maximum(d, d0))
        ds = np.sqrt(horiz2 + (zs[:, None] - self.receivers_m[None, :, 2]) ** 2)
        return -10.0 * self.exponent * np.log10(np.maximum(d, d0) / np.maximum(ds, d0))


@dataclass(frozen=True, eq=False)
class ReceiverGain:
    """The receivers' directivity toward points, for the height model.

    Attributes
    ----------
    receivers_m
        ``(n_rx, 3)`` receiver positions, metres.
    rotations
        ``(n_rx, 3, 3)`` body-to-world rotations of the receivers' orientations
        (``receivers.csv``'s azimuth, pitch, roll).
    patterns
        One pattern per receiver (dBi).
    """

    receivers_m: FloatArray
    rotations: FloatArray
    patterns: tuple[Pattern, ...]

    @classmethod
    def of_site(cls, site: Site) -> ReceiverGain | None:
        """The site's receivers' gain, ``None`` if every receiver's pattern is constant."""
        pats = tuple(site.patterns[r.pattern] for r in site.receivers)
        if all(float(np.ptp(p.directivity_dbi)) == 0.0 for p in pats):
            return None
        rot = np.stack([orientation_matrices(r.azimuth_deg, r.pitch_deg, r.roll_deg)[0]
                        for r in site.receivers])  # fmt: skip
        return cls(site.receiver_positions_m(), rot, pats)

    def gain_dbi(
        self, xyz_m: FloatArray, receiver_index: NDArray[np.int64] | None = None
    ) -> FloatArray:
        """``G_r(r → p)`` dBi: each receiver's directivity toward points ``(n, 3)``,
        ``(n, n_rx)``; with ``receiver_index`` ``(n,)`` (indices into the
        receivers), only each point's own receiver's, ``(n,)``."""
        p = np.asarray(xyz_m, float).reshape(-1, 3)
        if receiver_index is None:
            return np.stack([self._toward(j, p) for j in range(len(self.patterns))], axis=1)
        own = np.empty(p.shape[0])
        for j in range(len(self.patterns)):
            sel = receiver_index == j
            own[sel] = self._toward(j, p[sel])
        return own

    def _toward(self, j: int, p: FloatArray) -> FloatArray:
        """Receiver ``j``'s directivity (dBi) toward points ``p`` ``(n, 3)``, ``(n,)``."""
        phi, theta = pattern_angles_deg(self.receivers_m[j], self.rotations[j], p)
        return self.patterns[j].lookup_dbi(phi.reshape(-1), theta.reshape(-1))

    def kernel_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(rot, d, ax)`` of :func:`radiopose.filtering.kernels3d.receiver_gain_dbi`:
        ``rot`` ``(n_rx, 9)`` the rotations row-major, ``d`` ``(n_rx, A, P)`` the
        patterns padded to the largest, ``ax`` ``(n_rx, 5)`` per receiver
        ``[az0, az_step, polar_step, n_az, n_pol]`` (degrees; ``polar_step`` 1
        for a slice)."""
        n_az = max(p.azimuth_deg.size for p in self.patterns)
        n_pol = max(p.polar_deg.size for p in self.patterns)
        d = np.zeros((len(self.patterns), n_az, n_pol))
        ax = np.empty((len(self.patterns), 5))
        for j, p in enumerate(self.patterns):
            a, b = p.directivity_dbi.shape
            d[j, :a, :b] = p.directivity_dbi
            ax[j] = [p.azimuth_deg[0], p.azimuth_step_deg,
                     1.0 if p.is_slice else p.polar_step_deg, a, b]  # fmt: skip
        return np.ascontiguousarray(self.rotations.reshape(-1, 9)), d, ax


def no_receiver_gain() -> tuple[FloatArray, FloatArray, FloatArray]:
    """:meth:`ReceiverGain.kernel_arrays` for no gain term (zero receivers)."""
    return np.zeros((0, 9)), np.zeros((0, 1, 1)), np.zeros((0, 5))


def _bilinear_all(maps: FloatArray, x: FloatArray, y: FloatArray, p: FloatArray) -> FloatArray:
    """``(n, n_rx)`` bilinear values of ``maps`` ``(n_rx, nx, ny)`` at points ``p`` (clamped)."""
    dx = x[1] - x[0] if x.size > 1 else 1.0
    dy = y[1] - y[0] if y.size > 1 else 1.0
    u = np.clip((p[:, 0] - x[0]) / dx, 0.0, x.size - 1.0)
    v = np.clip((p[:, 1] - y[0]) / dy, 0.0, y.size - 1.0)
    i0 = np.minimum(u.astype(np.int64), max(x.size - 2, 0))
    j0 = np.minimum(v.astype(np.int64), max(y.size - 2, 0))
    i1 = np.minimum(i0 + 1, x.size - 1)
    j1 = np.minimum(j0 + 1, y.size - 1)
    fu = (u - i0)[:, None]
    fv = (v - j0)[:, None]
    a = maps[:, i0, j0].T * (1 - fv) + maps[:, i0, j1].T * fv
    b = maps[:, i1, j0].T * (1 - fv) + maps[:, i1, j1].T * fv
    return a * (1 - fu) + b * fu


def _corrected_survey(site: Site) -> FloatArray:
    """The survey's channel values ``M = R − P_tx − D_st`` per survey row, dB."""
    cfg = site.survey_config
    return correct_survey(site.survey_rows, cfg.tx_power_dbm, site.patterns[cfg.pattern],
                          site.receivers)  # fmt: skip


def _survey_log_distance(site: Site) -> tuple[NDArray[np.int64], FloatArray]:
    """Per survey row: its receiver's index and ``10 log10(max(d, d0))``, ``d`` the
    3-D distance from the surveyed point to that receiver (m)."""
    rows = site.survey_rows
    ids = list(site.receiver_ids)
    idx = np.array([ids.index(r) for r in rows.receiver_id], dtype=np.int64)
    d = np.linalg.norm(rows.xyz_m - site.receiver_positions_m()[idx], axis=1)
    return idx, 10.0 * np.log10(np.maximum(d, REFERENCE_DISTANCE_M))


def fit_exponent(site: Site) -> float:
    """Least-squares path-loss exponent of the corrected survey in 3-D distance.

    ``M = a_r − n · 10 log10(max(d, d0))`` with one intercept ``a_r`` per
    receiver; ``n`` clipped to :data:`EXPONENT_RANGE`.
    """
    return _fitted_exponent(_corrected_survey(site), *_survey_log_distance(site),
                            len(site.receiver_ids))  # fmt: skip


def _fitted_exponent(m_db: FloatArray, idx: np.ndarray, ell: FloatArray, n_rx: int) -> float:
    """:func:`fit_exponent` of the corrected survey values ``m_db``, their
    receivers ``idx`` and ``ell = 10 log10(max(d, d0))`` per survey row."""
    num = den = 0.0
    for r in range(n_rx):
        sel = idx == r
        if sel.sum() < 2:
            continue
        le = ell[sel] - ell[sel].mean()
        num += float(np.sum(le * (m_db[sel] - m_db[sel].mean())))
        den += float(np.sum(le * le))
    n = -num / den if den > 0 else 2.0
    return float(np.clip(n, *EXPONENT_RANGE))


def build_height_model(
    site: Site,
    decimals: int = SURVEY_HEIGHT_DECIMALS,
    detrend: bool = True,
    receiver_gain: bool = False,
) -> HeightModel:
    """The site's :class:`HeightModel`: one map per surveyed height (heights rounded
    to ``decimals``), the site's own survey map where only one height was surveyed;
    ``detrend`` (default on, as ``Pose3dConfig.survey_detrend``): maps of the survey
    with its fitted path loss removed (off: the survey's own maps),
    ``receiver_gain``: with the receivers' own directivity removed (module
    docstring); either interpolated with the site's own interpolation settings.

    Raises
    ------
    InputError
        A surveyed height without survey rows for some receiver (a loaded or
        assembled 3-D site never has one: :func:`radiopose.site_io.load_site`).
    """
    rows = site.survey_rows
    z = np.round(rows.xyz_m[:, 2], decimals)
    layers = np.unique(z)
    gap = missing_survey_height(rows, site.receiver_ids, decimals)
    if gap is not None:
        h, rid, _ = gap
        raise InputError(
            f"site {site.name!r}: receiver {rid!r} has no survey rows at surveyed height "
            f"{h:g} m; every surveyed height needs rows for every receiver"
        )
    x, y = np.asarray(site.survey_map.x_m, float), np.asarray(site.survey_map.y_m, float)
    m_db = _corrected_survey(site)
    idx, ell = _survey_log_distance(site)
    exponent = _fitted_exponent(m_db, idx, ell, len(site.receiver_ids))
    gain = ReceiverGain.of_site(site) if receiver_gain else None
    if layers.size == 1 and not detrend and gain is None:
        maps = np.asarray(site.survey_map.m_db, float)[None]
    else:
        if detrend:
            m_db = m_db + exponent * ell
        if gain is not None:
            m_db = m_db - gain.gain_dbi(rows.xyz_m, idx)
        out = []
        for h in layers:
            sel = z == h
            sub = type(rows)(rows.xyz_m[sel], rows.receiver_id[sel], rows.rss_dbm[sel],
                             rows.orientation_deg[sel])  # fmt: skip
            pts = survey_points_by_receiver(sub, m_db[sel], site.receiver_ids)
            smap = build_survey_map(
                site.receiver_ids, pts, x, y,
                site.survey_config.interpolation,  # type: ignore[arg-type]
                site.survey_config.outside,  # type: ignore[arg-type]
            )  # fmt: skip
            out.append(np.asarray(smap.m_db, float))
        maps = np.stack(out)
    return HeightModel(
        exponent, layers.astype(float), np.ascontiguousarray(maps), x, y,
        site.receiver_positions_m(), detrend, gain,
    )  # fmt: skip
