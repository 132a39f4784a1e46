"""A site: candidate grid, receivers, enrolled devices, patterns and survey.

A site directory (interchange contract, "Site"; its files are listed in
:mod:`radiopose.site_io`): :func:`~radiopose.site_io.load_site` validates all
of it (every referenced pattern present, receiver ids unique, grid sane, every
receiver surveyed — on a 3-D site at every surveyed height
(:func:`missing_survey_height`) — survey rows name known receivers) and builds the survey map
(:mod:`radiopose.survey`);
:func:`~radiopose.site_io.write_site` writes one (atomically, file by file).
This module holds the value objects, the validation limits and the geometry on
them; :mod:`radiopose.site_io` reads and writes the files (its four public
functions stay importable from here).

Validation limits (documented in ``docs/site.md``): coordinates within
±:data:`COORD_LIMIT_M`; at most :data:`MAX_GRID_POINTS` candidate positions,
:data:`MAX_ORIENTATIONS` candidate orientations and :data:`MAX_CANDIDATES`
positions × orientations; each area span a whole number of ``step_m`` (within
:data:`STEP_TOLERANCE` of a step per step); pitches and rolls distinct (rolls
modulo 360); each receiver's survey points spanning an area (3 points not on
one line) whose convex hull holds at least :data:`MIN_SURVEY_COVERAGE` of the
candidate positions. Candidates outside a receiver's hull follow ``[survey]
outside``.

Optional ``site.toml`` keys beyond the contract (documented in
``docs/site.md``): ``[survey] interpolation = "cubic"|"linear"``,
``[survey] outside = "nearest"|"exclude"``.

3-D pose (``docs/pose3d.md``): ``[area]`` takes either ``z_m`` (one candidate
height, the 2-D search) or ``z_min_m``, ``z_max_m``, ``z_step_m`` (a range of
candidate heights, at most :data:`MAX_HEIGHTS`), never both. With a range,
``AreaGrid.z_m`` is the level nearest the middle of the range (the height at
which the 2-D methods search).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from radiopose.errors import InputError
from radiopose.geometry import (
    direction_to_pattern_angles_deg,
    orientation_matrices,
    pattern_angles_deg,
    stored_orientation_matrices,
)
from radiopose.packets import RSS_MAX_DBM, RSS_MIN_DBM
from radiopose.patterns.pattern import Pattern
from radiopose.survey import (
    SurveyMap,
    SurveyPoints,
    average_by_point,
)
from radiopose.tables import Column
from radiopose.units import COORD_LIMIT_M, FloatArray

MAX_GRID_POINTS = 25_000_000
"""Most candidate positions (``nx · ny``)."""
MAX_ORIENTATIONS = 100_000
"""Most candidate orientations (azimuths × pitches × rolls); azimuth step ≥ 0.0036°."""
MAX_CANDIDATES = 250_000_000
"""Most candidate poses, positions × orientations (the standard scenario has
201² × 360 ≈ 14.5 million); beyond it a packet's exhaustive scoring and the
numpy scorer's float32 table (5 GB at 4 receivers) stop being practical."""
STEP_TOLERANCE = 1e-9
"""An area span is a whole number ``k`` of steps if ``|span/step − k| ≤ 1e-9 · max(k, 1)``."""
MAX_HEIGHTS = 1000
"""Most candidate heights of a ``z_min_m``/``z_max_m``/``z_step_m`` range."""
MIN_SURVEY_COVERAGE = 0.5
"""Least fraction of candidate positions inside each receiver's surveyed convex hull."""
SURVEY_HEIGHT_DECIMALS = 3
"""Survey heights (``z_m``) rounded to this many decimals are one surveyed height
(a layer of :func:`radiopose.survey_height.build_height_model`)."""
ANGLE_COLUMNS = (
    Column("azimuth_deg", low=-360.0, high=360.0),
    Column("pitch_deg", low=-90.0, high=90.0),
    Column("roll_deg", low=-360.0, high=360.0),
)
_XYZ_COLUMNS = tuple(
    Column(c, low=-COORD_LIMIT_M, high=COORD_LIMIT_M) for c in ("x_m", "y_m", "z_m")
)
RECEIVER_COLUMNS = (
    Column("receiver_id", "str"),
    *_XYZ_COLUMNS,
    *ANGLE_COLUMNS,
    Column("pattern", "str"),
)
DEVICE_COLUMNS = (
    Column("transmitter", "str"),
    Column("pattern", "str"),
    Column("tx_power_dbm", low=-100.0, high=60.0),
)
SURVEY_COLUMNS = (
    *_XYZ_COLUMNS,
    Column("receiver_id", "str"),
    Column("rss_dbm", low=RSS_MIN_DBM, high=RSS_MAX_DBM),
    *ANGLE_COLUMNS,
)


