"""Compiled per-particle kernels of the Bayesian tracker (radians inside, metres, dB).

Every function takes the particle matrix ``S`` of shape ``(n, N_COLUMNS)`` whose
columns are named by the constants below. Angles in ``S`` are radians (the one
place besides :mod:`radiopose.likelihood.exact` that wraps angles itself);
positions metres; ``OFFSET_DB`` / ``OFFSET_VAR_DB2`` are the mean and variance
of each particle's Gaussian belief about the device's transmit-power offset
(Rao-Blackwellised: the offset is integrated out exactly, not sampled).

The expected RSS of a particle at receiver ``r`` is the likelihood's model
(:mod:`radiopose.likelihood.candidates`) evaluated off the grid::

    RSS_r = M_r(x, y) + P_tx + D(φ_r, θ_r) + b

with ``M_r`` bilinear on the survey map's grid, ``D`` bilinear on the pattern
grid (periodic in azimuth, polar clamped), ``(φ_r, θ_r)`` the direction to the
receiver in the body frame of ``R = Rz(azimuth)·Rx(pitch)·Ry(roll)`` and ``b``
the power offset.
"""

from __future__ import annotations

import math

import numba
import numpy as np

X_M, Y_M, Z_M, VX_MPS, VY_MPS, AZIMUTH_RAD, RATE_RAD_S, PITCH_RAD, ROLL_RAD = range(9)
OFFSET_DB, OFFSET_VAR_DB2 = 9, 10
N_COLUMNS = 11
N_NOISE = 5
"""Standard normal draws per particle and step: x, y acceleration, angular
acceleration, pitch and roll steps."""

_TWO_PI = 2.0 * math.pi
_RAD_TO_DEG = 180.0 / math.pi


@numba.njit(cache=True, inline="always")
def _map_db(chan, r, x, y, x0, dx, nx, y0, dy, ny):  # pragma: no cover - compiled
    """``M_r(x, y)``, bilinear, clamped to the grid (NaN if a corner is NaN)."""
    u = min(max((x - x0) / dx, 0.0), nx - 1.0) if nx > 1 else 0.0
    v = min(max((y - y0) / dy, 0.0), ny - 1.0) if ny > 1 else 0.0
    i0 = min(int(u), max(nx - 2, 0))
    j0 = min(int(v), max(ny - 2, 0))
    i1 = min(i0 + 1, nx - 1)
    j1 = min(j0 + 1, ny - 1)
    fu = u - i0
    fv = v - j0
    a = chan[r, i0, j0] * (1.0 - fv) + chan[r, i0, j1] * fv
    b = chan[r, i1, j0] * (1.0 - fv) + chan[r, i1, j1] * fv
    return a * (1.0 - fu) + b * fu


@numba.njit(cache=True, inline="always")
def _pattern_dbi(d, phi_deg, theta_deg, az0, az_step, polar_step):  # pragma: no cover
    """Bilinear pattern lookup, as :meth:`radiopose.patterns.pattern.Pattern.lookup_dbi`."""
    n_az = d.shape[0]
    n_pol = d.shape[1]
    u = ((phi_deg - az0) % 360.0) / az_step
    w = 0.0 if n_pol == 1 else min(max(theta_deg, 0.0), 180.0) / polar_step
    fi0 = math.floor(u)
    fu = u - fi0
    i0 = int(fi0) % n_az
    i1 = (i0 + 1) % n_az
    j0 = min(int(w), n_pol - 1)
    fw = w - j0
    j1 = min(j0 + 1, n_pol - 1)
    top = d[i0, j0] * (1.0 - fu) + d[i1, j0] * fu
    bot = d[i0, j1] * (1.0 - fu) + d[i1, j1] * fu
    return top * (1.0 - fw) + bot * fw


