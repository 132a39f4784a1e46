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

One module of ~850 lines on purpose: every kernel reads the same column
constants and the same off-grid lookup (inlined by numba across functions in
one module), and the two likelihoods (the outlier mixture and the Huber
alternative, ``FilterConfig.likelihood``) sit side by side so that a change to
one is seen beside the other.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiopose.filtering.vmath import vatan2, vexp, vlog, vsincos

X_M, Y_M, Z_M, VX_MPS, VY_MPS, AZIMUTH_RAD, RATE_RAD_S, PITCH_RAD, ROLL_RAD = range(9)
OFFSET_DB, OFFSET_VAR_DB2 = 9, 10
N_COLUMNS = 11
N_NOISE = 5
"""Standard normal draws per particle and step: x, y acceleration, angular
acceleration, pitch and roll steps."""

_TWO_PI = 2.0 * math.pi
_RAD_TO_DEG = 180.0 / math.pi


@numba.njit(cache=True, inline="always")
def wrap_pi(a):  # pragma: no cover - compiled
    """``a`` radians wrapped to ``[-π, π)`` (the filters' and the smoother's one wrap)."""
    return (a + math.pi) % _TWO_PI - math.pi


@numba.njit(cache=True, inline="always")
def _map_cell(x, y, x0, dx, nx, y0, dy, ny):  # pragma: no cover - compiled
    """The survey-map cell of ``(x, y)``, clamped to the grid: corner indices
    ``i0, i1, j0, j1`` and the bilinear fractions ``fu, fv`` (:func:`_map_db`)."""
    u = min(max((x - x0) / dx, 0.0), nx - 1.0) if nx > 1 else 0.0
    v = min(max((y - y0) / dy, 0.0), ny - 1.0) if ny > 1 else 0.0
    i0 = min(int(u), max(nx - 2, 0))
    j0 = min(int(v), max(ny - 2, 0))
    i1 = min(i0 + 1, nx - 1)
    j1 = min(j0 + 1, ny - 1)
    return i0, i1, j0, j1, u - i0, v - j0


@numba.njit(cache=True, inline="always")
def _map_at(chan, r, i0, i1, j0, j1, fu, fv):  # pragma: no cover - compiled
    """``M_r`` in the cell of :func:`_map_cell`, bilinear (NaN if a corner is NaN)."""
    a = chan[r, i0, j0] * (1.0 - fv) + chan[r, i0, j1] * fv
    b = chan[r, i1, j0] * (1.0 - fv) + chan[r, i1, j1] * fv
    return a * (1.0 - fu) + b * fu


@numba.njit(cache=True, inline="always")
def _map_db(chan, r, x, y, x0, dx, nx, y0, dy, ny):  # pragma: no cover - compiled
    """``M_r(x, y)``, bilinear, clamped to the grid (NaN if a corner is NaN)."""
    i0, i1, j0, j1, fu, fv = _map_cell(x, y, x0, dx, nx, y0, dy, ny)
    return _map_at(chan, r, i0, i1, j0, j1, fu, fv)


@numba.njit(cache=True, inline="always")
def _pattern_dbi(d, phi_deg, theta_deg, az0, az_step, polar_step):  # pragma: no cover
    """Bilinear pattern lookup, as :meth:`radiopose.patterns.pattern.Pattern.lookup_dbi`."""
    n_az = d.shape[0]
    n_pol = d.shape[1]
    a = phi_deg - az0
    # a % 360 (Python's sign rule) without fmod: the same numbers for |a| < 720
    if a < 0.0:
        a = a + 360.0 if a >= -360.0 else a % 360.0
    elif a >= 360.0:
        a = a - 360.0 if a < 720.0 else a % 360.0
    u = a / az_step
    w = 0.0 if n_pol == 1 else min(max(theta_deg, 0.0), 180.0) / polar_step
    fi0 = math.floor(u)
    fu = u - fi0
    i0 = int(fi0)
    if i0 >= n_az:
        i0 %= n_az
    i1 = i0 + 1 if i0 + 1 < n_az else 0
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


