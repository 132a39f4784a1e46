"""Compiled kernels of the 3-D filter (:mod:`radiopose.filtering.particle3d`).

Radians inside, metres, dB; the particle matrix ``S`` and its columns are the
2-D filter's (:mod:`radiopose.filtering.kernels`, whose map and pattern
lookups, motion prediction and likelihood these reuse). What 3-D adds: the
survey map moved to the particle's height along 3-D distance
(:mod:`radiopose.survey_height`), the full-sphere expected RSS, random walks
of pitch (gimbal-aware), roll (periodic) and height, and the coarse grid's
scoring with the offset profiled out.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M

_TWO_PI = 2.0 * math.pi
_RAD_TO_DEG = 180.0 / math.pi


@numba.njit(cache=True, inline="always")
def _channel_db(maps, layers_z, exponent, r, x, y, z, horiz2, rz, g):  # pragma: no cover
    """``M_r(x, y, z)``: the surveyed maps moved along 3-D distance (survey_height)."""
    x0, dx, nx, y0, dy, ny = g[0], g[1], int(g[2]), g[3], g[4], int(g[5])
    d = math.sqrt(horiz2 + (rz - z) ** 2)
    ld = math.log10(max(d, 1.0))
    n_layer = layers_z.shape[0]
    lo = 0
    frac = 0.0
    if n_layer > 1:
        while lo < n_layer - 2 and z >= layers_z[lo + 1]:
            lo += 1
        frac = min(max((z - layers_z[lo]) / (layers_z[lo + 1] - layers_z[lo]), 0.0), 1.0)
    zl = layers_z[lo]
    ds = math.sqrt(horiz2 + (rz - zl) ** 2)
    m = K._map_db(maps[lo], r, x, y, x0, dx, nx, y0, dy, ny) - 10.0 * exponent * (
        ld - math.log10(max(ds, 1.0))
    )
    if frac > 0.0:
        zh = layers_z[lo + 1]
        ds = math.sqrt(horiz2 + (rz - zh) ** 2)
        mh = K._map_db(maps[lo + 1], r, x, y, x0, dx, nx, y0, dy, ny) - 10.0 * exponent * (
            ld - math.log10(max(ds, 1.0))
        )
        m = (1.0 - frac) * m + frac * mh
    return m


@numba.njit(cache=True)
def expected3d_into(
    S, heard, rx, maps, layers_z, exponent, grid, tx_dbm, d, pat, out
):  # pragma: no cover
    """Expected RSS ``(n, h)`` dBm without the offset into ``out``: the height
    model's channel + ``tx_dbm`` + the full-sphere pattern toward each receiver
    in the body frame of ``R = Rz(az)·Rx(pitch)·Ry(roll)``."""
    for i in range(S.shape[0]):
        x = S[i, K.X_M]
        y = S[i, K.Y_M]
        z = S[i, K.Z_M]
        ca = math.cos(S[i, K.AZIMUTH_RAD])
        sa = math.sin(S[i, K.AZIMUTH_RAD])
        cp = math.cos(S[i, K.PITCH_RAD])
        sp = math.sin(S[i, K.PITCH_RAD])
        cr = math.cos(S[i, K.ROLL_RAD])
        sr = math.sin(S[i, K.ROLL_RAD])
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = K.body_rotation(ca, sa, cp, sp, cr, sr)
        for q in range(heard.shape[0]):
            r = heard[q]
            ddx = rx[r, 0] - x
            ddy = rx[r, 1] - y
            ddz = rx[r, 2] - z
            vx = ddx * r00 + ddy * r10 + ddz * r20
            vy = ddx * r01 + ddy * r11 + ddz * r21
            vz = ddx * r02 + ddy * r12 + ddz * r22
            nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
            if nrm == 0.0:
                phi = 0.0
                theta = 90.0
            else:
                phi = math.atan2(vy, vx) * _RAD_TO_DEG
                theta = math.acos(min(max(vz / nrm, -1.0), 1.0)) * _RAD_TO_DEG
            m = _channel_db(maps, layers_z, exponent, r, x, y, z, ddx * ddx + ddy * ddy,
                            rx[r, 2], grid)  # fmt: skip
            out[i, q] = m + tx_dbm + K._pattern_dbi(d, phi, theta, pat[0], pat[1], pat[2])


@numba.njit(cache=True)
def tilt_height_step(S, noise_tilt, noise_z, dt_s, q_tilt, q_z, tilt, z_box):  # pragma: no cover
    """Random walks of pitch, roll and height by ``dt_s`` in place.

    ``tilt`` = ``[pitch_lo, pitch_hi, roll_centre, roll_half_width]`` radians:
    pitch reflected at its ends, except over a pole (an end at ±π/2), where
    ``(az, p, r) → (az + π, ±π − p, r + π)`` writes the same rotation with
    pitch back in range (gimbal); roll as an offset ``u = wrap(r − centre)``
    reflected at ``±half_width``, or wrapped when the half width is ≥ π.
    Height reflected into ``z_box`` = ``[z_lo, z_hi]`` (frozen if equal).
    """
    sq = math.sqrt(dt_s)
    half_pi = 0.5 * math.pi
    for i in range(S.shape[0]):
        if tilt[1] > tilt[0]:
            p = S[i, K.PITCH_RAD] + q_tilt * sq * noise_tilt[i, 0]
            flip = False
            if p > tilt[1]:
                if tilt[1] >= half_pi:
                    p = math.pi - p
                    flip = True
                else:
                    p = 2.0 * tilt[1] - p
            elif p < tilt[0]:
                if tilt[0] <= -half_pi:
                    p = -math.pi - p
                    flip = True
                else:
                    p = 2.0 * tilt[0] - p
            S[i, K.PITCH_RAD] = min(max(p, tilt[0]), tilt[1])
            if flip:
                S[i, K.AZIMUTH_RAD] = (S[i, K.AZIMUTH_RAD] + math.pi) % _TWO_PI
                S[i, K.ROLL_RAD] = S[i, K.ROLL_RAD] + math.pi
        if tilt[3] > 0.0:
            u = S[i, K.ROLL_RAD] + q_tilt * sq * noise_tilt[i, 1] - tilt[2]
            u = (u + math.pi) % _TWO_PI - math.pi
            if tilt[3] < math.pi:
                if u > tilt[3]:
                    u = 2.0 * tilt[3] - u
                elif u < -tilt[3]:
                    u = -2.0 * tilt[3] - u
                u = min(max(u, -tilt[3]), tilt[3])
            r = tilt[2] + u
            S[i, K.ROLL_RAD] = (r + math.pi) % _TWO_PI - math.pi
        if z_box[1] > z_box[0]:
            z = S[i, K.Z_M] + q_z * sq * noise_z[i]
            if z < z_box[0]:
                z = 2.0 * z_box[0] - z
            if z > z_box[1]:
                z = 2.0 * z_box[1] - z
            S[i, K.Z_M] = min(max(z, z_box[0]), z_box[1])


@numba.njit(cache=True)
def packet_update3d(  # pragma: no cover - compiled
    S, logw, noise, noise_z, dt_s, motion, box, tilt, z_box,
    heard, rx, maps, layers_z, exponent, grid, tx_dbm, d, pat,
    rss, sigma_db, log_eps, pred, w,
):  # fmt: skip
    """One packet: predict (the 2-D :func:`kernels.predict` for x, y, azimuth,
    then :func:`tilt_height_step`), expected RSS (:func:`expected3d_into`), the
    2-D likelihood (:func:`kernels.measurement_update`) and normalised weights.
    Returns ``(lse0, lse1)`` as :func:`kernels.packet_update`."""
    if dt_s > 0.0:
        frozen = np.zeros(4)
        K.predict(S, noise, dt_s, motion[0], motion[1], 0.0, motion[3], motion[4], box, frozen)
        tilt_height_step(S, noise[:, 3:5], noise_z, dt_s, motion[2], motion[5], tilt, z_box)
    lse0 = K.log_sum_exp(logw)
    expected3d_into(S, heard, rx, maps, layers_z, exponent, grid, tx_dbm, d, pat, pred)
    K.measurement_update(S, pred, rss, sigma_db, log_eps, logw)
    return lse0, K.normalise_into(logw, w)


@numba.njit(cache=True)
def coarse_costs(table, heard, rss, sigma_db, prior_db, prior_sd_db, out):  # pragma: no cover
    """Cost of every coarse pose (rows of ``table`` ``(n_pose, n_rx)``, expected RSS
    without offset) for one reading per heard receiver, the offset profiled out:
    ``Σ (e − b̂)²/2σ² + (b̂ − b₀)²/2s²``, ``b̂ = (Σe/σ² + b₀/s²)/(h/σ² + 1/s²)``."""
    h = heard.shape[0]
    lam = 1.0 / (sigma_db * sigma_db)
    lam0 = 1.0 / (prior_sd_db * prior_sd_db)
    e = np.empty(h)
    for i in range(table.shape[0]):
        s = 0.0
        for q in range(h):
            e[q] = rss[q] - table[i, heard[q]]
            s += e[q]
        b = (lam * s + lam0 * prior_db) / (h * lam + lam0)
        c = 0.0
        for q in range(h):
            c += (e[q] - b) ** 2
        out[i] = 0.5 * lam * c + 0.5 * lam0 * (b - prior_db) ** 2