@numba.njit(cache=True)
def predict(  # pragma: no cover - compiled
    S, noise, dt_s, q_acc, q_rate, q_tilt, max_speed, max_rate, box, tilt_box
):
    """Propagate particles by ``dt_s`` in place.

    Nearly-constant velocity and turn rate: white acceleration of density
    ``q_acc`` (m/s²·√s) and angular acceleration ``q_rate`` (rad/s²·√s);
    pitch and roll a random walk of ``q_tilt`` rad/√s within ``tilt_box``
    (``[pitch_lo, pitch_hi, roll_lo, roll_hi]``; equal bounds freeze the axis).
    Speed and turn rate are clipped at ``max_speed`` / ``max_rate`` (the
    prior's support); positions are reflected at ``box`` (``[x_lo, x_hi,
    y_lo, y_hi]``).
    """
    n = S.shape[0]
    sq = math.sqrt(dt_s)
    for i in range(n):
        vx0 = S[i, VX_MPS]
        vy0 = S[i, VY_MPS]
        w0 = S[i, RATE_RAD_S]
        # v(t+dt) = v(t) + a dt with a ~ N(0, q²/dt): Var(dv) = q² dt
        vx = vx0 + q_acc * sq * noise[i, 0]
        vy = vy0 + q_acc * sq * noise[i, 1]
        sp = math.sqrt(vx * vx + vy * vy)
        if sp > max_speed:
            vx *= max_speed / sp
            vy *= max_speed / sp
        w = min(max(w0 + q_rate * sq * noise[i, 2], -max_rate), max_rate)
        # x(t+dt) = x(t) + dt (v(t) + v(t+dt)) / 2
        x = S[i, X_M] + 0.5 * (vx0 + vx) * dt_s
        y = S[i, Y_M] + 0.5 * (vy0 + vy) * dt_s
        if x < box[0]:
            x, vx = 2.0 * box[0] - x, -vx
        if x > box[1]:
            x, vx = 2.0 * box[1] - x, -vx
        if y < box[2]:
            y, vy = 2.0 * box[2] - y, -vy
        if y > box[3]:
            y, vy = 2.0 * box[3] - y, -vy
        S[i, X_M] = min(max(x, box[0]), box[1])
        S[i, Y_M] = min(max(y, box[2]), box[3])
        S[i, VX_MPS] = vx
        S[i, VY_MPS] = vy
        S[i, AZIMUTH_RAD] = (S[i, AZIMUTH_RAD] + 0.5 * (w0 + w) * dt_s) % _TWO_PI
        S[i, RATE_RAD_S] = w
        if tilt_box[1] > tilt_box[0]:
            p = S[i, PITCH_RAD] + q_tilt * sq * noise[i, 3]
            S[i, PITCH_RAD] = min(max(p, tilt_box[0]), tilt_box[1])
        if tilt_box[3] > tilt_box[2]:
            r = S[i, ROLL_RAD] + q_tilt * sq * noise[i, 4]
            S[i, ROLL_RAD] = min(max(r, tilt_box[2]), tilt_box[3])


@numba.njit(cache=True, parallel=True)
def expected_rss_dbm(S, heard, rx, chan, grid, tx_dbm, d, pat):  # pragma: no cover - compiled
    """Expected RSS ``(n, h)`` dBm of every particle at the heard receivers,
    without the power offset. ``grid`` = ``[x0, dx, nx, y0, dy, ny]``;
    ``pat`` = ``[az0, az_step, polar_step]`` (degrees)."""
    n = S.shape[0]
    h = heard.shape[0]
    out = np.empty((n, h))
    x0, dx, nx, y0, dy, ny = grid[0], grid[1], int(grid[2]), grid[3], grid[4], int(grid[5])
    for i in numba.prange(n):
        ca = math.cos(S[i, AZIMUTH_RAD])
        sa = math.sin(S[i, AZIMUTH_RAD])
        cp = math.cos(S[i, PITCH_RAD])
        sp = math.sin(S[i, PITCH_RAD])
        cr = math.cos(S[i, ROLL_RAD])
        sr = math.sin(S[i, ROLL_RAD])
        # R = Rz(a) Rx(p) Ry(r), body to world; v = Rᵀ d
        r00 = ca * cr - sa * sp * sr
        r01 = -sa * cp
        r02 = ca * sr + sa * sp * cr
        r10 = sa * cr + ca * sp * sr
        r11 = ca * cp
        r12 = sa * sr - ca * sp * cr
        r20 = -cp * sr
        r21 = sp
        r22 = cp * cr
        for q in range(h):
            r = heard[q]
            ddx = rx[r, 0] - S[i, X_M]
            ddy = rx[r, 1] - S[i, Y_M]
            ddz = rx[r, 2] - S[i, Z_M]
            vx = ddx * r00 + ddy * r10 + ddz * r20
            vy = ddx * r01 + ddy * r11 + ddz * r21
            vz = ddx * r02 + ddy * r12 + ddz * r22
            nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
            if nrm > 0.0:
                phi = math.atan2(vy, vx) * _RAD_TO_DEG
                theta = math.acos(min(max(vz / nrm, -1.0), 1.0)) * _RAD_TO_DEG
            else:
                phi = 0.0
                theta = 90.0
            m = _map_db(chan, r, S[i, X_M], S[i, Y_M], x0, dx, nx, y0, dy, ny)
            out[i, q] = m + tx_dbm + _pattern_dbi(d, phi, theta, pat[0], pat[1], pat[2])
    return out


