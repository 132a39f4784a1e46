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
def _channel_db(maps, layers_z, exponent, detrended, r, x, y, z, horiz2, rz, g):  # pragma: no cover
    """``M_r(x, y, z)``: the surveyed maps moved along 3-D distance (survey_height);
    ``detrended``: the maps hold the survey with its path loss removed
    (:attr:`radiopose.survey_height.HeightModel.detrended`), which is added back
    here at the exact 3-D distance."""
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
    # the law at the surveyed height, which detrended maps have already removed
    zl = layers_z[lo]
    lds = 0.0 if detrended else math.log10(max(math.sqrt(horiz2 + (rz - zl) ** 2), 1.0))
    m = K._map_db(maps[lo], r, x, y, x0, dx, nx, y0, dy, ny) - 10.0 * exponent * (ld - lds)
    if frac > 0.0:
        zh = layers_z[lo + 1]
        lds = 0.0 if detrended else math.log10(max(math.sqrt(horiz2 + (rz - zh) ** 2), 1.0))
        mh = K._map_db(maps[lo + 1], r, x, y, x0, dx, nx, y0, dy, ny) - 10.0 * exponent * (ld - lds)
        m = (1.0 - frac) * m + frac * mh
    return m


@numba.njit(cache=True, inline="always")
def _pattern_angles_deg(vx, vy, vz):  # pragma: no cover - compiled
    """``(phi, theta)`` degrees of a body-frame direction, as
    :func:`radiopose.geometry.direction_to_pattern_angles_deg` (``(0, 90)`` for
    zero; ``phi`` in ``(−180, 180]``, which the pattern lookups wrap)."""
    nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
    if nrm == 0.0:
        return 0.0, 90.0
    return (
        math.atan2(vy, vx) * _RAD_TO_DEG,
        math.acos(min(max(vz / nrm, -1.0), 1.0)) * _RAD_TO_DEG,
    )


@numba.njit(cache=True, inline="always")
def receiver_gain_dbi(rot, d, ax, r, wx, wy, wz):  # pragma: no cover - compiled
    """Receiver ``r``'s directivity (dBi) toward the world direction ``w`` (receiver
    → device): its pattern at the angles of ``v = Rᵀ w``, ``R = rot[r]`` row-major
    (:meth:`radiopose.survey_height.ReceiverGain.kernel_arrays`; the bilinear
    lookup of :meth:`radiopose.patterns.pattern.Pattern.lookup_dbi`)."""
    phi, theta = _pattern_angles_deg(
        wx * rot[r, 0] + wy * rot[r, 3] + wz * rot[r, 6],
        wx * rot[r, 1] + wy * rot[r, 4] + wz * rot[r, 7],
        wx * rot[r, 2] + wy * rot[r, 5] + wz * rot[r, 8],
    )
    table = d[r, : int(ax[r, 3]), : int(ax[r, 4])]
    return K._pattern_dbi(table, phi, theta, ax[r, 0], ax[r, 1], ax[r, 2])


@numba.njit(cache=True, parallel=True)
def expected3d_into(
    S, heard, rx, maps, layers_z, exponent, detrended, rg_rot, rg_d, rg_ax, grid, tx_dbm, d, pat,
    out,
):  # pragma: no cover  # fmt: skip
    """Expected RSS ``(n, h)`` dBm without the offset into ``out``: the height
    model's channel + ``tx_dbm`` + the full-sphere pattern toward each receiver
    in the body frame of ``R = Rz(az)·Rx(pitch)·Ry(roll)``; with ``rg_*`` of
    :meth:`~radiopose.survey_height.ReceiverGain.kernel_arrays` (zero rows: no
    term) the receiver's own directivity toward the particle as well.

    Particles in parallel over numba's threads (``NUMBA_NUM_THREADS``; one
    particle's row is one thread's, so the result does not depend on them)."""
    gain = rg_rot.shape[0] > 0
    for i in numba.prange(S.shape[0]):
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
            phi, theta = _pattern_angles_deg(
                ddx * r00 + ddy * r10 + ddz * r20,
                ddx * r01 + ddy * r11 + ddz * r21,
                ddx * r02 + ddy * r12 + ddz * r22,
            )
            m = _channel_db(maps, layers_z, exponent, detrended, r, x, y, z, ddx * ddx + ddy * ddy,
                            rx[r, 2], grid)  # fmt: skip
            if gain:
                m += receiver_gain_dbi(rg_rot, rg_d, rg_ax, r, -ddx, -ddy, -ddz)
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
            u = K.wrap_pi(u)
            if tilt[3] < math.pi:
                if u > tilt[3]:
                    u = 2.0 * tilt[3] - u
                elif u < -tilt[3]:
                    u = -2.0 * tilt[3] - u
                u = min(max(u, -tilt[3]), tilt[3])
            r = tilt[2] + u
            S[i, K.ROLL_RAD] = K.wrap_pi(r)
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
    heard, rx, maps, layers_z, exponent, detrended, rg_rot, rg_d, rg_ax, grid, tx_dbm, d, pat,
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
    expected3d_into(
        S, heard, rx, maps, layers_z, exponent, detrended, rg_rot, rg_d, rg_ax, grid, tx_dbm, d,
        pat, pred,
    )  # fmt: skip
    K.measurement_update(S, pred, rss, sigma_db, log_eps, logw)
    return lse0, K.normalise_into(logw, w)


