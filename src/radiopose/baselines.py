"""The ``lms`` baseline: log-distance path loss and per-packet least squares.

Paper, "Enhanced Localisation Pipeline", comparison methods. The baseline
ignores every radiation pattern and estimates position only:

1. Fit, per receiver ``r``, a log-distance model to the raw survey:
   ``RSS − P_tx,survey = A_r − 10 n_r log10(max(d, d0) / d0)`` (linear least
   squares in ``A_r`` and ``n_r``; ``d`` the 3-D survey-point–receiver distance).
2. Per packet, minimise ``Σ_r (RSS_r − P_tx − A_r + 10 n_r log10(d_r(x, y)))²``
   over the heard receivers with :func:`scipy.optimize.least_squares`, bounded
   to the site's area, at the candidate height. The start is the best point of
   a coarse grid (``init_step_m``) so the local solver does not stop in a poor
   local minimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from radiopose.site import Site
from radiopose.units import FloatArray


@dataclass(frozen=True, eq=False)
class LogDistanceFit:
    """Per-receiver log-distance fit to the survey.

    Attributes
    ----------
    receiver_ids
        Receiver order.
    receiver_positions_m
        ``(n_rx, 3)`` receiver positions, metres.
    intercept_db
        ``(n_rx,)`` ``A_r``: RSS − P_tx at ``d0``, dB.
    exponent
        ``(n_rx,)`` path-loss exponents ``n_r``.
    rms_residual_db
        ``(n_rx,)`` RMS residual of each fit, dB.
    d0_m
        Reference distance, metres.
    """

    receiver_ids: tuple[str, ...]
    receiver_positions_m: FloatArray
    intercept_db: FloatArray
    exponent: FloatArray
    rms_residual_db: FloatArray
    d0_m: float = 1.0

    def predict_dbm(
        self, xyz_m: FloatArray, receiver_index: NDArray[np.int64], tx_power_dbm: float
    ) -> FloatArray:
        """Predicted RSS ``(n, h)`` in dBm at ``(n, 3)`` points for the given receivers."""
        p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        rx = self.receiver_positions_m[receiver_index]
        d = np.linalg.norm(rx[None, :, :] - p[:, None, :], axis=-1)
        d = np.maximum(d, self.d0_m)
        return (
            tx_power_dbm
            + self.intercept_db[receiver_index][None, :]
            - 10.0 * self.exponent[receiver_index][None, :] * np.log10(d / self.d0_m)
        )


def fit_log_distance(site: Site, d0_m: float = 1.0) -> LogDistanceFit:
    """Fit ``A_r`` and ``n_r`` of every receiver to the site's raw survey."""
    rows = site.survey_rows
    rx_pos = site.receiver_positions_m()
    ids = site.receiver_ids
    a = np.empty(len(ids))
    n = np.empty(len(ids))
    rms = np.empty(len(ids))
    for r, rid in enumerate(ids):
        sel = rows.receiver_id == rid
        d = np.maximum(np.linalg.norm(rows.xyz_m[sel] - rx_pos[r], axis=1), d0_m)
        y = rows.rss_dbm[sel] - site.survey_config.tx_power_dbm
        x = -10.0 * np.log10(d / d0_m)
        if np.ptp(x) > 0:
            design = np.column_stack([np.ones_like(x), x])
            (a[r], n[r]), *_ = np.linalg.lstsq(design, y, rcond=None)
        else:  # all survey points at one distance: no slope information
            a[r], n[r] = float(np.mean(y)), 2.0
        rms[r] = float(np.sqrt(np.mean((y - a[r] - n[r] * x) ** 2)))
    return LogDistanceFit(ids, rx_pos, a, n, rms, d0_m)


@dataclass(frozen=True)
class LmsLocator:
    """Per-packet least-squares positioning with a :class:`LogDistanceFit`.

    Attributes
    ----------
    fit
        The fitted path-loss models.
    bounds_xy_m
        ``(x_min, x_max, y_min, y_max)`` of the search, metres.
    z_m
        Height of the estimate, metres.
    init_step_m
        Step of the coarse start grid, metres.
    """

    fit: LogDistanceFit
    bounds_xy_m: tuple[float, float, float, float]
    z_m: float
    init_step_m: float = 1.0

    @classmethod
    def for_site(cls, site: Site, init_step_m: float = 1.0) -> LmsLocator:
        a = site.area
        return cls(
            fit_log_distance(site),
            (a.x_min_m, a.x_max_m, a.y_min_m, a.y_max_m),
            a.z_m,
            init_step_m,
        )

    def locate(
        self, receiver_index: NDArray[np.int64], rss_dbm: FloatArray, tx_power_dbm: float
    ) -> FloatArray:
        """Position ``(3,)`` in metres minimising the squared RSS residuals."""
        x0, x1, y0, y1 = self.bounds_xy_m
        ridx = np.asarray(receiver_index, dtype=np.int64)
        rss = np.asarray(rss_dbm, dtype=np.float64)
        gx = np.linspace(x0, x1, max(2, round((x1 - x0) / self.init_step_m) + 1))
        gy = np.linspace(y0, y1, max(2, round((y1 - y0) / self.init_step_m) + 1))
        mx, my = np.meshgrid(gx, gy, indexing="ij")
        grid = np.column_stack([mx.ravel(), my.ravel(), np.full(mx.size, self.z_m)])
        cost = np.sum((self.fit.predict_dbm(grid, ridx, tx_power_dbm) - rss[None, :]) ** 2, 1)
        start = grid[int(np.argmin(cost)), :2]

        def residuals(xy: FloatArray) -> FloatArray:
            p = np.array([xy[0], xy[1], self.z_m])
            return self.fit.predict_dbm(p, ridx, tx_power_dbm)[0] - rss

        if x1 > x0 and y1 > y0:
            from scipy.optimize import least_squares  # ~0.7 s to import: only when used

            sol = least_squares(residuals, start, bounds=([x0, y0], [x1, y1]), method="trf")
            xy = sol.x
        else:  # degenerate area: nothing to optimise
            xy = start
        return np.array([float(xy[0]), float(xy[1]), self.z_m])