@numba.njit(cache=True, inline="always")
def body_rotation(ca, sa, cp, sp, cr, sr):  # pragma: no cover - compiled
    """The elements ``r00 … r22`` of ``R = Rz(a)·Rx(p)·Ry(r)`` (body to world; a
    direction ``d`` in the body frame is ``Rᵀ d``) from the cosines and sines of
    azimuth, pitch and roll."""
    return (
        ca * cr - sa * sp * sr,
        -sa * cp,
        ca * sr + sa * sp * cr,
        sa * cr + ca * sp * sr,
        ca * cp,
        sa * sr - ca * sp * cr,
        -cp * sr,
        sp,
        cp * cr,
    )


@numba.njit(cache=True, inline="always")
def _expected_row(S, i, heard, rx, chan, grid, tx_dbm, d, pat, out, row):  # pragma: no cover
    """Expected RSS of particle ``i`` at the heard receivers into ``out[row, :h]``
    (see :func:`expected_rss_dbm`)."""
    x0, dx, nx, y0, dy, ny = grid[0], grid[1], int(grid[2]), grid[3], grid[4], int(grid[5])
    x = S[i, X_M]
    y = S[i, Y_M]
    pitch = S[i, PITCH_RAD]
    roll = S[i, ROLL_RAD]
    ca = math.cos(S[i, AZIMUTH_RAD])
    sa = math.sin(S[i, AZIMUTH_RAD])
    if pitch == 0.0 and roll == 0.0:  # the same numbers as the general case, cheaper
        cp, sp, cr, sr = 1.0, 0.0, 1.0, 0.0
    else:
        cp = math.cos(pitch)
        sp = math.sin(pitch)
        cr = math.cos(roll)
        sr = math.sin(roll)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = body_rotation(ca, sa, cp, sp, cr, sr)
    slice_pattern = d.shape[1] == 1  # polar angle unused: no acos
    for q in range(heard.shape[0]):
        r = heard[q]
        ddx = rx[r, 0] - x
        ddy = rx[r, 1] - y
        ddz = rx[r, 2] - S[i, Z_M]
        vx = ddx * r00 + ddy * r10 + ddz * r20
        vy = ddx * r01 + ddy * r11 + ddz * r21
        vz = ddx * r02 + ddy * r12 + ddz * r22
        if vx == 0.0 and vy == 0.0 and vz == 0.0:
            phi = 0.0
            theta = 90.0
        else:
            phi = math.atan2(vy, vx) * _RAD_TO_DEG
            if slice_pattern:
                theta = 90.0
            else:
                nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
                theta = math.acos(min(max(vz / nrm, -1.0), 1.0)) * _RAD_TO_DEG
        m = _map_db(chan, r, x, y, x0, dx, nx, y0, dy, ny)
        out[row, q] = m + tx_dbm + _pattern_dbi(d, phi, theta, pat[0], pat[1], pat[2])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _pattern_dbi_near(d, phi_deg, theta_deg, az0, az_step, polar_step):  # pragma: no cover
    """:func:`_pattern_dbi` for ``phi_deg − az0`` in ``[−360, 720)`` (a pattern
    azimuth from ``atan2`` and ``az0`` in ``[0, step)``): the same numbers,
    branch-free (the wrap by one turn as selects), so that a loop over
    particles vectorises."""
    n_az = d.shape[0]
    n_pol = d.shape[1]
    a = phi_deg - az0
    a = a + 360.0 if a < 0.0 else a
    a = a - 360.0 if a >= 360.0 else a
    u = a / az_step
    w = 0.0 if n_pol == 1 else min(max(theta_deg, 0.0), 180.0) / polar_step
    fi0 = math.floor(u)
    fu = u - fi0
    i0 = int(fi0)
    i0 = i0 - n_az if i0 >= n_az else i0
    i1 = i0 + 1 if i0 + 1 < n_az else 0
    j0 = min(int(w), n_pol - 1)
    fw = w - j0
    j1 = min(j0 + 1, n_pol - 1)
    top = d[i0, j0] * (1.0 - fu) + d[i1, j0] * fu
    bot = d[i0, j1] * (1.0 - fu) + d[i1, j1] * fu
    return top * (1.0 - fw) + bot * fw