def grid_steps(span: float, step: float) -> tuple[int, bool]:
    """Whole steps of ``step`` that fit in ``span`` and whether they fill it.

    Returns ``(k, exact)``: ``k = round(span/step)`` if that is within
    :data:`STEP_TOLERANCE` (relative) of ``span/step`` and ``exact`` is true;
    otherwise ``k = floor(span/step)`` and ``exact`` is false.
    """
    k = span / step
    r = round(k)
    if abs(k - r) <= STEP_TOLERANCE * max(abs(k), 1.0):
        return int(r), True
    return int(np.floor(k)), False


@dataclass(frozen=True)
class AreaGrid:
    """Candidate positions: a regular grid at one height (or a range of heights).

    ``x_m()`` runs ``x_min_m, x_min_m + step_m, …`` up to ``x_max_m`` (inclusive
    when the span is a whole number of steps within :data:`STEP_TOLERANCE`,
    which :func:`load_site` requires); likewise ``y_m()``. Flattened candidates
    are in ``ij`` order: index ``ix * ny + iy``, all at height ``z_m``.

    3-D pose: ``z_min_m``, ``z_max_m``, ``z_step_m`` (all three or none) give
    the candidate heights :meth:`z_levels_m`; ``z_m`` is then the level nearest
    the middle of the range (see :func:`height_range_middle_m`).
    """

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    z_m: float
    step_m: float
    z_min_m: float | None = None
    z_max_m: float | None = None
    z_step_m: float | None = None

    @property
    def has_height_range(self) -> bool:
        """Whether the site carries a range of candidate heights (3-D pose)."""
        return self.z_min_m is not None

    def z_levels_m(self) -> FloatArray:
        """``(nz,)`` candidate heights, metres: the range, or ``[z_m]``."""
        if self.z_min_m is None or self.z_max_m is None or self.z_step_m is None:
            return np.array([self.z_m])
        n = grid_steps(self.z_max_m - self.z_min_m, self.z_step_m)[0] + 1
        return self.z_min_m + np.arange(n, dtype=np.float64) * self.z_step_m

    def _axis(self, lo: float, hi: float) -> FloatArray:
        n = grid_steps(hi - lo, self.step_m)[0] + 1
        return lo + np.arange(n, dtype=np.float64) * self.step_m

    def x_m(self) -> FloatArray:
        return self._axis(self.x_min_m, self.x_max_m)

    def y_m(self) -> FloatArray:
        return self._axis(self.y_min_m, self.y_max_m)

    @property
    def shape(self) -> tuple[int, int]:
        return self.x_m().size, self.y_m().size

    def points_m(self) -> FloatArray:
        """``(nx·ny, 3)`` candidate positions in ``ij`` order, metres."""
        gx, gy = np.meshgrid(self.x_m(), self.y_m(), indexing="ij")
        return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, self.z_m)])


