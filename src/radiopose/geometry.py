"""Frames, orientations and the direction from a device to a point in pattern angles.

Conventions (the interchange contract, ``docs/conventions.md``)
---------------------------------------------------------------
* World frame: right-handed, ``x``/``y`` horizontal, ``z`` up, metres.
* Device body frame: ``x`` to the right edge of the screen, ``y`` to the top of
  the device, ``z`` out of the screen. At rest (all angles 0) body and world
  axes coincide: the device lies flat, screen up, top toward world ``+y``.
* Orientation ``(azimuth_deg, pitch_deg, roll_deg)``: intrinsic rotations about
  ``z``, then the new ``x``, then the newest ``y``; body-to-world rotation
  ``R = Rz(azimuth) · Rx(pitch) · Ry(roll)`` =
  ``Rotation.from_euler("ZXY", [az, pitch, roll], degrees=True)``.
* A point ``P`` seen from a device at ``T`` is the body-frame direction
  ``v = Rᵀ (P − T)``; its pattern azimuth is ``phi = atan2(v_y, v_x) mod 360``
  and its polar angle ``theta = arccos(v_z / |v|)`` (0 = out of the screen,
  90 = plane of the screen, 180 = out of the back). A zero-length ``v`` (the
  point coincides with the device) is given ``phi = 0, theta = 90``.

Shapes: points are ``(n, 3)``, samples first; rotation matrices ``(m, 3, 3)``.
Every rotation goes through :class:`scipy.spatial.transform.Rotation`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from radiopose.units import FloatArray, angle_diff_deg, wrap_deg

if TYPE_CHECKING:  # imported where used: scipy.spatial.transform costs ≈ 0.35 s
    from scipy.spatial.transform import Rotation

EULER_SEQ = "ZXY"
"""scipy Euler sequence of the contract: intrinsic z, then x, then y."""


@dataclass(frozen=True)
class Pose:
    """A device pose at one instant.

    Attributes
    ----------
    x_m, y_m, z_m
        Position in the world frame, metres.
    azimuth_deg, pitch_deg, roll_deg
        Orientation, contract Euler angles ("ZXY" intrinsic), degrees.
    t_s
        Time, seconds.
    """

    x_m: float
    y_m: float
    z_m: float
    azimuth_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    t_s: float = 0.0

    @property
    def position_m(self) -> FloatArray:
        """Position as a ``(3,)`` array in metres."""
        return np.array([self.x_m, self.y_m, self.z_m])

    @property
    def orientation_deg(self) -> FloatArray:
        """``(azimuth, pitch, roll)`` as a ``(3,)`` array in degrees."""
        return np.array([self.azimuth_deg, self.pitch_deg, self.roll_deg])

    def rotation(self) -> Rotation:
        """Body-to-world rotation."""
        return rotation_from_euler_deg(self.azimuth_deg, self.pitch_deg, self.roll_deg)


def rotation_from_euler_deg(
    azimuth_deg: ArrayLike, pitch_deg: ArrayLike = 0.0, roll_deg: ArrayLike = 0.0
) -> Rotation:
    """Body-to-world rotation(s) from contract Euler angles in degrees.

    Scalars give a single rotation; arrays (broadcast together) a stack.
    """
    az, pi, ro = np.broadcast_arrays(
        np.asarray(azimuth_deg, float), np.asarray(pitch_deg, float), np.asarray(roll_deg, float)
    )
    angles = np.stack([az, pi, ro], axis=-1)
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler(EULER_SEQ, angles, degrees=True)


def euler_deg_from_rotation(rotation: Rotation) -> FloatArray:
    """Contract Euler angles ``(..., 3)`` = (azimuth, pitch, roll) in degrees.

    Azimuth and roll are wrapped to ``[0, 360)``; pitch lies in ``[-90, 90]``
    (scipy's convention for the middle angle of a Tait–Bryan sequence).
    """
    import warnings

    with warnings.catch_warnings():
        # Gimbal lock (pitch = ±90) is not an error: scipy picks one solution.
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        e = rotation.as_euler(EULER_SEQ, degrees=True)
    out = np.array(e, dtype=np.float64)
    out[..., 0] = wrap_deg(out[..., 0])
    out[..., 2] = wrap_deg(out[..., 2])
    return out


def orientation_matrices(
    azimuth_deg: ArrayLike, pitch_deg: ArrayLike = 0.0, roll_deg: ArrayLike = 0.0
) -> FloatArray:
    """Body-to-world rotation matrices ``(m, 3, 3)`` for ``m`` orientations."""
    mats = rotation_from_euler_deg(azimuth_deg, pitch_deg, roll_deg).as_matrix()
    return np.asarray(mats, dtype=np.float64).reshape(-1, 3, 3)


def stored_orientation_matrices(orientation_deg: ArrayLike) -> FloatArray:
    """:func:`orientation_matrices` of ``(m, 3)`` (azimuth, pitch, roll) rows in
    degrees, memoised on disk (:mod:`radiopose.diskcache`): the same numbers, and
    a process that loads a site it has seen before need not import scipy's
    ``Rotation`` (≈ 0.35 s) for them. For the site's fixed sets (survey rows,
    candidate orientations), not for per-packet work."""
    from radiopose.diskcache import memo_arrays

    o = np.asarray(orientation_deg, dtype=np.float64).reshape(-1, 3)
    return memo_arrays("orientation-matrices", (o,), lambda: {"rot": orientation_matrices(*o.T)})[
        "rot"
    ]


def direction_to_pattern_angles_deg(v: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Body-frame direction vectors ``(..., 3)`` → (pattern azimuth, polar angle) in degrees.

    ``phi = atan2(v_y, v_x) mod 360`` in ``[0, 360)``; ``theta = arccos(v_z/|v|)``
    in ``[0, 180]``. Zero vectors give ``(0, 90)``; a vector with a NaN or
    infinite component gives NaN angles (which a pattern lookup refuses), not
    a valid-looking direction.
    """
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(v, axis=-1)
    zero = norm == 0
    phi = wrap_deg(np.rad2deg(np.arctan2(v[..., 1], v[..., 0])))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_t = np.clip(v[..., 2] / norm, -1.0, 1.0)
    theta = np.where(zero, 90.0, np.rad2deg(np.arccos(np.where(zero, 0.0, cos_t))))
    phi = np.where(zero, 0.0, phi)
    bad = ~np.isfinite(norm)
    if bad.any():
        phi, theta = np.where(bad, np.nan, phi), np.where(bad, np.nan, theta)
    return phi, theta


