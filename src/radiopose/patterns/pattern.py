"""The radiation pattern value object and its CSV form.

A :class:`Pattern` is a directivity grid in dBi, ``(n_azimuth, n_polar)``,
travelling with its axis vectors:

* ``azimuth_deg`` — ``n_azimuth`` values at a constant step ``360 / n_azimuth``
  starting at ``azimuth_deg[0]`` in ``[0, step)``; lookups are periodic;
* ``polar_deg`` — either one value (a *slice*: the same row is used for every
  polar angle) or values at a constant step covering ``[0, 180]`` exactly.

Lookups (:meth:`Pattern.lookup_dbi`) interpolate bilinearly in dB (or take the
nearest grid point), periodic in azimuth and clamped in polar angle.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from radiopose.errors import InputError
from radiopose.tables import Column, read_table, write_table
from radiopose.units import FloatArray, db_to_linear, linear_to_db, wrap_deg

_STEP_TOL = 1e-6

PATTERN_COLUMNS = (
    Column("azimuth_deg", low=0.0, high=360.0, high_open=True),
    Column("polar_deg", low=0.0, high=180.0),
    Column("directivity_dbi", low=-200.0, high=200.0),
)


@dataclass(frozen=True, eq=False)
class Pattern:
    """A directivity pattern on a regular (azimuth, polar) grid.

    Parameters
    ----------
    name
        Pattern name (``patterns/<name>.csv`` in a site).
    azimuth_deg
        ``(n_azimuth,)`` pattern azimuths, constant step, ``n_azimuth·step = 360``.
    polar_deg
        ``(n_polar,)`` polar angles: one value (slice) or a constant step
        covering ``[0, 180]``.
    directivity_dbi
        ``(n_azimuth, n_polar)`` directivity in dBi.
    """

    name: str
    azimuth_deg: FloatArray
    polar_deg: FloatArray
    directivity_dbi: FloatArray
    _digest: str = field(default="", repr=False, compare=False)

    def __post_init__(self) -> None:
        az = np.array(self.azimuth_deg, dtype=np.float64).reshape(-1)
        po = np.array(self.polar_deg, dtype=np.float64).reshape(-1)
        d = np.array(self.directivity_dbi, dtype=np.float64)
        if d.ndim == 1 and po.size == 1:
            d = d.reshape(-1, 1)
        if az.size < 1 or d.shape != (az.size, po.size):
            raise ValueError(
                f"pattern {self.name!r}: directivity shape {d.shape} does not match "
                f"axes ({az.size}, {po.size})"
            )
        if not np.all(np.isfinite(d)):
            raise ValueError(f"pattern {self.name!r}: directivity has NaN/inf")
        step = 360.0 / az.size
        regular = np.allclose(np.diff(az), step, atol=_STEP_TOL)
        if az[0] < 0 or az[0] >= step - _STEP_TOL or not regular:
            raise ValueError(
                f"pattern {self.name!r}: azimuths must be a constant step covering [0, 360)"
            )
        if po.size > 1:
            if po[0] != 0.0 or abs(po[-1] - 180.0) > _STEP_TOL:
                raise ValueError(f"pattern {self.name!r}: polar angles must cover [0, 180]")
            if not np.allclose(np.diff(po), 180.0 / (po.size - 1), atol=_STEP_TOL):
                raise ValueError(f"pattern {self.name!r}: polar angles need a constant step")
        for arr in (az, po, d):
            arr.setflags(write=False)
        object.__setattr__(self, "azimuth_deg", az)
        object.__setattr__(self, "polar_deg", po)
        object.__setattr__(self, "directivity_dbi", d)
        h = hashlib.sha256()
        for arr in (az, po, d):
            h.update(np.ascontiguousarray(arr).tobytes())
        object.__setattr__(self, "_digest", h.hexdigest())

    # ------------------------------------------------------------------ properties
    @property
    def is_slice(self) -> bool:
        """True if the pattern has a single polar angle (used for every polar angle)."""
        return self.polar_deg.size == 1

    @property
    def azimuth_step_deg(self) -> float:
        """Azimuth grid step in degrees."""
        return 360.0 / self.azimuth_deg.size

    @property
    def polar_step_deg(self) -> float:
        """Polar grid step in degrees (``0`` for a slice)."""
        return 0.0 if self.is_slice else 180.0 / (self.polar_deg.size - 1)

    @property
    def digest(self) -> str:
        """SHA-256 of the grid (content key for caches)."""
        return self._digest

    @property
    def range_dbi(self) -> tuple[float, float]:
        """(min, max) directivity in dBi."""
        return float(self.directivity_dbi.min()), float(self.directivity_dbi.max())

    def slice_dbi(self, polar_deg: float = 90.0) -> FloatArray:
        """Directivity ``(n_azimuth,)`` at one polar angle (interpolated), dBi."""
        theta = np.full(self.azimuth_deg.shape, float(polar_deg))
        return self.lookup_dbi(self.azimuth_deg, theta)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pattern):
            return NotImplemented
        return self.name == other.name and self._digest == other._digest

    def __hash__(self) -> int:
        return hash((self.name, self._digest))

    # ------------------------------------------------------------------ lookups
    def lookup_dbi(
        self,
        azimuth_deg: ArrayLike,
        polar_deg: ArrayLike | None = None,
        method: Literal["bilinear", "nearest"] = "bilinear",
    ) -> FloatArray:
        """Directivity in dBi at pattern angles (arrays broadcast together).

        Parameters
        ----------
        azimuth_deg
            Pattern azimuths in degrees, any real value (periodic).
        polar_deg
            Polar angles in degrees, clamped to ``[0, 180]``; ignored for a
            slice (may be ``None`` then).
        method
            ``"bilinear"`` (linear in each axis, in dB) or ``"nearest"``.
        """
        phi = np.asarray(azimuth_deg, dtype=np.float64)
        theta = phi * 0.0 + 90.0 if polar_deg is None else np.asarray(polar_deg, np.float64)
        phi, theta = np.broadcast_arrays(phi, theta)
        n_az = self.azimuth_deg.size
        u = wrap_deg(phi - self.azimuth_deg[0]) / self.azimuth_step_deg
        if self.is_slice:
            w = np.zeros_like(u)
        else:
            w = np.clip(theta, 0.0, 180.0) / self.polar_step_deg
        d = self.directivity_dbi
        if method == "nearest":
            i = np.rint(u).astype(np.int64) % n_az
            j = np.rint(w).astype(np.int64)
            return d[i, j]
        if method != "bilinear":
            raise ValueError(f"unknown lookup method {method!r}")
        i0 = np.floor(u).astype(np.int64)
        fu = u - i0
        i0 %= n_az
        i1 = (i0 + 1) % n_az
        j0 = np.minimum(np.floor(w).astype(np.int64), d.shape[1] - 1)
        fw = w - j0
        j1 = np.minimum(j0 + 1, d.shape[1] - 1)
        top = d[i0, j0] * (1 - fu) + d[i1, j0] * fu
        bot = d[i0, j1] * (1 - fu) + d[i1, j1] * fu
        return top * (1 - fw) + bot * fw

    # ------------------------------------------------------------------ derived
    def resampled(self, azimuth_step_deg: float) -> Pattern:
        """The pattern resampled (bilinearly) onto azimuths ``0, step, …``."""
        n = round(360.0 / azimuth_step_deg)
        if n < 1 or abs(n * azimuth_step_deg - 360.0) > 1e-6:
            raise ValueError(f"azimuth step {azimuth_step_deg} does not divide 360")
        az = np.arange(n) * (360.0 / n)
        phi, theta = np.meshgrid(az, self.polar_deg, indexing="ij")
        return Pattern(self.name, az, self.polar_deg, self.lookup_dbi(phi, theta))

    def renamed(self, name: str) -> Pattern:
        """The same grid under another name."""
        return Pattern(name, self.azimuth_deg, self.polar_deg, self.directivity_dbi)

    def normalised(self) -> Pattern:
        """The pattern rescaled to a directivity (mean radiation intensity = 0 dBi).

        Full sphere: divides by ``∫ U sinθ dθ dφ / 4π`` (trapezoid in θ);
        slice: by the mean of the linear slice.
        """
        lin = db_to_linear(self.directivity_dbi)
        return Pattern(
            self.name,
            self.azimuth_deg,
            self.polar_deg,
            linear_to_db(lin / mean_intensity(self, lin)),
        )


def mean_intensity(pattern: Pattern, linear: FloatArray | None = None) -> float:
    """Mean of a linear intensity grid over the sphere (``sinθ``-weighted) or the slice.

    ``P_rad / 4π`` for a full-sphere grid; the arithmetic mean for a slice.
    """
    lin = db_to_linear(pattern.directivity_dbi) if linear is None else linear
    if pattern.is_slice:
        return float(lin.mean())
    theta = np.deg2rad(pattern.polar_deg)
    ring = lin.mean(axis=0)  # mean over azimuth for each polar angle
    integral = np.trapezoid(ring * np.sin(theta), theta)  # ∫ ring sinθ dθ
    return float(integral / 2.0)  # (2π ∫ ring sinθ dθ) / 4π


# ---------------------------------------------------------------------- CSV io
def read_pattern_csv(path: str | os.PathLike[str], name: str | None = None) -> Pattern:
    """Read a contract pattern CSV (``azimuth_deg, polar_deg, directivity_dbi``).

    Raises :class:`~radiopose.errors.InputError` naming file, line and column
    for malformed values, duplicate or missing grid points, or an irregular grid.
    """
    table = read_table(path, PATTERN_COLUMNS)
    if len(table) == 0:
        raise InputError("no pattern samples", path=path, line=2)
    az = table["azimuth_deg"]
    po = table["polar_deg"]
    az_u = np.unique(az)
    po_u = np.unique(po)
    a_idx = np.searchsorted(az_u, az)
    p_idx = np.searchsorted(po_u, po)
    flat = a_idx * po_u.size + p_idx
    order = np.argsort(flat, kind="stable")
    dup = np.nonzero(np.diff(flat[order]) == 0)[0]
    if dup.size:
        r = int(order[dup[0] + 1])
        raise table.error(r, "azimuth_deg", f"duplicate grid point ({az[r]:g}, {po[r]:g}) deg")
    if flat.size != az_u.size * po_u.size:
        have = np.zeros(az_u.size * po_u.size, bool)
        have[flat] = True
        miss = int(np.nonzero(~have)[0][0])
        raise InputError(
            f"missing grid point azimuth {az_u[miss // po_u.size]:g}, "
            f"polar {po_u[miss % po_u.size]:g} deg (every grid point must be present once)",
            path=path,
        )
    grid = np.empty(az_u.size * po_u.size)
    grid[flat] = table["directivity_dbi"]
    stem = os.path.splitext(os.path.basename(os.fspath(path)))[0]
    try:
        return Pattern(name or stem, az_u, po_u, grid.reshape(az_u.size, po_u.size))
    except ValueError as exc:
        msg = str(exc).split(": ", 1)[-1]
        raise InputError(msg, path=path) from None


def write_pattern_csv(pattern: Pattern, path: str | os.PathLike[str]) -> None:
    """Write a pattern as a contract CSV (atomically), azimuth-major order."""
    phi, theta = np.meshgrid(pattern.azimuth_deg, pattern.polar_deg, indexing="ij")
    write_table(
        path,
        {
            "azimuth_deg": phi.ravel(),
            "polar_deg": theta.ravel(),
            "directivity_dbi": pattern.directivity_dbi.ravel(),
        },
    )