@dataclass(frozen=True)
class OrientationGrid:
    """Candidate orientations: azimuths at a step × listed pitches × listed rolls.

    Flattened order: pitch slowest, then roll, azimuth fastest — index
    ``(ip * n_roll + ir) * n_azimuth + ia``.
    """

    azimuth_step_deg: float = 1.0
    pitch_deg: tuple[float, ...] = (0.0,)
    roll_deg: tuple[float, ...] = (0.0,)

    def azimuth_deg(self) -> FloatArray:
        n = round(360.0 / self.azimuth_step_deg)
        return np.arange(n, dtype=np.float64) * (360.0 / n)

    @property
    def n_azimuth(self) -> int:
        return round(360.0 / self.azimuth_step_deg)

    def __len__(self) -> int:
        return self.n_azimuth * len(self.pitch_deg) * len(self.roll_deg)

    def orientations_deg(self) -> FloatArray:
        """``(m, 3)`` (azimuth, pitch, roll) in degrees, flattened order above."""
        p, r, a = np.meshgrid(self.pitch_deg, self.roll_deg, self.azimuth_deg(), indexing="ij")
        return np.column_stack([a.ravel(), p.ravel(), r.ravel()])


@dataclass(frozen=True)
class Receiver:
    """A fixed receiver: id, position (m), orientation (deg) and pattern name."""

    receiver_id: str
    x_m: float
    y_m: float
    z_m: float
    azimuth_deg: float
    pitch_deg: float
    roll_deg: float
    pattern: str

    @property
    def position_m(self) -> FloatArray:
        return np.array([self.x_m, self.y_m, self.z_m])


@dataclass(frozen=True)
class Device:
    """An enrolled device: transmitter address, pattern name, transmit power (dBm)."""

    transmitter: str
    pattern: str
    tx_power_dbm: float


@dataclass(frozen=True)
class SurveyConfig:
    """Survey transmitter and survey-map settings."""

    tx_power_dbm: float
    pattern: str
    interpolation: str = "cubic"
    outside: str = "nearest"


@dataclass(frozen=True)
class SurveyRows:
    """Raw survey rows (contract ``survey.csv``), one array per column."""

    xyz_m: FloatArray
    receiver_id: np.ndarray
    rss_dbm: FloatArray
    orientation_deg: FloatArray


@dataclass(frozen=True, eq=False)
class Site:
    """A validated site. See the module docstring."""

    name: str
    area: AreaGrid
    orientations: OrientationGrid
    survey_config: SurveyConfig
    receivers: tuple[Receiver, ...]
    devices: tuple[Device, ...]
    patterns: Mapping[str, Pattern]
    survey_rows: SurveyRows
    survey_map: SurveyMap = field(repr=False)
    path: str | None = None

    @property
    def receiver_ids(self) -> tuple[str, ...]:
        return tuple(r.receiver_id for r in self.receivers)

    def receiver_positions_m(self) -> FloatArray:
        """``(n_receivers, 3)`` receiver positions, metres, in site order."""
        return np.array([r.position_m for r in self.receivers]).reshape(-1, 3)

    def device(self, transmitter: str) -> Device:
        """The enrolled device of a transmitter (case-insensitive address match).

        Raises
        ------
        InputError
            ``transmitter`` is not text, or not enrolled.
        """
        if not isinstance(transmitter, str):
            raise InputError(
                f"transmitter must be text, got {type(transmitter).__name__} {transmitter!r:.40}"
            )
        key = transmitter.lower()
        for d in self.devices:
            if d.transmitter.lower() == key:
                return d
        raise InputError(f"unknown transmitter {transmitter!r}: not enrolled in devices.csv")

    def device_pattern(self, transmitter: str) -> Pattern:
        """The pattern of a transmitter's enrolled device.

        Raises
        ------
        InputError
            As :meth:`device`, or the site holds no pattern of the device's name.
        """
        d = self.device(transmitter)
        pattern = self.patterns.get(d.pattern)
        if pattern is None:
            raise InputError(
                f"device {d.transmitter!r} names pattern {d.pattern!r}, which site "
                f"{self.name!r} does not hold"
            )
        return pattern


