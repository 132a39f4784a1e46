"""Synthetic radiation patterns for simulation and analytic tests.

* :func:`isotropic` — 0 dBi everywhere.
* :func:`dipole` — an ideal short dipole ``D = 1.5 sin²γ`` (``γ`` the angle to
  its axis in the body frame), floored at ``floor_dbi`` where it vanishes.
* :func:`smartphone_like` — smooth, arbitrary (several lobes, no single main
  lobe), seeded, with a directivity range like measured phones. A mixture of
  von Mises–Fisher lobes ``Σ w_j exp(κ_j (v·u_j − 1))`` is evaluated on the grid,
  taken to dB, rescaled so that max − min equals ``range_db`` (default drawn
  from 14–20 dB; the paper's Samsung A50 slice spans −12.29…+5.06 = 17.35 dB),
  and normalised to a directivity (mean radiation intensity 0 dBi over the
  sphere, or over the slice for a slice pattern). Smoothness is that of the
  lobes (κ ≤ 8 gives features no narrower than ~20°).
"""

from __future__ import annotations

import numbers

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.pattern import Pattern, finite_number, grid_count, mean_intensity
from radiopose.units import FloatArray, db_to_linear, linear_to_db

MAX_RANGE_DB = 200.0
"""Largest ``range_db`` of :func:`smartphone_like` (a pattern CSV holds ±200 dBi)."""

MAX_LOBES = 100
"""Most lobes of :func:`smartphone_like`."""


def _axes(azimuth_step_deg: float, polar_step_deg: float | None) -> tuple[FloatArray, FloatArray]:
    """Grid axes; a step that is not a number, finer than 0.1° or does not divide
    360 (180) is an :class:`InputError` before anything is allocated."""
    n_az = grid_count(azimuth_step_deg, 360.0, "pattern azimuth step")
    az = np.arange(n_az, dtype=np.float64) * (360.0 / n_az)
    if polar_step_deg is None:
        po = np.array([90.0])
    else:
        n_po = grid_count(polar_step_deg, 180.0, "pattern polar step")
        po = np.arange(n_po + 1, dtype=np.float64) * (180.0 / n_po)
    return az, po


def _unit_vectors(az_deg: FloatArray, po_deg: FloatArray) -> FloatArray:
    """Body-frame unit vectors ``(n_az, n_po, 3)`` of pattern angles."""
    phi, theta = np.meshgrid(np.deg2rad(az_deg), np.deg2rad(po_deg), indexing="ij")
    return np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1
    )


def _normalise_db(name: str, az: FloatArray, po: FloatArray, d_db: FloatArray) -> Pattern:
    raw = Pattern(name, az, po, d_db)
    return Pattern(name, az, po, d_db - float(linear_to_db(mean_intensity(raw))))


def isotropic(name: str = "isotropic", azimuth_step_deg: float = 1.0) -> Pattern:
    """An isotropic slice pattern: 0 dBi in every direction."""
    az, po = _axes(azimuth_step_deg, None)
    return Pattern(name, az, po, np.zeros((az.size, 1)))


def dipole(
    name: str = "dipole",
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0),
    azimuth_step_deg: float = 1.0,
    polar_step_deg: float = 1.0,
    floor_dbi: float = -40.0,
) -> Pattern:
    """An ideal short dipole along ``axis`` (body frame): ``D = 1.5 sin²γ``.

    Not renormalised after flooring (the floor changes the mean by < 1e-4).
    """
    az, po = _axes(azimuth_step_deg, polar_step_deg)
    floor_dbi = finite_number(floor_dbi, "dipole floor_dbi")
    try:
        a = np.asarray(axis, float).reshape(-1)
    except (TypeError, ValueError):
        a = np.full(1, np.nan)
    if a.size != 3 or not np.isfinite(a).all() or not np.any(a):
        raise InputError(f"dipole axis {axis!r:.60} is not a finite non-zero 3-vector")
    a = a / np.linalg.norm(a)
    cos_g = _unit_vectors(az, po) @ a
    lin = 1.5 * (1.0 - cos_g**2)
    return Pattern(name, az, po, np.maximum(linear_to_db(lin), floor_dbi))


def smartphone_like(
    rng: np.random.Generator,
    name: str = "phone",
    *,
    range_db: float | None = None,
    n_lobes: int | None = None,
    azimuth_step_deg: float = 1.0,
    polar_step_deg: float | None = None,
) -> Pattern:
    """A smooth, arbitrary, smartphone-like pattern.

    Parameters
    ----------
    rng
        Source of randomness (same state → same pattern).
    name
        Pattern name.
    range_db
        Max − min directivity over the grid, dB; drawn from U(14, 20) if None.
    n_lobes
        Number of lobes; drawn from 3–6 if None.
    azimuth_step_deg
        Azimuth grid step, degrees.
    polar_step_deg
        Polar grid step for a full-sphere pattern; ``None`` gives a slice at
        polar 90° (the plane of the screen), used for every polar angle.
    """
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"smartphone_like needs a numpy Generator, got {type(rng).__name__}")
    # the checks that need no randomness first: a bad setting consumes none of rng
    if range_db is not None:
        range_db = finite_number(range_db, "smartphone_like range_db")
        if not 0.0 <= range_db <= MAX_RANGE_DB:
            raise InputError(
                f"smartphone_like range_db {range_db:g} dB is out of range [0, {MAX_RANGE_DB:g}]"
            )
    if n_lobes is not None and (
        isinstance(n_lobes, (bool, np.bool_))
        or not isinstance(n_lobes, numbers.Integral)
        or not 1 <= n_lobes <= MAX_LOBES
    ):
        raise InputError(
            f"smartphone_like n_lobes {n_lobes!r:.40} is not an integer in [1, {MAX_LOBES}]"
        )
    _axes(azimuth_step_deg, polar_step_deg)
    if range_db is None:
        range_db = float(rng.uniform(14.0, 20.0))
    if n_lobes is None:
        n_lobes = int(rng.integers(3, 7))
    # Lobe axes: uniform azimuth, elevation within ±40° of the screen plane so
    # the 90° slice sees their structure; concentration and weight vary.
    lobe_phi = rng.uniform(0.0, 2 * np.pi, n_lobes)
    lobe_el = np.deg2rad(rng.uniform(-40.0, 40.0, n_lobes))
    u = np.stack(
        [np.cos(lobe_el) * np.cos(lobe_phi), np.cos(lobe_el) * np.sin(lobe_phi), np.sin(lobe_el)],
        axis=-1,
    )
    kappa = rng.uniform(2.0, 8.0, n_lobes)
    weight = rng.lognormal(0.0, 0.5, n_lobes)
    az, po = _axes(azimuth_step_deg, polar_step_deg)
    v = _unit_vectors(az, po)
    lin = np.einsum("j,abj->ab", weight, np.exp(kappa * (v @ u.T - 1.0)))
    shape_db = linear_to_db(lin + 1e-3 * lin.max())
    span = float(shape_db.max() - shape_db.min())
    d_db = (shape_db - shape_db.mean()) * (range_db / span)
    return _normalise_db(name, az, po, d_db)


def from_linear(name: str, az: FloatArray, po: FloatArray, intensity: FloatArray) -> Pattern:
    """A directivity pattern from a linear radiation-intensity grid (any scale)."""
    return _normalise_db(name, az, po, linear_to_db(np.asarray(intensity, float)))


__all__ = ["db_to_linear", "dipole", "from_linear", "isotropic", "smartphone_like"]
