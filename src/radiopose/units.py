"""Unit conversions and angle arithmetic: every one of them, once.

Conventions
-----------
* Angles are degrees at every public interface; radians only inside kernels.
* ``wrap_deg`` maps to ``[0, 360)``; ``wrap_signed_deg`` to ``[-180, 180)``.
* ``angle_diff_deg(a, b)`` is the signed smallest difference ``a - b`` in
  ``[-180, 180)`` — it knows that 359 - 1 is -2 and 1 - 359 is 2.
* Power: ``dbm_to_mw``/``mw_to_dbm`` and the ratio forms ``db_to_linear``/
  ``linear_to_db`` (10·log10, power quantities).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_deg(angle_deg: ArrayLike) -> FloatArray:
    """Wrap angles to ``[0, 360)`` degrees (works on scalars and arrays)."""
    a = np.mod(np.asarray(angle_deg, dtype=np.float64), 360.0)
    # np.mod(-1e-17, 360) == 360.0 in floating point; keep the half-open range.
    return np.where(a >= 360.0, 0.0, a)


def wrap_signed_deg(angle_deg: ArrayLike) -> FloatArray:
    """Wrap angles to ``[-180, 180)`` degrees."""
    return wrap_deg(np.asarray(angle_deg, dtype=np.float64) + 180.0) - 180.0


def angle_diff_deg(a_deg: ArrayLike, b_deg: ArrayLike) -> FloatArray:
    """Signed smallest difference ``a - b`` in ``[-180, 180)`` degrees."""
    return wrap_signed_deg(np.asarray(a_deg, dtype=np.float64) - np.asarray(b_deg))


def circular_mean_deg(angle_deg: ArrayLike, weights: ArrayLike | None = None) -> float:
    """Weighted circular mean of angles in degrees, result in ``[0, 360)``."""
    a = np.deg2rad(np.asarray(angle_deg, dtype=np.float64))
    w = np.ones_like(a) if weights is None else np.asarray(weights, dtype=np.float64)
    s = float(np.sum(w * np.sin(a)))
    c = float(np.sum(w * np.cos(a)))
    return float(wrap_deg(np.rad2deg(np.arctan2(s, c))))


def dbm_to_mw(power_dbm: ArrayLike) -> FloatArray:
    """dBm -> milliwatts: ``P_mW = 10^(P_dBm / 10)``."""
    return np.power(10.0, np.asarray(power_dbm, dtype=np.float64) / 10.0)


def mw_to_dbm(power_mw: ArrayLike) -> FloatArray:
    """Milliwatts -> dBm: ``P_dBm = 10·log10(P_mW)`` (``-inf`` for 0)."""
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(np.asarray(power_mw, dtype=np.float64))


def db_to_linear(ratio_db: ArrayLike) -> FloatArray:
    """Power ratio dB (or dBi) -> linear: ``10^(x/10)``."""
    return np.power(10.0, np.asarray(ratio_db, dtype=np.float64) / 10.0)


def linear_to_db(ratio: ArrayLike) -> FloatArray:
    """Linear power ratio -> dB: ``10·log10(x)`` (``-inf`` for 0)."""
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(np.asarray(ratio, dtype=np.float64))


# Largest |time| int64 nanoseconds hold: 2**63 ns = 9,223,372,036.85 s (years 1677-2262).
MAX_ABS_TIME_S = 9_223_372_036.0

COORD_LIMIT_M = 1e6
"""Bound on every coordinate, metres: site.toml's area, receivers.csv, survey.csv,
and the positions of truth.csv and estimates.csv (a distance beyond it overflows
nothing, but no site holds it: a typo or a corrupt file)."""


def seconds_to_ns(t_s: ArrayLike) -> NDArray[np.int64]:
    """Seconds -> integer nanoseconds (rounded to nearest).

    Raises :class:`ValueError` for a time beyond :data:`MAX_ABS_TIME_S` or not
    finite (the file loaders reject those first, naming the line).
    """
    t = np.asarray(t_s, dtype=np.float64)
    if t.size and not (np.all(np.isfinite(t)) and float(np.max(np.abs(t))) <= MAX_ABS_TIME_S):
        raise ValueError(f"time outside +-{MAX_ABS_TIME_S:g} s cannot be held in int64 ns")
    return np.rint(t * 1e9).astype(np.int64)


def ns_to_seconds(t_ns: ArrayLike) -> FloatArray:
    """Integer nanoseconds -> seconds (float64)."""
    return np.asarray(t_ns, dtype=np.int64).astype(np.float64) / 1e9