@numba.njit(cache=True, error_model="numpy")
def expected_rss_into(S, heard, rx, chan, grid, tx_dbm, d, pat, out):  # pragma: no cover
    """:func:`expected_rss_dbm` into a preallocated ``out`` ``(n, h)``.

    Receiver-major (docs/performance.md, "Fourth pass"): per particle first its
    survey-map cell, then its rotation in a loop without library calls
    (``cos``/``sin`` are :func:`~radiopose.filtering.vmath.vsincos`; it
    vectorises); then per heard receiver the pattern azimuth of every
    particle in a loop without library calls (``atan2`` is
    :func:`~radiopose.filtering.vmath.vatan2`; the loop vectorises), then the
    map's and the pattern's bilinear lookups (gathers: scalar). The polar angle
    of a full-sphere pattern takes the C library's ``acos``.
    """
    n = S.shape[0]
    x0, dx, nx, y0, dy, ny = grid[0], grid[1], int(grid[2]), grid[3], grid[4], int(grid[5])
    rot = np.empty((9, n))
    xs = np.empty(n)
    ys = np.empty(n)
    zs = np.empty(n)
    angles = np.empty((3, n))  # azimuth, pitch, roll
    cell = np.empty((4, n), np.int64)
    frac = np.empty((2, n))
    for i in range(n):
        x = S[i, X_M]
        y = S[i, Y_M]
        xs[i] = x
        ys[i] = y
        zs[i] = S[i, Z_M]
        angles[0, i] = S[i, AZIMUTH_RAD]
        angles[1, i] = S[i, PITCH_RAD]
        angles[2, i] = S[i, ROLL_RAD]
        i0, i1, j0, j1, fu, fv = _map_cell(x, y, x0, dx, nx, y0, dy, ny)
        cell[0, i] = i0
        cell[1, i] = i1
        cell[2, i] = j0
        cell[3, i] = j1
        frac[0, i] = fu
        frac[1, i] = fv
    for i in range(n):  # no library calls: SIMD (vsincos(0) = (0, 1) exactly)
        sa, ca = vsincos(angles[0, i])
        sp, cp = vsincos(angles[1, i])
        sr, cr = vsincos(angles[2, i])
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = body_rotation(ca, sa, cp, sp, cr, sr)
        rot[0, i] = r00
        rot[1, i] = r01
        rot[2, i] = r02
        rot[3, i] = r10
        rot[4, i] = r11
        rot[5, i] = r12
        rot[6, i] = r20
        rot[7, i] = r21
        rot[8, i] = r22
    phi = np.empty(n)
    theta = np.full(n, 90.0)
    slice_pattern = d.shape[1] == 1  # polar angle unused: no acos
    for q in range(heard.shape[0]):
        r = heard[q]
        rx0 = rx[r, 0]
        rx1 = rx[r, 1]
        rx2 = rx[r, 2]
        for i in range(n):  # no library calls, no gathers: SIMD
            ddx = rx0 - xs[i]
            ddy = rx1 - ys[i]
            ddz = rx2 - zs[i]
            vx = ddx * rot[0, i] + ddy * rot[3, i] + ddz * rot[6, i]
            vy = ddx * rot[1, i] + ddy * rot[4, i] + ddz * rot[7, i]
            vz = ddx * rot[2, i] + ddy * rot[5, i] + ddz * rot[8, i]
            here = vx == 0.0 and vy == 0.0 and vz == 0.0
            phi[i] = 0.0 if here else vatan2(vy, vx) * _RAD_TO_DEG
        if not slice_pattern:
            for i in range(n):
                ddx = rx0 - xs[i]
                ddy = rx1 - ys[i]
                ddz = rx2 - zs[i]
                vx = ddx * rot[0, i] + ddy * rot[3, i] + ddz * rot[6, i]
                vy = ddx * rot[1, i] + ddy * rot[4, i] + ddz * rot[7, i]
                vz = ddx * rot[2, i] + ddy * rot[5, i] + ddz * rot[8, i]
                if vx == 0.0 and vy == 0.0 and vz == 0.0:
                    theta[i] = 90.0
                else:
                    nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
                    theta[i] = math.acos(min(max(vz / nrm, -1.0), 1.0)) * _RAD_TO_DEG
        for i in range(n):
            m = _map_at(
                chan, r, cell[0, i], cell[1, i], cell[2, i], cell[3, i], frac[0, i], frac[1, i]
            )
            out[i, q] = m + tx_dbm + _pattern_dbi_near(d, phi[i], theta[i], pat[0], pat[1], pat[2])