@numba.njit(cache=True, parallel=True)
def coarse_costs(table, heard, rss, sigma_db, prior_db, prior_sd_db, out):  # pragma: no cover
    """Cost of every coarse pose (rows of ``table`` ``(n_pose, n_rx)``, expected RSS
    without offset) for one reading per heard receiver, the offset profiled out:
    ``Σ (e − b̂)²/2σ² + (b̂ − b₀)²/2s²``, ``b̂ = (Σe/σ² + b₀/s²)/(h/σ² + 1/s²)``.
    Rows in parallel over numba's threads (each row's cost is one thread's)."""
    h = heard.shape[0]
    lam = 1.0 / (sigma_db * sigma_db)
    lam0 = 1.0 / (prior_sd_db * prior_sd_db)
    for i in numba.prange(table.shape[0]):
        s = 0.0
        for q in range(h):
            s += rss[q] - table[i, heard[q]]
        b = (lam * s + lam0 * prior_db) / (h * lam + lam0)
        c = 0.0
        for q in range(h):
            c += ((rss[q] - table[i, heard[q]]) - b) ** 2
        out[i] = 0.5 * lam * c + 0.5 * lam0 * (b - prior_db) ** 2


@numba.njit(cache=True)
def _row_rotation(rows, i, out):  # pragma: no cover - compiled
    """``R = Rz(a)·Rx(p)·Ry(r)`` of pose row ``i`` (:data:`kernels.POSE_ROW`) into ``out[:9]``."""
    ca, sa = rows[i, 3], rows[i, 4]
    na = math.hypot(ca, sa)
    if na > 0.0:
        ca, sa = ca / na, sa / na
    else:
        ca, sa = 1.0, 0.0
    cr, sr = rows[i, 6], rows[i, 7]
    nr = math.hypot(cr, sr)
    if nr > 0.0:
        cr, sr = cr / nr, sr / nr
    else:
        cr, sr = 1.0, 0.0
    p = rows[i, 5]
    r = K.body_rotation(ca, sa, math.cos(p), math.sin(p), cr, sr)
    for c in range(9):
        out[c] = r[c]


@numba.njit(cache=True, inline="always")
def _in_cluster(rows, rot, i, cx, cy, cz, cr, r2, tr_min):  # pragma: no cover - compiled
    """Whether pose row ``i`` lies within ``√r2`` metres of ``(cx, cy, cz)`` and its
    rotation ``rot[i]`` within the angle of ``tr(crᵀ R) ≥ tr_min`` of ``cr``."""
    dx = rows[i, 0] - cx
    dy = rows[i, 1] - cy
    dz = rows[i, 2] - cz
    if dx * dx + dy * dy + dz * dz > r2:
        return False
    tr = 0.0
    for e in range(9):
        tr += cr[e] * rot[i, e]
    return tr >= tr_min