@numba.njit(cache=True, inline="always")
def _inlier(u, log_eps):  # pragma: no cover - compiled
    """Cost ``ρ(u) = −log(exp(−u²/2) + ε′)`` of a standardised residual ``u`` and
    its inlier weight ``exp(−u²/2) / (exp(−u²/2) + ε′)`` (``log_eps = log ε′``)."""
    g = -0.5 * u * u
    m = max(g, log_eps)
    lse = m + math.log(math.exp(g - m) + math.exp(log_eps - m))
    return -lse, math.exp(g - lse)


@numba.njit(cache=True)
def measurement_update(S, pred, rss, sigma_db, log_eps, logw):  # pragma: no cover - compiled
    """Add each particle's log-likelihood of one packet to ``logw`` and update its
    power-offset belief in place (Rao-Blackwellised scalar Kalman filter).

    Each receiver's reading is an inlier, Gaussian in dB around the expected
    RSS, or with a small probability an outlier spread over the plausible RSS
    range: per receiver ``p(e) ∝ exp(−u²/2) + ε′``, ``u = (e − ē)/σ``, with
    ``ε′ = ε √(2π) σ / ((1 − ε) U)`` (``log_eps = log ε′``; ε the outlier
    probability, U the range in dB). A receiver far off costs at most
    ``−log ε′`` whatever its size (a 15 dB error does not throw the track), and
    it gets the inlier weight ``w_q = exp(−u²/2)/(exp(−u²/2) + ε′)`` in the
    offset update. With residuals ``e_q = rss_q − pred_q − b̄``, offset belief
    ``b ~ N(b̄, P)`` and ``ē`` the offset correction before weighting::

        log L = −Σ ρ(u_q) + ½ P (Σ w e/σ²)² / a − ½ log a,   a = 1 + P Σ w/σ²
        b̄ ← b̄ + P (Σ w e/σ²) / a,   P ← P / a

    A particle whose expected RSS is NaN (outside the survey) gets ``−inf``.
    """
    n = S.shape[0]
    h = rss.shape[0]
    s2 = sigma_db * sigma_db
    e = np.empty(h)
    for i in range(n):
        b = S[i, OFFSET_DB]
        p = S[i, OFFSET_VAR_DB2]
        sum_e = 0.0
        for q in range(h):
            e[q] = rss[q] - pred[i, q] - b
            sum_e += e[q]
        if math.isnan(sum_e):
            logw[i] = -np.inf
            continue
        ebar = p * sum_e / s2 / (1.0 + p * h / s2)
        sw = 0.0
        swe = 0.0
        cost = 0.0
        for q in range(h):
            rho, w = _inlier((e[q] - ebar) / sigma_db, log_eps)
            cost += rho
            sw += w
            swe += w * e[q]
        a = 1.0 + p * sw / s2
        logw[i] += -cost + 0.5 * p * (swe / s2) ** 2 / a - 0.5 * math.log(a)
        S[i, OFFSET_DB] = b + p * swe / s2 / a
        S[i, OFFSET_VAR_DB2] = p / a