def pattern_angles_deg(
    device_xyz_m: ArrayLike,
    rotations: ArrayLike,
    targets_xyz_m: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Pattern angles of target points seen from devices in many orientations.

    Parameters
    ----------
    device_xyz_m
        Device positions ``(n, 3)`` (or ``(3,)``), metres.
    rotations
        Body-to-world rotation matrices ``(m, 3, 3)`` (or ``(3, 3)``), e.g. from
        :func:`orientation_matrices`.
    targets_xyz_m
        Points seen from the device (receivers), ``(k, 3)`` (or ``(3,)``), metres.

    Returns
    -------
    phi_deg, theta_deg
        Arrays of shape ``(n, m, k)``: the pattern azimuth and polar angle of
        target ``k`` seen from device position ``n`` in orientation ``m``.
    """
    dev = np.asarray(device_xyz_m, dtype=np.float64).reshape(-1, 3)
    rot = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    tgt = np.asarray(targets_xyz_m, dtype=np.float64).reshape(-1, 3)
    d = tgt[None, :, :] - dev[:, None, :]  # (n, k, 3) world directions
    # v = Rᵀ d  for every (n, m, k):  v_j = sum_i d_i R_ij
    v = np.einsum("nki,mij->nmkj", d, rot)
    return direction_to_pattern_angles_deg(v)


def relative_rotation_angle_deg(est_deg: ArrayLike, true_deg: ArrayLike) -> FloatArray:
    """Orientation error: the angle of ``R_estᵀ R_true`` in degrees, ``[0, 180]``.

    Parameters
    ----------
    est_deg, true_deg
        ``(n, 3)`` (or ``(3,)``) arrays of (azimuth, pitch, roll) in degrees.

    A row with a non-finite angle gives NaN (as numpy's own arithmetic would;
    scipy's rotations refuse it).
    """
    e = np.asarray(est_deg, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(true_deg, dtype=np.float64).reshape(-1, 3)
    e, t = np.broadcast_arrays(e, t)
    ok = np.isfinite(e).all(axis=1) & np.isfinite(t).all(axis=1)
    out = np.full(e.shape[0], np.nan)
    if ok.any():
        e, t = e[ok], t[ok]
        r_e = rotation_from_euler_deg(e[:, 0], e[:, 1], e[:, 2])
        r_t = rotation_from_euler_deg(t[:, 0], t[:, 1], t[:, 2])
        out[ok] = np.rad2deg((r_e.inv() * r_t).magnitude())
    return out


def orientation_error_deg(est_deg: ArrayLike, true_deg: ArrayLike) -> FloatArray:
    """Orientation error per the contract.

    Where pitch and roll of both are zero (azimuth-only motion) this is the
    wrapped azimuth difference ``|angle_diff_deg|``; otherwise the angle of the
    relative rotation. The two agree for azimuth-only poses (up to rounding);
    the first is exact. A row with a non-finite angle gives NaN.
    """
    e = np.asarray(est_deg, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(true_deg, dtype=np.float64).reshape(-1, 3)
    e, t = np.broadcast_arrays(e, t)
    flat = (e[:, 1] == 0) & (e[:, 2] == 0) & (t[:, 1] == 0) & (t[:, 2] == 0)
    out = relative_rotation_angle_deg(e, t)
    out[flat] = np.abs(angle_diff_deg(e[flat, 0], t[flat, 0]))
    return out


def distances_m(a_xyz_m: ArrayLike, b_xyz_m: ArrayLike) -> FloatArray:
    """Pairwise Euclidean distances ``(n, k)`` between ``(n, 3)`` and ``(k, 3)`` points."""
    a = np.asarray(a_xyz_m, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(b_xyz_m, dtype=np.float64).reshape(-1, 3)
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


def as_points(xyz: ArrayLike) -> NDArray[np.float64]:
    """Validate and return an ``(n, 3)`` float array."""
    a = np.asarray(xyz, dtype=np.float64)
    if a.ndim == 1:
        a = a.reshape(1, -1)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"expected points of shape (n, 3), got {a.shape}")
    return a