def height_range_middle_m(z_min_m: float, z_max_m: float, z_step_m: float) -> float:
    """The candidate height nearest the middle of a range (lower one on a tie), metres."""
    n = grid_steps(z_max_m - z_min_m, z_step_m)[0]
    return z_min_m + (n // 2) * z_step_m


def site_is_3d(site: Site) -> bool:
    """Whether a site asks for 3-D pose: a height range, or several pitches or rolls."""
    return parts_are_3d(site.area, site.orientations)


def parts_are_3d(area: AreaGrid, orientations: OrientationGrid) -> bool:
    """:func:`site_is_3d` of a site's area and candidate orientations."""
    o = orientations
    return area.has_height_range or len(o.pitch_deg) > 1 or len(o.roll_deg) > 1


def missing_survey_height(
    rows: SurveyRows, receiver_ids: tuple[str, ...], decimals: int = SURVEY_HEIGHT_DECIMALS
) -> tuple[float, str, int] | None:
    """The first surveyed height that lacks rows for some receiver.

    Heights are the survey's ``z_m`` rounded to ``decimals``; a survey at one
    height is complete. Returns ``(height_m, receiver_id, row)`` (``row``: the
    first survey row at that height) or ``None`` when every surveyed height has
    rows for every receiver.
    """
    z = np.round(np.asarray(rows.xyz_m, float)[:, 2], decimals)
    layers = np.unique(z)
    if layers.size < 2:
        return None
    rid = np.asarray(rows.receiver_id)
    for h in layers:
        sel = z == h
        present = set(rid[sel].tolist())
        for r in receiver_ids:
            if r not in present:
                return float(h), r, int(np.argmax(sel))
    return None


# ----------------------------------------------------------------------------- survey
def correct_survey(
    rows: SurveyRows, tx_power_dbm: float, survey_pattern: Pattern, receivers: tuple[Receiver, ...]
) -> FloatArray:
    """``M = R − P_tx − D_st`` per survey row (dB), see :mod:`radiopose.survey`."""
    ids = [r.receiver_id for r in receivers]
    rx_pos = np.array([r.position_m for r in receivers]).reshape(-1, 3)
    idx = np.array([ids.index(r) for r in rows.receiver_id], dtype=np.int64)
    rot = stored_orientation_matrices(rows.orientation_deg)  # (n, 3, 3)
    d = rx_pos[idx] - rows.xyz_m  # world direction survey tx → receiver
    v = np.einsum("ni,nij->nj", d, rot)  # body frame: v = Rᵀ d
    phi, theta = direction_to_pattern_angles_deg(v)
    d_st = survey_pattern.lookup_dbi(phi, theta)
    return rows.rss_dbm - tx_power_dbm - d_st


def survey_points_by_receiver(
    rows: SurveyRows, m_db: FloatArray, receiver_ids: tuple[str, ...]
) -> tuple[SurveyPoints, ...]:
    """Average corrected values per surveyed point, for each receiver in order."""
    out = []
    for rid in receiver_ids:
        sel = rows.receiver_id == rid
        out.append(average_by_point(rows.xyz_m[sel, :2], m_db[sel]))
    return tuple(out)


def device_directivity_dbi(
    pattern: Pattern,
    device_xyz_m: FloatArray,
    orientation_deg: FloatArray,
    receiver_xyz_m: FloatArray,
) -> FloatArray:
    """Device directivity toward receivers, ``(n, m, k)`` dBi (see geometry)."""
    rot = orientation_matrices(*np.asarray(orientation_deg, float).reshape(-1, 3).T)
    phi, theta = pattern_angles_deg(device_xyz_m, rot, receiver_xyz_m)
    return pattern.lookup_dbi(phi, theta)


# ------------------------------------------------------------- files (radiopose.site_io)
_IO_NAMES = ("assemble_site", "load_site", "write_site", "write_site_toml")

if TYPE_CHECKING:  # the lazy re-exports below, for type checkers
    from radiopose.site_io import assemble_site as assemble_site
    from radiopose.site_io import load_site as load_site
    from radiopose.site_io import write_site as write_site
    from radiopose.site_io import write_site_toml as write_site_toml


def __getattr__(name: str) -> Any:
    """The file functions, now in :mod:`radiopose.site_io` (imported on first use:
    that module imports this one)."""
    if name in _IO_NAMES:
        from radiopose import site_io

        return getattr(site_io, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