@numba.njit(cache=True)
def fixed_offset_loglik(pred, rss, offset_db, sigma_db, log_eps, out):  # pragma: no cover
    """Add the log-likelihood of one packet at each row's fixed offset to ``out``
    (the inlier/outlier mixture of :func:`measurement_update`, ``−inf`` for NaN)."""
    n = pred.shape[0]
    h = rss.shape[0]
    for i in range(n):
        acc = 0.0
        for q in range(h):
            rho, _ = _inlier((rss[q] - pred[i, q] - offset_db[i]) / sigma_db, log_eps)
            acc += rho
        out[i] -= acc if not math.isnan(acc) else np.inf


@numba.njit(cache=True)
def systematic_resample(weights, u0):  # pragma: no cover - compiled
    """Systematic resampling: ``n`` ancestor indices for normalised ``weights``,
    one uniform draw ``u0`` in ``[0, 1)``."""
    n = weights.shape[0]
    idx = np.empty(n, np.int64)
    c = weights[0]
    j = 0
    for i in range(n):
        u = (u0 + i) / n
        while u > c and j < n - 1:
            j += 1
            c += weights[j]
        idx[i] = j
    return idx


@numba.njit(cache=True)
def log_sum_exp(logw):  # pragma: no cover - compiled
    """``log Σ exp(logw)`` (``-inf`` for an empty or all ``-inf`` vector)."""
    m = -np.inf
    for v in logw:
        if v > m:
            m = v
    if not math.isfinite(m):
        return m
    acc = 0.0
    for v in logw:
        acc += math.exp(v - m)
    return m + math.log(acc)


@numba.njit(cache=True, fastmath={"afn", "contract"})
def pose_moments(S, w, cols):  # pragma: no cover - compiled
    """Weighted moments of the pose columns ``cols`` = (x, y, z, azimuth, pitch, roll)
    of ``S`` with normalised weights ``w``: ``[x̄, ȳ, z̄, Σw cos a, Σw sin a, pitch̄,
    Σw cos r, Σw sin r, Σw ((x−x̄)² + (y−ȳ)²)]`` (angles in radians)."""
    out = np.zeros(9)
    n = S.shape[0]
    for i in range(n):
        wi = w[i]
        out[0] += wi * S[i, cols[0]]
        out[1] += wi * S[i, cols[1]]
        out[2] += wi * S[i, cols[2]]
        out[3] += wi * math.cos(S[i, cols[3]])
        out[4] += wi * math.sin(S[i, cols[3]])
        out[5] += wi * S[i, cols[4]]
        out[6] += wi * math.cos(S[i, cols[5]])
        out[7] += wi * math.sin(S[i, cols[5]])
    for i in range(n):
        dx = S[i, cols[0]] - out[0]
        dy = S[i, cols[1]] - out[1]
        out[8] += w[i] * (dx * dx + dy * dy)
    return out


@numba.njit(cache=True)
def median_squared_residual(S, pred, rss, w, lim2, u0):  # pragma: no cover - compiled
    """The posterior median over particles of the mean squared residual
    ``(rss − pred − b)²`` (each term clipped at ``lim2``; a NaN row counts as
    ``lim2``): the median of at most 256 particles drawn by systematic resampling
    of the normalised weights ``w`` (one uniform ``u0``), which estimates the
    ``w``-weighted median without sorting every particle."""
    n = S.shape[0]
    h = rss.shape[0]
    m = min(n, 256)
    r2 = np.empty(m)
    c = w[0]
    i = 0
    for k in range(m):
        u = (u0 + k) / m
        while u > c and i < n - 1:
            i += 1
            c += w[i]
        acc = 0.0
        for q in range(h):
            e = rss[q] - pred[i, q] - S[i, OFFSET_DB]
            acc += min(e * e, lim2)
        v = acc / h
        r2[k] = lim2 if math.isnan(v) else v
    r2.sort()
    return r2[(m - 1) // 2]