@numba.njit(cache=True)
def mode_pose(rows, w, n_centres, radius_m, cos_half_radius, iterations, out):  # pragma: no cover
    """The posterior's main mode from weighted pose rows, into ``out`` ``(7,)``.

    ``rows`` ``(n, POSE_ROW)`` (x, y, z, cos a, sin a, pitch, cos r, sin r) with
    weights ``w`` ``(n,)`` (any non-negative scale). Candidate centres are
    ``n_centres`` rows drawn systematically by weight (fixed phase ½: no random
    numbers are used); a centre's mass is the weight of the rows within
    ``radius_m`` of its position and within a rotation angle θ of its rotation,
    ``cos(θ/2) ≥ cos_half_radius`` (``tr(RcᵀR) ≥ 4 cos²(θ/2) − 1``). From the
    heaviest centre, ``iterations`` mean-shift steps: the weighted mean position
    of its members and the chordal L2 mean of their rotations (the weighted sum
    of the matrices projected onto SO(3) by an SVD), then the members again
    around that mean.

    ``out`` = ``[x, y, z, azimuth, pitch, roll, mass]`` (m, radians with azimuth
    and roll in ``[0, 2π)``, pitch in ``[−π/2, π/2]``; ``mass`` the members'
    share of the total weight).
    """
    n = rows.shape[0]
    total = 0.0
    for i in range(n):
        total += w[i]
    rot = np.empty((n, 9))
    for i in range(n):
        if w[i] > 0.0:
            _row_rotation(rows, i, rot[i])
    r2 = radius_m * radius_m
    tr_min = 4.0 * cos_half_radius * cos_half_radius - 1.0
    # systematic draw of the centres (fixed phase)
    centres = np.empty(n_centres, np.int64)
    step = total / n_centres
    u = 0.5 * step
    acc = 0.0
    j = 0
    for i in range(n):
        if w[i] <= 0.0:
            continue
        acc += w[i]
        while j < n_centres and u < acc:
            centres[j] = i
            j += 1
            u += step
    last = n - 1
    while last > 0 and w[last] <= 0.0:
        last -= 1
    while j < n_centres:
        centres[j] = last
        j += 1
    best_mass = -1.0
    best = 0
    for q in range(n_centres):
        c = centres[q]
        if q > 0 and c == centres[q - 1]:
            continue
        mass = 0.0
        for i in range(n):
            if w[i] > 0.0 and _in_cluster(
                rows, rot, i, rows[c, 0], rows[c, 1], rows[c, 2], rot[c], r2, tr_min
            ):
                mass += w[i]
        if mass > best_mass:
            best_mass = mass
            best = c
    cx, cy, cz = rows[best, 0], rows[best, 1], rows[best, 2]
    cr = rot[best].copy()
    mass = 0.0
    for _ in range(max(iterations, 1)):
        sx = 0.0
        sy = 0.0
        sz = 0.0
        mass = 0.0
        msum = np.zeros((3, 3))
        for i in range(n):
            if w[i] <= 0.0 or not _in_cluster(rows, rot, i, cx, cy, cz, cr, r2, tr_min):
                continue
            wi = w[i]
            mass += wi
            sx += wi * rows[i, 0]
            sy += wi * rows[i, 1]
            sz += wi * rows[i, 2]
            for e in range(9):
                msum[e // 3, e % 3] += wi * rot[i, e]
        if mass <= 0.0:
            break
        cx, cy, cz = sx / mass, sy / mass, sz / mass
        u_, _, vt = np.linalg.svd(msum)
        rm = u_ @ vt
        if np.linalg.det(rm) < 0.0:
            for a in range(3):
                u_[a, 2] = -u_[a, 2]
            rm = u_ @ vt
        for e in range(9):
            cr[e] = rm[e // 3, e % 3]
    # R = Rz(a)·Rx(p)·Ry(r): row z = (−cp sr, sp, cp cr), column y = (−sa cp, ca cp, sp)
    out[0] = cx
    out[1] = cy
    out[2] = cz
    out[3] = math.atan2(-cr[1], cr[4]) % _TWO_PI
    out[4] = math.asin(min(max(cr[7], -1.0), 1.0))
    out[5] = math.atan2(-cr[6], cr[8]) % _TWO_PI
    out[6] = mass / total if total > 0.0 else 0.0


@numba.njit(cache=True)
def heading_prior(S, logw, weight, kappa, v0_mps):  # pragma: no cover - compiled
    """Add the hand-held heading prior to ``logw`` in place.

    ``weight · κ · g(v) · (cos Δ − 1)`` per particle, ``Δ`` the angle between
    its azimuth and its walking direction (the azimuth that points the body
    ``+y``, the phone's top, along the velocity: ``atan2(vy, vx) − π/2``),
    ``g(v) = v² / (v² + v0²)`` (no coupling at rest), ``κ`` the von Mises
    concentration and ``weight`` the fraction of the prior's correlation time
    that the step covers (``dt / τ``).
    """
    half_pi = 0.5 * math.pi
    v02 = v0_mps * v0_mps
    for i in range(S.shape[0]):
        vx = S[i, K.VX_MPS]
        vy = S[i, K.VY_MPS]
        v2 = vx * vx + vy * vy
        if v2 == 0.0:
            continue
        walk = math.atan2(vy, vx) - half_pi
        logw[i] += weight * kappa * (v2 / (v2 + v02)) * (math.cos(S[i, K.AZIMUTH_RAD] - walk) - 1.0)