@numba.njit(cache=True)
def expected_rss_dbm(S, heard, rx, chan, grid, tx_dbm, d, pat):  # pragma: no cover - compiled
    """Expected RSS ``(n, h)`` dBm of every particle at the heard receivers,
    without the power offset. ``grid`` = ``[x0, dx, nx, y0, dy, ny]``;
    ``pat`` = ``[az0, az_step, polar_step]`` (degrees).

    Serial: a packet's few thousand particles take well under a millisecond,
    less than what a parallel region costs to start on a busy 2-core machine.
    """
    out = np.empty((S.shape[0], heard.shape[0]))
    expected_rss_into(S, heard, rx, chan, grid, tx_dbm, d, pat, out)
    return out


@numba.njit(cache=True, inline="always", error_model="numpy")
def _inlier(u, log_eps):  # pragma: no cover - compiled
    """Cost ``ρ(u) = −log(exp(−u²/2) + ε′)`` of a standardised residual ``u`` and
    its inlier weight ``exp(−u²/2) / (exp(−u²/2) + ε′)`` (``log_eps = log ε′``).

    Branch-free, with :mod:`radiopose.filtering.vmath`'s ``exp``/``log`` (not the
    C library's, within 2 ulp of it), so that a loop over particles calling it
    vectorises (:func:`measurement_update`)."""
    g = -0.5 * u * u
    m = max(g, log_eps)
    # m + log(exp(g − m) + exp(log ε′ − m)): one of the two exponentials is
    # exp(0) = 1 exactly and the other exp(−|g − log ε′|), so one exp is not
    # computed
    lse = m + vlog(1.0 + vexp(-abs(g - log_eps)))
    return -lse, vexp(g - lse)


@numba.njit(cache=True, inline="always")
def _offset_residuals(S, i, pred, rss, s2, e):  # pragma: no cover - compiled
    """Particle ``i``'s residuals ``e_q = rss_q − pred_q − b̄`` into ``e`` and the
    offset correction before weighting ``ē = P Σe/σ² / (1 + P h/σ²)``; returns
    ``(b̄, P, ē)``, ``ē`` NaN when a residual is (expected RSS outside the survey).
    Shared by the likelihoods (:func:`measurement_update`, its Huber twin)."""
    b = S[i, OFFSET_DB]
    p = S[i, OFFSET_VAR_DB2]
    h = rss.shape[0]
    sum_e = 0.0
    for q in range(h):
        e[q] = rss[q] - pred[i, q] - b
        sum_e += e[q]
    if math.isnan(sum_e):
        return b, p, math.nan
    return b, p, p * sum_e / s2 / (1.0 + p * h / s2)


@numba.njit(cache=True, inline="always")
def _update_offset(S, i, b, p, swe, s2, a):  # pragma: no cover - compiled
    """The scalar Kalman update of particle ``i``'s offset belief from the weighted
    residual sum ``Σ w e`` (over ``s2 = σ²``) and ``a = 1 + P Σ w/σ²``."""
    S[i, OFFSET_DB] = b + p * swe / s2 / a
    S[i, OFFSET_VAR_DB2] = p / a


