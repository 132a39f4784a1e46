"""Device trajectories: a straight line or a walk with turns; linear, periodic,
too-fast or heading-following rotation.

Paper, "2D Proof of Concept Simulations": the transmitter moves in a straight
line at constant speed while rotating linearly. Also available: a periodic,
human-like rotation (sum of two sinusoids, peak rate at most 377°/s and
almost always within the rotation model's 360°/s), a rotation faster than
the rotation model allows, and, for long traces, a walk between random
waypoints with rounded turns (:func:`walk_path`) during which the device
faces the way it walks with a small sway (``rotation="heading"``).

Positions stay inside the area shrunk by ``margin_m``: a start point and heading
are drawn until the whole straight path fits (200 tries); if none fits (a long
run in a small area) the path reflects off the margin like a billiard ball.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.units import FloatArray, wrap_deg

RotationKind = Literal["linear", "periodic", "fast", "heading"]
PathKind = Literal["straight", "walk"]


MIN_WALK_CORNER_M = 0.01
"""Smallest :attr:`MotionConfig.walk_corner_m`, metres: the walk is sampled at a
quarter of it, so a micrometre corner once sampled a 20 m walk 80 million times."""


@dataclass(frozen=True)
class MotionConfig:
    """How the simulated device moves.

    Attributes
    ----------
    rotation
        ``"linear"`` (constant rate), ``"periodic"`` (human-like sway),
        ``"fast"`` (constant rate beyond the rotation model's bound) or
        ``"heading"`` (the device's top, body ``+y``, points where it walks,
        plus a sway of ``heading_sway_deg`` at ``periodic_frequency_hz``).
    path
        ``"straight"`` (the paper's constant-velocity line, reflected at the
        margin if it does not fit) or ``"walk"`` (:func:`walk_path`: legs
        between random waypoints, corners rounded, constant speed).
    speed_mps
        Speed drawn uniformly from this range, metres per second.
    linear_rate_deg_s
        Magnitude of the linear rotation rate, uniform in this range (random sign).
    fast_rate_deg_s
        Magnitude of the too-fast rate (the default bound is 360°/s).
    periodic_amplitude_deg, periodic_frequency_hz
        Ranges of the main sway's amplitude and frequency; a second harmonic of
        a third of the amplitude is added with a random phase.
    heading_sway_deg
        Range of the sway amplitude of ``rotation="heading"``, degrees.
    walk_min_leg_m
        ``path="walk"``: shortest distance between consecutive waypoints,
        metres (shortened to half the walkable diagonal in a small area).
    walk_max_turn_deg
        ``path="walk"``: largest change of direction at a waypoint, degrees.
    walk_corner_m
        ``path="walk"``: standard deviation, in metres of path, of the
        Gaussian that rounds the corners (larger: wider, slower turns).
    margin_m
        Distance kept from the area's edges, metres.
    """

    rotation: RotationKind = "linear"
    speed_mps: tuple[float, float] = (0.5, 1.5)
    linear_rate_deg_s: tuple[float, float] = (10.0, 90.0)
    fast_rate_deg_s: tuple[float, float] = (450.0, 900.0)
    periodic_amplitude_deg: tuple[float, float] = (20.0, 60.0)
    periodic_frequency_hz: tuple[float, float] = (0.2, 0.6)
    path: PathKind = "straight"
    heading_sway_deg: tuple[float, float] = (5.0, 15.0)
    walk_min_leg_m: float = 4.0
    walk_max_turn_deg: float = 120.0
    walk_corner_m: float = 1.0
    margin_m: float = 1.0

    def validate(self) -> None:
        """Raise :class:`InputError` naming the first out-of-range setting."""
        check_setting_types(self, "motion")
        if self.rotation not in ("linear", "periodic", "fast", "heading"):
            raise InputError(f"motion setting rotation = {self.rotation!r} is unknown")
        if self.path not in ("straight", "walk"):
            raise InputError(f"motion setting path = {self.path!r} is unknown")
        ranges = {
            "speed_mps": (self.speed_mps, 0.0, 100.0),
            "linear_rate_deg_s": (self.linear_rate_deg_s, 0.0, 36_000.0),
            "fast_rate_deg_s": (self.fast_rate_deg_s, 0.0, 36_000.0),
            "periodic_amplitude_deg": (self.periodic_amplitude_deg, 0.0, 180.0),
            "periodic_frequency_hz": (self.periodic_frequency_hz, 0.0, 100.0),
            "heading_sway_deg": (self.heading_sway_deg, 0.0, 180.0),
        }
        for name, ((lo, hi), lo_ok, hi_ok) in ranges.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and lo_ok <= lo <= hi <= hi_ok):
                raise InputError(
                    f"motion setting {name} = ({lo!r}, {hi!r}) needs "
                    f"{lo_ok:g} <= MIN <= MAX <= {hi_ok:g}"
                )
        if not (math.isfinite(self.margin_m) and self.margin_m >= 0):
            raise InputError(f"motion setting margin_m = {self.margin_m!r} is out of range")
        walk = {
            "walk_min_leg_m": (self.walk_min_leg_m, 0.0, 1e6),
            "walk_max_turn_deg": (self.walk_max_turn_deg, 1.0, 180.0),
            "walk_corner_m": (self.walk_corner_m, MIN_WALK_CORNER_M, 1e3),
        }
        for name, (v, lo_ok, hi_ok) in walk.items():
            if not (math.isfinite(v) and lo_ok <= v <= hi_ok and v > 0):
                raise InputError(
                    f"motion setting {name} = {v!r} needs {lo_ok:g} < VALUE <= {hi_ok:g}"
                )


def _reflect(x: FloatArray, lo: float, hi: float) -> FloatArray:
    """Fold coordinates into ``[lo, hi]`` by reflection at both ends."""
    span = hi - lo
    if span <= 0:
        return np.full_like(x, lo)
    u = np.mod(x - lo, 2 * span)
    return lo + np.where(u > span, 2 * span - u, u)


def straight_path(
    rng: np.random.Generator,
    t_s: FloatArray,
    bounds_xy_m: tuple[float, float, float, float],
    z_m: float,
    config: MotionConfig,
) -> FloatArray:
    """Positions ``(n, 3)`` of a constant-speed straight walk at times ``t_s``."""
    x0, x1, y0, y1 = bounds_xy_m
    m = config.margin_m
    lo = np.array([x0 + m, y0 + m])
    hi = np.array([x1 - m, y1 - m])
    speed = rng.uniform(*config.speed_mps)
    t = np.asarray(t_s, float) - float(t_s[0])
    length = speed * float(t[-1]) if t.size else 0.0
    start = rng.uniform(lo, hi)
    heading = rng.uniform(0, 2 * np.pi)
    for _ in range(200):
        end = start + length * np.array([np.cos(heading), np.sin(heading)])
        if np.all(end >= lo) and np.all(end <= hi):
            break
        start = rng.uniform(lo, hi)
        heading = rng.uniform(0, 2 * np.pi)
    xy = start[None, :] + np.outer(speed * t, [np.cos(heading), np.sin(heading)])
    xy[:, 0] = _reflect(xy[:, 0], lo[0], hi[0])
    xy[:, 1] = _reflect(xy[:, 1], lo[1], hi[1])
    return np.column_stack([xy, np.full(t.size, z_m)])


def walk_path(
    rng: np.random.Generator,
    t_s: FloatArray,
    bounds_xy_m: tuple[float, float, float, float],
    z_m: float,
    config: MotionConfig,
) -> FloatArray:
    """Positions ``(n, 3)`` of a constant-speed walk with turns at times ``t_s``.

    Waypoints are drawn uniformly in the area shrunk by ``margin_m``, each at
    least ``walk_min_leg_m`` from the previous one and turning by at most
    ``walk_max_turn_deg`` (the best of 200 draws otherwise); the polyline
    through them is sampled every 5 cm and smoothed along its length by a
    Gaussian of standard deviation ``walk_corner_m``, which rounds every
    corner and keeps the path inside the shrunk area (each smoothed point is
    a weighted mean of points inside it, a convex set). The device then moves
    along the smoothed curve at one speed drawn from ``speed_mps``.

    The turn rate at a corner is speed × curvature; with the defaults (≤ 1.5
    m/s, turns ≤ 120°, corners rounded over ~2 m) the direction of travel
    turned at most 286°/s over 200 seeds of 30 s (median of the per-seed
    peaks 135°/s), within the rotation model's 360°/s even with the heading
    sway added (≤ 2π · 0.6 Hz · 15° ≈ 57°/s); ``tests/test_simulate.py``
    checks the bound.
    """
    from scipy.interpolate import CubicSpline
    from scipy.ndimage import gaussian_filter1d

    x0, x1, y0, y1 = bounds_xy_m
    m = config.margin_m
    lo = np.array([x0 + m, y0 + m])
    hi = np.array([x1 - m, y1 - m])
    speed = rng.uniform(*config.speed_mps)
    t = np.asarray(t_s, float) - float(t_s[0])
    length = speed * float(t[-1]) if t.size else 0.0
    min_leg = min(config.walk_min_leg_m, 0.5 * float(np.hypot(*(hi - lo))))
    max_turn = math.radians(config.walk_max_turn_deg)
    # in an area smaller than a rounded corner the corners shrink with the legs
    # (else smoothing would fold the walk onto the area's centre)
    corner_m = min(config.walk_corner_m, 0.25 * min_leg)
    # the path is sampled at ds (at most 1 mm finer, in an area too small to walk
    # a rounded corner: a bound on the samples, not a change of any valid walk)
    ds = max(min(0.05, 0.25 * corner_m), 1e-3)
    sigma = corner_m / ds
    pts = [rng.uniform(lo, hi)]
    heading: float | None = None
    need_m = length + 4.0 * corner_m
    raw_m, check_m = 0.0, need_m
    while True:
        # extend the polyline until its smoothed version is long enough; smoothing
        # only shortens a curve, so it is tried once the raw polyline is, and after
        # a miss once the raw polyline has grown by the smoothed one's shortfall
        best, best_bad = pts[-1], math.inf
        for _ in range(200):
            q = rng.uniform(lo, hi)
            d = q - pts[-1]
            leg = float(np.hypot(*d))
            turn = 0.0 if heading is None else abs(_wrap_rad(math.atan2(d[1], d[0]) - heading))
            bad = max(min_leg - leg, 0.0) + max(turn - max_turn, 0.0)
            if bad < best_bad:
                best, best_bad = q, bad
            if bad == 0.0:
                break
        d = best - pts[-1]
        if np.hypot(*d) > 0:
            heading = math.atan2(d[1], d[0])
            pts.append(best)
            raw_m += float(np.hypot(*d))
        if len(pts) < 2 or raw_m < check_m:
            continue
        poly = np.array(pts)
        seg = np.hypot(*np.diff(poly, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        dense_s = np.arange(0.0, s[-1] + ds / 2, ds)
        dense = np.column_stack(
            [np.interp(dense_s, s, poly[:, 0]), np.interp(dense_s, s, poly[:, 1])]
        )
        smooth = gaussian_filter1d(dense, sigma, axis=0, mode="nearest")
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(smooth, axis=0).T))])
        if arc[-1] >= need_m:
            break
        check_m = raw_m + (need_m - arc[-1])
    # start beyond the first corner-rounding span, where the curve is already
    # smooth; a cubic spline through the smoothed samples keeps the heading
    # continuous between them (linear interpolation would kink every 5 cm)
    keep = np.concatenate([[True], np.diff(arc) > 1e-9])
    curve = CubicSpline(arc[keep], smooth[keep], axis=0)
    xy = curve(speed * t + min(2.0 * corner_m, arc[-1] - length))
    return np.column_stack([xy, np.full(t.size, z_m)])


def device_path(
    rng: np.random.Generator,
    t_s: FloatArray,
    bounds_xy_m: tuple[float, float, float, float],
    z_m: float,
    config: MotionConfig,
) -> tuple[FloatArray, FloatArray]:
    """Positions ``(n, 3)`` and orientations ``(n, 3)`` (degrees) at times ``t_s``:
    the path of ``config.path``, then the rotation of ``config.rotation``."""
    if config.path == "walk":
        pos = walk_path(rng, t_s, bounds_xy_m, z_m, config)
    else:
        pos = straight_path(rng, t_s, bounds_xy_m, z_m, config)
    return pos, rotation_path(rng, t_s, config, pos)


def walking_azimuth_deg(t_s: FloatArray, position_m: FloatArray) -> FloatArray:
    """Azimuth ``(n,)`` degrees at which the device's top (body ``+y``) points
    along the direction of travel: ``atan2(v_y, v_x) − 90°`` (conventions:
    azimuth 0 points the top to world ``+y``)."""
    p = np.asarray(position_m, float)
    if p.shape[0] < 2:
        return np.zeros(p.shape[0])
    v = np.gradient(p[:, :2], np.asarray(t_s, float), axis=0)
    return wrap_deg(np.degrees(np.arctan2(v[:, 1], v[:, 0])) - 90.0)


def _wrap_rad(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def rotation_path(
    rng: np.random.Generator,
    t_s: FloatArray,
    config: MotionConfig,
    position_m: FloatArray | None = None,
) -> FloatArray:
    """Orientations ``(n, 3)`` (azimuth, pitch, roll) in degrees at times ``t_s``.

    Only the azimuth changes (2-D scenario); pitch and roll stay 0.
    ``rotation="heading"`` needs the positions ``(n, 3)`` of the path.
    """
    t = np.asarray(t_s, float) - float(t_s[0])
    if config.rotation == "heading":
        if position_m is None:
            raise ValueError('rotation "heading" needs the positions of the path')
        amp = rng.uniform(*config.heading_sway_deg)
        f = rng.uniform(*config.periodic_frequency_hz)
        ph = rng.uniform(0, 2 * np.pi)
        az = walking_azimuth_deg(t, position_m)
        az = np.degrees(np.unwrap(np.radians(az))) + amp * np.sin(2 * np.pi * f * t + ph)
        return np.column_stack([wrap_deg(az), np.zeros(t.size), np.zeros(t.size)])
    az0 = rng.uniform(0.0, 360.0)
    sign = rng.choice([-1.0, 1.0])
    if config.rotation == "linear":
        az = az0 + sign * rng.uniform(*config.linear_rate_deg_s) * t
    elif config.rotation == "fast":
        az = az0 + sign * rng.uniform(*config.fast_rate_deg_s) * t
    elif config.rotation == "periodic":
        amp = rng.uniform(*config.periodic_amplitude_deg)
        f = rng.uniform(*config.periodic_frequency_hz)
        ph1, ph2 = rng.uniform(0, 2 * np.pi, 2)
        az = (
            az0
            + amp * np.sin(2 * np.pi * f * t + ph1)
            + amp / 3.0 * np.sin(4 * np.pi * f * t + ph2)
        )
    else:
        raise ValueError(f"unknown rotation kind {config.rotation!r}")
    return np.column_stack([wrap_deg(az), np.zeros(t.size), np.zeros(t.size)])
