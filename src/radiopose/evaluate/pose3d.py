"""Per-axis errors of 3-D pose estimates (docs/pose3d.md), beside the contract's scoring.

The contract scores orientation as the angle of the relative rotation
``R_estᵀ R_true`` (:func:`radiopose.geometry.orientation_error_deg`); for 3-D
pose the axes are reported too: height error ``|z_est − z_true|``, and the
wrapped differences of azimuth, pitch and roll. Euler axes are only
meaningful away from pitch ±90° (where azimuth and roll mix); hand-held poses
stay there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from radiopose.estimates import Estimates
from radiopose.evaluate.scoring import match_truth
from radiopose.geometry import orientation_error_deg
from radiopose.packets import Truth
from radiopose.units import FloatArray, angle_diff_deg


@dataclass(frozen=True)
class AxisErrors:
    """``(n,)`` absolute errors per matched estimate: 3-D position (m), height (m),
    rotation angle, azimuth, pitch, roll (degrees); ``coverage`` estimates/packets."""

    position_m: FloatArray
    height_m: FloatArray
    rotation_deg: FloatArray
    azimuth_deg: FloatArray
    pitch_deg: FloatArray
    roll_deg: FloatArray
    coverage: float

    def means(self) -> dict[str, float]:
        """Mean of each error (NaN where there is none) and the coverage."""
        out = {
            k: float(np.mean(getattr(self, k))) if getattr(self, k).size else float("nan")
            for k in ("position_m", "height_m", "rotation_deg", "azimuth_deg", "pitch_deg",
                      "roll_deg")
        }  # fmt: skip
        out["coverage"] = self.coverage
        return out


def axis_errors_of(
    est_xyz_m: ArrayLike, est_deg: ArrayLike, true_xyz_m: ArrayLike, true_deg: ArrayLike
) -> AxisErrors:
    """Per-axis errors of matched ``(n, 3)`` positions and orientations (coverage 1)."""
    pe, pt = (
        np.asarray(est_xyz_m, float).reshape(-1, 3),
        np.asarray(true_xyz_m, float).reshape(-1, 3),
    )
    oe, ot = np.asarray(est_deg, float).reshape(-1, 3), np.asarray(true_deg, float).reshape(-1, 3)
    return AxisErrors(
        np.linalg.norm(pe - pt, axis=1),
        np.abs(pe[:, 2] - pt[:, 2]),
        orientation_error_deg(oe, ot),
        np.abs(angle_diff_deg(oe[:, 0], ot[:, 0])),
        np.abs(oe[:, 1] - ot[:, 1]),
        np.abs(angle_diff_deg(oe[:, 2], ot[:, 2])),
        1.0,
    )


def axis_errors(truth: Truth, estimates: Estimates) -> AxisErrors:
    """Per-axis errors of every estimate against the truth row of its packet time."""
    idx = match_truth(truth, estimates)
    ok = idx >= 0
    e = axis_errors_of(
        estimates.position_m[ok], estimates.orientation_deg[ok],
        truth.position_m[idx[ok]], truth.orientation_deg[idx[ok]],
    )  # fmt: skip
    n = len(truth)
    return AxisErrors(
        e.position_m, e.height_m, e.rotation_deg, e.azimuth_deg, e.pitch_deg, e.roll_deg,
        float(ok.sum()) / n if n else 0.0,
    )  # fmt: skip