@numba.njit(cache=True, error_model="numpy")
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

    Receiver-major passes over contiguous per-particle arrays (the offsets, the
    expected RSS of one receiver, the sums), so that the loops over particles
    vectorise with the branch-free :func:`_inlier` (docs/performance.md,
    "Fourth pass"); each particle's sums run over the receivers in order, as
    in a particle-major loop.
    """
    n = S.shape[0]
    h = rss.shape[0]
    s2 = sigma_db * sigma_db
    b = np.empty(n)
    p = np.empty(n)
    ebar = np.zeros(n)
    sw = np.zeros(n)
    swe = np.zeros(n)
    cost = np.zeros(n)
    cols = np.empty((h, n))  # pred receiver-major: contiguous loads
    for i in range(n):
        b[i] = S[i, OFFSET_DB]
        p[i] = S[i, OFFSET_VAR_DB2]
        for q in range(h):
            cols[q, i] = pred[i, q]
    for q in range(h):
        # the residuals e_q = rss_q − pred_q − b̄ summed (ē below; NaN: outside)
        rq = rss[q]
        col = cols[q]
        for i in range(n):
            ebar[i] += rq - col[i] - b[i]
    for i in range(n):
        ebar[i] = p[i] * ebar[i] / s2 / (1.0 + p[i] * h / s2)
    for q in range(h):
        rq = rss[q]
        col = cols[q]
        for i in range(n):
            e = rq - col[i] - b[i]
            u = (e - ebar[i]) / sigma_db
            rho, w = _inlier(0.0 if math.isnan(u) else u, log_eps)
            cost[i] += rho
            sw[i] += w
            swe[i] += w * e
    for i in range(n):
        if math.isnan(ebar[i]):
            logw[i] = -np.inf
            continue
        a = 1.0 + p[i] * sw[i] / s2
        logw[i] += -cost[i] + 0.5 * p[i] * (swe[i] / s2) ** 2 / a - 0.5 * vlog(a)
        _update_offset(S, i, b[i], p[i], swe[i], s2, a)


@numba.njit(cache=True, error_model="numpy")
def fixed_offset_loglik(pred, rss, offset_db, sigma_db, log_eps, out):  # pragma: no cover
    """Add the log-likelihood of one packet at each row's fixed offset to ``out``
    (the inlier/outlier mixture of :func:`measurement_update`, ``−inf`` for NaN);
    receiver-major like it, so that the loop over rows vectorises."""
    n = pred.shape[0]
    h = rss.shape[0]
    acc = np.zeros(n)
    nan = np.zeros(n)  # NaN where a residual is
    col = np.empty(n)
    for q in range(h):
        rq = rss[q]
        for i in range(n):
            col[i] = pred[i, q]
        for i in range(n):
            u = (rq - col[i] - offset_db[i]) / sigma_db
            rho, _ = _inlier(0.0 if math.isnan(u) else u, log_eps)
            acc[i] += rho
            nan[i] += u - u
    for i in range(n):
        out[i] -= np.inf if math.isnan(nan[i]) else acc[i]


@numba.njit(cache=True)
def systematic_indices_into(weights, u0, idx):  # pragma: no cover - compiled
    """Systematic resampling: ``n`` ancestor indices for normalised ``weights``
    into ``idx``, one uniform draw ``u0`` in ``[0, 1)``."""
    n = weights.shape[0]
    c = weights[0]
    j = 0
    for i in range(n):
        u = (u0 + i) / n
        while u > c and j < n - 1:
            j += 1
            c += weights[j]
        idx[i] = j


@numba.njit(cache=True)
def systematic_resample(weights, u0):  # pragma: no cover - compiled
    """Systematic resampling: ``n`` ancestor indices for normalised ``weights``,
    one uniform draw ``u0`` in ``[0, 1)``."""
    idx = np.empty(weights.shape[0], np.int64)
    systematic_indices_into(weights, u0, idx)
    return idx


# ----------------------------------------------------------------------------- one packet
# The per-packet path of ParticleFilter.step in few compiled calls: no
# (n, h)-sized temporaries from Python, resampling in place.


@numba.njit(cache=True)
def log_sum_exp(logw):  # pragma: no cover - compiled
    """``log Σ exp(logw)`` (``-inf`` if every entry is ``-inf``)."""
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


@numba.njit(cache=True)
def normalise_into(logw, w):  # pragma: no cover - compiled
    """Normalised weights ``w = exp(logw − max) / Σ``; returns ``log Σ exp(logw)``
    from the same exponentials (``w`` untouched and the max returned when no
    entry of ``logw`` is finite)."""
    top = -np.inf
    for v in logw:
        if v > top:
            top = v
    if not math.isfinite(top):
        return top
    total = 0.0
    for i in range(logw.shape[0]):
        w[i] = math.exp(logw[i] - top)
        total += w[i]
    for i in range(logw.shape[0]):
        w[i] /= total
    return top + math.log(total)


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_TWO_M32 = 1.0 / 4294967296.0


@numba.njit(cache=True, error_model="numpy", nogil=True)
def motion_noise_into(noise, seed, row0, tilt_box):  # pragma: no cover - compiled
    """Standard normal draws of :func:`predict` for the rows of ``noise`` ``(n,
    N_NOISE)``, counter-based: row ``i`` of the block is particle ``row0 + i`` of
    the packet, and its draws depend only on ``seed`` (one 63-bit integer per
    packet, drawn by the caller from the track's generator) and that particle
    index. So a block of rows gives the same numbers whether the packet's
    particles are filled in one call or in two blocks on two threads
    (:func:`packet_update` with ``row0``).

    Each pair of draws is a Box-Muller transform of the two 32-bit halves of
    splitmix64 (S. Vigna's finaliser) of ``seed + (2 · particle + pair + 1) ·
    φ·2⁶⁴`` (the largest draw is ≈ 6.7; moments and independence are checked by
    ``tests/test_filter_kernels.py``). The x, y and angular accelerations and
    the pitch step are the first two pairs; the roll step, the third pair's
    first draw, is made only when ``tilt_box`` leaves roll free (a frozen axis
    is never read by :func:`predict`; its column is left as it was). Two
    branch-free loops over the draws (integer hashing, then :mod:`vmath`'s
    ``log`` and ``sincos``) that vectorise: ≈ 5× faster than numpy's ziggurat
    for the same number of draws (docs/performance.md, "Counter-based motion
    noise")."""
    n = noise.shape[0]
    pairs = 3 if tilt_box[3] > tilt_box[2] else 2
    total = n * pairs
    s = np.uint64(seed)
    base = np.uint64(row0 * 3 + 1)
    u = np.empty((2, total))
    for k in range(total):
        i = k // pairs
        z = s + (base + np.uint64(i * 3 + k - i * pairs)) * _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
        z = z ^ (z >> np.uint64(31))
        u[0, k] = (np.float64(z >> np.uint64(32)) + 0.5) * _TWO_M32
        u[1, k] = np.float64(z & np.uint64(0xFFFFFFFF)) * _TWO_M32
    for k in range(total):
        r = math.sqrt(-2.0 * vlog(u[0, k]))
        sn, cs = vsincos(_TWO_PI * u[1, k])
        u[0, k] = r * cs
        u[1, k] = r * sn
    for i in range(n):
        k = i * pairs
        noise[i, 0] = u[0, k]
        noise[i, 1] = u[1, k]
        noise[i, 2] = u[0, k + 1]
        noise[i, 3] = u[1, k + 1]
        if pairs == 3:
            noise[i, 4] = u[0, k + 2]


@numba.njit(cache=True, nogil=True)
def packet_update(  # pragma: no cover - compiled
    S, logw, noise, seed, row0, dt_s, motion, box, tilt_box,
    heard, rx, chan, grid, tx_dbm, d, pat,
    rss, sigma_db, likelihood_parameter, pred, w,
):  # fmt: skip
    """One packet's predict + weight in one call.

    :func:`predict` by ``dt_s`` (skipped if ``dt_s <= 0``; ``motion`` =
    ``[q_acc, q_rate, q_tilt, max_speed, max_rate]`` as in :func:`predict`)
    with the draws of :func:`motion_noise_into` (``seed``, ``row0``: the first
    row's index among the packet's particles) in the work array ``noise``,
    the expected RSS into ``pred`` ``(n, h)`` (:func:`expected_rss_into`), the
    likelihood (:func:`measurement_update`, which alone defines it:
    ``likelihood_parameter`` is its scalar after σ), and, if any particle is
    still possible, the normalised weights into ``w``.

    Returns ``(lse0, lse1)``: ``log Σ exp(logw)`` before and after the packet
    (their difference is the packet's evidence; ``lse1 = -inf`` if every
    particle became impossible).

    Each particle's predict, expected RSS and likelihood use only its own row,
    so the call may run on a block of rows (views of ``S``, ``logw``, ``noise``,
    ``pred``, ``w``) while another thread runs the others (it releases the GIL);
    the weights and ``lse`` of the whole set are then taken over all rows
    (:func:`log_sum_exp`, :func:`normalise_into`: the same numbers).
    """
    if dt_s > 0.0:
        motion_noise_into(noise, seed, row0, tilt_box)
        predict(
            S, noise, dt_s, motion[0], motion[1], motion[2], motion[3], motion[4], box, tilt_box
        )
    lse0 = log_sum_exp(logw)
    expected_rss_into(S, heard, rx, chan, grid, tx_dbm, d, pat, pred)
    measurement_update(S, pred, rss, sigma_db, likelihood_parameter, logw)
    return lse0, normalise_into(logw, w)


POSE_ROW = 8
"""Columns of a pose row: x, y, z, cos azimuth, sin azimuth, pitch, cos roll, sin roll."""


@numba.njit(cache=True, error_model="numpy")
def posterior_moments(S, w, rows, m):  # pragma: no cover - compiled
    """Weighted moments of the particles (normalised ``w``)::

        [x̄, ȳ, z̄, Σw cos a, Σw sin a, pitch̄, Σw cos r, Σw sin r,
         Σw ((x − x̄)² + (y − ȳ)²), b̄ (offset mean), Σw²]

    into ``m`` ``(11,)`` (angles radians; ``1 / Σw²`` is the effective sample
    size). The particles' pose rows (:data:`POSE_ROW`: x, y, z, cos a, sin a,
    pitch, cos r, sin r) go to ``rows`` ``(n, POSE_ROW)``: what the smoother
    keeps (:func:`lineage_moments`). ``cos``/``sin`` are
    :func:`~radiopose.filtering.vmath.vsincos`, in a loop of their own (SIMD).
    """
    n = S.shape[0]
    ang = np.empty((2, n))
    trig = np.empty((4, n))
    for i in range(n):
        ang[0, i] = S[i, AZIMUTH_RAD]
        ang[1, i] = S[i, ROLL_RAD]
    for i in range(n):
        sa, ca = vsincos(ang[0, i])
        sr, cr = vsincos(ang[1, i])  # (0, 1) exactly for roll 0
        trig[0, i] = ca
        trig[1, i] = sa
        trig[2, i] = cr
        trig[3, i] = sr
    m[:] = 0.0
    for i in range(n):
        rows[i, 0] = S[i, X_M]
        rows[i, 1] = S[i, Y_M]
        rows[i, 2] = S[i, Z_M]
        rows[i, 3] = trig[0, i]
        rows[i, 4] = trig[1, i]
        rows[i, 5] = S[i, PITCH_RAD]
        rows[i, 6] = trig[2, i]
        rows[i, 7] = trig[3, i]
        wi = w[i]
        for c in range(POSE_ROW):
            m[c] += wi * rows[i, c]
        m[9] += wi * S[i, OFFSET_DB]
        m[10] += wi * wi
    for i in range(n):
        dx = S[i, X_M] - m[0]
        dy = S[i, Y_M] - m[1]
        m[8] += w[i] * (dx * dx + dy * dy)


@numba.njit(cache=True)
def lineage_moments(rows, anc, w, m):  # pragma: no cover - compiled
    """The first nine :func:`posterior_moments` of the pose rows ``rows[anc[i]]``
    (``rows`` ``(·, POSE_ROW)``) with weights ``w[i]``, into ``m[:9]``."""
    m[:] = 0.0
    for i in range(anc.shape[0]):
        k = anc[i]
        wi = w[i]
        for c in range(POSE_ROW):
            m[c] += wi * rows[k, c]
    for i in range(anc.shape[0]):
        k = anc[i]
        dx = rows[k, 0] - m[0]
        dy = rows[k, 1] - m[1]
        m[8] += w[i] * (dx * dx + dy * dy)


@numba.njit(cache=True)
def resample_in_place(S, w, u0, scratch, idx):  # pragma: no cover - compiled
    """Systematic resampling of the rows of ``S`` in place (``scratch`` a
    same-shaped work array); the ancestor indices go to ``idx``."""
    n = S.shape[0]
    systematic_indices_into(w, u0, idx)
    scratch[:, :] = S
    for i in range(n):
        S[i, :] = scratch[idx[i], :]


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


@numba.njit(cache=True)
def push_differences(  # pragma: no cover - compiled
    heard, rss, t_s, max_dt_s, last_rss, last_time_s, diff2, count
):
    """Record the squared differences of this packet's readings from each
    receiver's previous one at most ``max_dt_s`` earlier (``0 < gap <= max_dt_s``)
    into the ring ``diff2`` (slot ``count % len``, ``count`` then advanced), then
    make this packet's readings the receivers' last (``last_rss``,
    ``last_time_s`` per receiver, updated in place). Returns the new count."""
    size = diff2.shape[0]
    for q in range(heard.shape[0]):
        r = heard[q]
        gap = t_s - last_time_s[r]
        if gap > 0.0 and gap <= max_dt_s:
            d = rss[q] - last_rss[r]
            diff2[count % size] = d * d
            count += 1
    for q in range(heard.shape[0]):
        r = heard[q]
        last_rss[r] = rss[q]
        last_time_s[r] = t_s
    return count


@numba.njit(cache=True)
def median_of_first(values, n):  # pragma: no cover - compiled
    """``np.median(values[:n])`` (the same number: the middle value, or the mean
    of the two middle values, by selection instead of numpy's call overhead)."""
    return np.median(values[:n])


# ----------------------------------------------------------------------------- Huber likelihood
# FilterConfig.likelihood = "huber" (issue 16, the real BLE site): the previous
# design's Huber-weighted Gaussian, beside the default outlier mixture above.
# New functions only; the mixture's path is untouched.


@numba.njit(cache=True)
def measurement_update_huber(S, pred, rss, sigma_db, huber_c, logw):  # pragma: no cover
    """:func:`measurement_update` with Huber weights instead of the outlier mixture.

    With residuals ``e_q = rss_q − pred_q − b̄`` and offset belief
    ``b ~ N(b̄, P)``, the marginal of ``e`` is ``N(0, Σ + P·11ᵀ)`` with
    ``Σ = diag(σ²/w_q)``; Huber weights ``w_q = min(1, c σ / |e_q − ē|)``
    (``ē`` the offset correction before weighting; ``c = huber_c``) make a
    receiver far off count linearly instead of quadratically::

        log L = −½ [Σ w e²/σ² − P (Σ w e/σ²)² / a] − ½ log a,   a = 1 + P Σ w/σ²
        b̄ ← b̄ + P (Σ w e/σ²) / a,   P ← P / a

    A particle whose expected RSS is NaN (outside the survey) gets ``−inf``.
    """
    n = S.shape[0]
    h = rss.shape[0]
    s2 = sigma_db * sigma_db
    e = np.empty(h)
    for i in range(n):
        b, p, ebar = _offset_residuals(S, i, pred, rss, s2, e)
        if math.isnan(ebar):
            logw[i] = -np.inf
            continue
        sw = 0.0
        swe = 0.0
        swee = 0.0
        for q in range(h):
            u = abs(e[q] - ebar) / sigma_db
            w = 1.0 if u <= huber_c else huber_c / u
            sw += w
            swe += w * e[q]
            swee += w * e[q] * e[q]
        a = 1.0 + p * sw / s2
        logw[i] += -0.5 * (swee / s2 - p * (swe / s2) ** 2 / a) - 0.5 * math.log(a)
        _update_offset(S, i, b, p, swe, s2, a)


@numba.njit(cache=True)
def fixed_offset_loglik_huber(pred, rss, offset_db, sigma_db, huber_c, out):  # pragma: no cover
    """Add the Huber log-likelihood of one packet at each row's fixed offset to
    ``out`` (:func:`measurement_update_huber`'s cost, ``−inf`` for NaN)."""
    n = pred.shape[0]
    h = rss.shape[0]
    half_c2 = 0.5 * huber_c * huber_c
    for i in range(n):
        acc = 0.0
        for q in range(h):
            u = abs(rss[q] - pred[i, q] - offset_db[i]) / sigma_db
            acc += 0.5 * u * u if u <= huber_c else huber_c * u - half_c2
        out[i] -= acc if not math.isnan(acc) else np.inf


@numba.njit(cache=True, nogil=True)
def packet_update_huber(  # pragma: no cover - compiled
    S, logw, noise, seed, row0, dt_s, motion, box, tilt_box,
    heard, rx, chan, grid, tx_dbm, d, pat,
    rss, sigma_db, huber_c, pred, w,
):  # fmt: skip
    """:func:`packet_update` with :func:`measurement_update_huber` as the likelihood
    (``huber_c`` the Huber threshold in units of σ); the same arguments and returns."""
    if dt_s > 0.0:
        motion_noise_into(noise, seed, row0, tilt_box)
        predict(
            S, noise, dt_s, motion[0], motion[1], motion[2], motion[3], motion[4], box, tilt_box
        )
    lse0 = log_sum_exp(logw)
    expected_rss_into(S, heard, rx, chan, grid, tx_dbm, d, pat, pred)
    measurement_update_huber(S, pred, rss, sigma_db, huber_c, logw)
    return lse0, normalise_into(logw, w)
