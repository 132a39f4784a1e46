"""Motion models: how far a device can turn and move between two packets.

Paper, "Enhanced Localisation Pipeline", steps 4 and 5.

* Rotation model: an orientation cluster is invalid if, on any axis, it differs
  from the previous valid orientation by more than
  ``max_rotation_deg · dt / rotation_period_s`` (paper: 180° per 0.5 s, i.e.
  360°/s), ``dt`` being the time since that previous valid orientation. Angle
  differences on periodic axes use the smallest wrapped difference.
* Gap cap: the paper caps the gap between valid estimates at ``t/2``
  (``rotation_period_s / 2`` = 0.25 s). Past it the previous orientation is
  stale: the next orientation is *re-acquired without constraint*. (At 360°/s
  the bound reaches 90° at the cap; a wrapped difference never exceeds 180°, so
  without the cap the constraint would vanish only at 0.5 s.)
* Movement model: a position cluster is invalid if its centroid lies farther
  than ``max_speed_mps · dt`` (paper: 10 m/s) from the previous valid position.
  The same gap cap applies (the tracker passes ``t/2`` by default): past it
  the position is re-acquired without constraint, so one wrong first estimate
  cannot hold the track for long.

Both models accept everything when there is no previous valid estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radiopose.units import FloatArray, angle_diff_deg

PERIODIC_AXES = (True, False, True)
"""(azimuth, pitch, roll): azimuth and roll wrap at 360°, pitch does not."""


@dataclass(frozen=True)
class RotationModel:
    """Bound on rotation between packets (paper: 180° per 0.5 s, gap cap 0.25 s).

    Attributes
    ----------
    max_rotation_deg
        Largest change per ``rotation_period_s`` on any axis, degrees.
    rotation_period_s
        The period ``t`` of the bound, seconds.
    max_gap_s
        Beyond this time since the previous valid orientation, re-acquire
        without constraint; ``None`` means ``rotation_period_s / 2``.
    """

    max_rotation_deg: float = 180.0
    rotation_period_s: float = 0.5
    max_gap_s: float | None = None

    @property
    def gap_s(self) -> float:
        return self.rotation_period_s / 2.0 if self.max_gap_s is None else self.max_gap_s

    def allowed_deg(self, dt_s: float) -> float:
        """Largest allowed change on one axis after ``dt_s`` seconds, degrees."""
        return self.max_rotation_deg * max(dt_s, 0.0) / self.rotation_period_s

    def valid(
        self,
        orientations_deg: FloatArray,
        previous_deg: FloatArray | None,
        dt_s: float,
    ) -> np.ndarray:
        """Which of ``(m, 3)`` orientations are reachable from ``previous_deg`` in ``dt_s``.

        Returns ``(m,)`` bool; all True without a previous orientation or past the gap cap.
        """
        o = np.asarray(orientations_deg, dtype=np.float64).reshape(-1, 3)
        if previous_deg is None or dt_s > self.gap_s:
            return np.ones(o.shape[0], dtype=bool)
        change = axis_change_deg(o, np.asarray(previous_deg, dtype=np.float64))
        return np.all(change <= self.allowed_deg(dt_s) + 1e-9, axis=1)


@dataclass(frozen=True)
class MovementModel:
    """Bound on movement between packets (paper: 10 m/s).

    Attributes
    ----------
    max_speed_mps
        Largest speed, metres per second.
    max_gap_s
        Beyond this time since the previous valid position, re-acquire without
        constraint (default: never — the bound simply grows with ``dt``).
    """

    max_speed_mps: float = 10.0
    max_gap_s: float = float("inf")

    def allowed_m(self, dt_s: float) -> float:
        """Largest allowed distance after ``dt_s`` seconds, metres."""
        return self.max_speed_mps * max(dt_s, 0.0)

    def valid(
        self, positions_m: FloatArray, previous_m: FloatArray | None, dt_s: float
    ) -> np.ndarray:
        """Which of ``(m, 3)`` positions are reachable from ``previous_m`` in ``dt_s``."""
        p = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
        if previous_m is None or dt_s > self.max_gap_s:
            return np.ones(p.shape[0], dtype=bool)
        dist = np.linalg.norm(p - np.asarray(previous_m, dtype=np.float64)[None, :], axis=1)
        return dist <= self.allowed_m(dt_s) + 1e-9


def axis_change_deg(orientations_deg: FloatArray, previous_deg: FloatArray) -> FloatArray:
    """Absolute per-axis change ``(m, 3)`` in degrees (wrapped on periodic axes).

    ``previous_deg`` is one orientation ``(3,)`` or one per row ``(m, 3)``.
    """
    o = np.asarray(orientations_deg, dtype=np.float64).reshape(-1, 3)
    prev = np.asarray(previous_deg, dtype=np.float64).reshape(-1, 3)
    out = np.abs(o - prev)
    for axis, periodic in enumerate(PERIODIC_AXES):
        if periodic:
            out[:, axis] = np.abs(angle_diff_deg(o[:, axis], prev[:, axis]))
    return out
