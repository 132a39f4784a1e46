"""Device trajectories: straight-line motion with linear, periodic or too-fast rotation.

Paper, "2D Proof of Concept Simulations": the transmitter moves in a straight
line at constant speed while rotating linearly. Also available: a periodic,
human-like rotation (sum of two sinusoids, peak rate at most 377°/s and
almost always within the rotation model's 360°/s) and a rotation faster than
the rotation model allows.

Positions stay inside the area shrunk by ``margin_m``: a start point and heading
are drawn until the whole straight path fits (200 tries); if none fits (a long
run in a small area) the path reflects off the margin like a billiard ball.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from radiopose.errors import InputError
from radiopose.units import FloatArray, wrap_deg

RotationKind = Literal["linear", "periodic", "fast"]


@dataclass(frozen=True)
class MotionConfig:
    """How the simulated device moves.

    Attributes
    ----------
    rotation
        ``"linear"`` (constant rate), ``"periodic"`` (human-like sway) or
        ``"fast"`` (constant rate beyond the rotation model's bound).
    speed_mps
        Speed drawn uniformly from this range, metres per second.
    linear_rate_deg_s
        Magnitude of the linear rotation rate, uniform in this range (random sign).
    fast_rate_deg_s
        Magnitude of the too-fast rate (the default bound is 360°/s).
    periodic_amplitude_deg, periodic_frequency_hz
        Ranges of the main sway's amplitude and frequency; a second harmonic of
        a third of the amplitude is added with a random phase.
    margin_m
        Distance kept from the area's edges, metres.
    """

    rotation: RotationKind = "linear"
    speed_mps: tuple[float, float] = (0.5, 1.5)
    linear_rate_deg_s: tuple[float, float] = (10.0, 90.0)
    fast_rate_deg_s: tuple[float, float] = (450.0, 900.0)
    periodic_amplitude_deg: tuple[float, float] = (20.0, 60.0)
    periodic_frequency_hz: tuple[float, float] = (0.2, 0.6)
    margin_m: float = 1.0

    def validate(self) -> None:
        """Raise :class:`InputError` naming the first out-of-range setting."""
        if self.rotation not in ("linear", "periodic", "fast"):
            raise InputError(f"motion setting rotation = {self.rotation!r} is unknown")
        ranges = {
            "speed_mps": (self.speed_mps, 0.0, 100.0),
            "linear_rate_deg_s": (self.linear_rate_deg_s, 0.0, 36_000.0),
            "fast_rate_deg_s": (self.fast_rate_deg_s, 0.0, 36_000.0),
            "periodic_amplitude_deg": (self.periodic_amplitude_deg, 0.0, 180.0),
            "periodic_frequency_hz": (self.periodic_frequency_hz, 0.0, 100.0),
        }
        for name, ((lo, hi), lo_ok, hi_ok) in ranges.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and lo_ok <= lo <= hi <= hi_ok):
                raise InputError(
                    f"motion setting {name} = ({lo!r}, {hi!r}) needs "
                    f"{lo_ok:g} <= MIN <= MAX <= {hi_ok:g}"
                )
        if not (math.isfinite(self.margin_m) and self.margin_m >= 0):
            raise InputError(f"motion setting margin_m = {self.margin_m!r} is out of range")


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


def rotation_path(rng: np.random.Generator, t_s: FloatArray, config: MotionConfig) -> FloatArray:
    """Orientations ``(n, 3)`` (azimuth, pitch, roll) in degrees at times ``t_s``.

    Only the azimuth changes (2-D scenario); pitch and roll stay 0.
    """
    t = np.asarray(t_s, float) - float(t_s[0])
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
