"""A site: candidate grid, receivers, enrolled devices, patterns and survey.

A site directory (interchange contract, "Site")::

    site.toml            area, candidate grid, survey transmitter
    receivers.csv        receiver_id, x_m, y_m, z_m, azimuth_deg, pitch_deg, roll_deg, pattern
    devices.csv          transmitter, pattern, tx_power_dbm
    patterns/<name>.csv  every pattern named above
    survey.csv           x_m, y_m, z_m, receiver_id, rss_dbm, azimuth_deg, pitch_deg, roll_deg

:func:`load_site` validates all of it (every referenced pattern present,
receiver ids unique, grid sane, every receiver surveyed, survey rows name known
receivers) and builds the survey map (:mod:`radiopose.survey`).
:func:`write_site` writes one (atomically, file by file).

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

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.config import Section, load_toml
from radiopose.errors import InputError
from radiopose.geometry import (
    direction_to_pattern_angles_deg,
    orientation_matrices,
    pattern_angles_deg,
)
from radiopose.patterns.pattern import Pattern, read_pattern_csv, write_pattern_csv
from radiopose.survey import (
    SurveyMap,
    SurveyPoints,
    average_by_point,
    build_survey_map,
    hull_coverage,
    spans_two_dimensions,
)
from radiopose.tables import Column, Table, atomic_writer, read_table, write_table
from radiopose.units import FloatArray, wrap_signed_deg

COORD_LIMIT_M = 1e6
"""Bound on every coordinate (site.toml area, receivers.csv, survey.csv), metres."""
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
    Column("rss_dbm", low=-200.0, high=50.0),
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
        """The enrolled device of a transmitter (case-insensitive address match)."""
        key = transmitter.lower()
        for d in self.devices:
            if d.transmitter.lower() == key:
                return d
        raise InputError(f"unknown transmitter {transmitter!r}: not enrolled in devices.csv")

    def device_pattern(self, transmitter: str) -> Pattern:
        return self.patterns[self.device(transmitter).pattern]


def height_range_middle_m(z_min_m: float, z_max_m: float, z_step_m: float) -> float:
    """The candidate height nearest the middle of a range (lower one on a tie), metres."""
    n = grid_steps(z_max_m - z_min_m, z_step_m)[0]
    return z_min_m + (n // 2) * z_step_m


def site_is_3d(site: Site) -> bool:
    """Whether a site asks for 3-D pose: a height range, or several pitches or rolls."""
    o = site.orientations
    return site.area.has_height_range or len(o.pitch_deg) > 1 or len(o.roll_deg) > 1


# ----------------------------------------------------------------------------- survey
def correct_survey(
    rows: SurveyRows, tx_power_dbm: float, survey_pattern: Pattern, receivers: tuple[Receiver, ...]
) -> FloatArray:
    """``M = R − P_tx − D_st`` per survey row (dB), see :mod:`radiopose.survey`."""
    ids = [r.receiver_id for r in receivers]
    rx_pos = np.array([r.position_m for r in receivers]).reshape(-1, 3)
    idx = np.array([ids.index(r) for r in rows.receiver_id], dtype=np.int64)
    rot = orientation_matrices(*rows.orientation_deg.T)  # (n, 3, 3)
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


# ----------------------------------------------------------------------------- loading
@dataclass(frozen=True)
class _SiteToml:
    name: str
    area: AreaGrid
    orientations: OrientationGrid
    survey: SurveyConfig
    area_section: Section
    survey_section: Section


def _safe_pattern_name(name: str) -> bool:
    """A pattern name is a plain file name: ``patterns/<name>.csv`` stays in ``patterns/``."""
    return "/" not in name and "\\" not in name and "\0" not in name and name not in (".", "..")


def _axis_steps(a: Section, axis: str, lo: float, hi: float, step: float) -> int:
    """Steps along one area axis; the span must be a whole number of steps."""
    if hi < lo:
        raise a.error(f"{axis}_max_m", f"must be >= {axis}_min_m ({lo:g}), got {hi:g}")
    k = (hi - lo) / step  # inf when a subnormal step overflows the division
    if not np.isfinite(k) or k + 1 > MAX_GRID_POINTS:
        raise a.error(
            "step_m",
            f"{axis} span {hi - lo:g} m / step {step:g} m gives more than "
            f"{MAX_GRID_POINTS:,} candidate positions",
        )
    n, exact = grid_steps(hi - lo, step)
    if not exact:
        raise a.error(
            "step_m",
            f"the {axis} span {hi - lo:g} m ({axis}_min_m to {axis}_max_m) must be a whole "
            f"number of steps of {step:g} m, got {k:.6g} steps",
        )
    return n


def _distinct(o: Section, name: str, values: tuple[float, ...], periodic: bool) -> None:
    """Reject repeated angles (modulo 360 if ``periodic``: roll 180 = roll -180)."""
    seen: dict[float, int] = {}
    for i, v in enumerate(values):
        key = float(wrap_signed_deg(v)) if periodic else v
        key = round(key, 9) + 0.0  # -0.0 == 0.0; float noise below 1e-9 deg
        if periodic and key == 180.0:  # 179.9999999999 rounds up: the same roll as -180
            key = -key
        if key in seen:
            same = "equal modulo 360 to" if periodic else "the same as"
            raise o.error(
                name, f"item {i} = {v:g} is {same} item {seen[key]}; values must be distinct"
            )
        seen[key] = i


_HEIGHT_KEYS = ("z_min_m", "z_max_m", "z_step_m")


def _read_heights(a: Section) -> tuple[float, tuple[float | None, float | None, float | None]]:
    """``[area]`` heights: ``z_m`` alone (2-D) or ``z_min_m``/``z_max_m``/``z_step_m``
    (3-D); returns ``(z_m, (z_min_m, z_max_m, z_step_m))`` (``None`` s without a range)."""
    lim: dict[str, Any] = {"low": -COORD_LIMIT_M, "high": COORD_LIMIT_M}
    given = [k for k in _HEIGHT_KEYS if a.has(k)]
    if not given:
        return a.number("z_m", required=True, **lim), (None, None, None)
    if a.has("z_m"):
        raise a.error(
            given[0],
            "give either z_m (one candidate height) or z_min_m, z_max_m, z_step_m, not both",
        )
    for k in _HEIGHT_KEYS:
        if k not in given:
            raise a.error(k, f"missing: a height range needs all of {', '.join(_HEIGHT_KEYS)}")
    z_lo = a.number("z_min_m", required=True, **lim)
    z_hi = a.number("z_max_m", required=True, **lim)
    z_step = a.number("z_step_m", required=True, positive=True, high=2 * COORD_LIMIT_M)
    if z_hi < z_lo:
        raise a.error("z_max_m", f"must be >= z_min_m ({z_lo:g}), got {z_hi:g}")
    n_steps = (z_hi - z_lo) / z_step
    if not np.isfinite(n_steps) or n_steps + 1 > MAX_HEIGHTS:
        raise a.error("z_step_m", f"the height range gives more than {MAX_HEIGHTS} heights")
    if not grid_steps(z_hi - z_lo, z_step)[1]:
        raise a.error(
            "z_step_m",
            f"the height span {z_hi - z_lo:g} m (z_min_m to z_max_m) must be a whole number "
            f"of steps of {z_step:g} m, got {k:.6g} steps",
        )
    return height_range_middle_m(z_lo, z_hi, z_step), (z_lo, z_hi, z_step)


def _read_site_toml(path: Path) -> _SiteToml:
    root = Section(load_toml(path), path)
    name = root.string("name", path.parent.name)
    a = root.section("area")
    lim: dict[str, Any] = {"low": -COORD_LIMIT_M, "high": COORD_LIMIT_M}
    x_min = a.number("x_min_m", required=True, **lim)
    x_max = a.number("x_max_m", required=True, **lim)
    y_min = a.number("y_min_m", required=True, **lim)
    y_max = a.number("y_max_m", required=True, **lim)
    z, z_range = _read_heights(a)
    step = a.number("step_m", required=True, positive=True, high=2 * COORD_LIMIT_M)
    nx = _axis_steps(a, "x", x_min, x_max, step) + 1
    ny = _axis_steps(a, "y", y_min, y_max, step) + 1
    if nx * ny > MAX_GRID_POINTS:
        raise a.error("step_m", f"grid of {nx}x{ny} candidates exceeds {MAX_GRID_POINTS:,}")
    a.finish()
    area = AreaGrid(x_min, x_max, y_min, y_max, z, step, *z_range)

    o = root.section("orientations")
    az_step = o.number("azimuth_step_deg", 1.0, positive=True, high=360.0)
    n_az = 360.0 / az_step
    if n_az > MAX_ORIENTATIONS + 0.5:
        raise o.error(
            "azimuth_step_deg",
            f"{az_step:g} gives {n_az:.4g} azimuths, more than {MAX_ORIENTATIONS:,} candidate "
            f"orientations (the step must be >= {360.0 / MAX_ORIENTATIONS:g})",
        )
    if abs(round(n_az) * az_step - 360.0) > 1e-6:
        raise o.error("azimuth_step_deg", f"{az_step:g} does not divide 360")
    pitch = o.numbers("pitch_deg", (0.0,), low=-90.0, high=90.0, scalar=False)
    _distinct(o, "pitch_deg", pitch, periodic=False)
    roll = o.numbers("roll_deg", (0.0,), low=-360.0, high=360.0, scalar=False)
    _distinct(o, "roll_deg", roll, periodic=True)
    orient = OrientationGrid(az_step, pitch, roll)
    if len(orient) > MAX_ORIENTATIONS:
        raise o.table_error(
            f"{orient.n_azimuth} azimuths x {len(pitch)} pitches x {len(roll)} rolls = "
            f"{len(orient):,} candidate orientations, more than {MAX_ORIENTATIONS:,}"
        )
    if nx * ny * len(orient) > MAX_CANDIDATES:
        raise o.table_error(
            f"{nx * ny:,} positions x {len(orient):,} orientations = "
            f"{nx * ny * len(orient):.3g} candidate poses, more than {MAX_CANDIDATES:,}; "
            "use a coarser [area] step_m or fewer orientations"
        )
    o.finish()

    s = root.section("survey")
    survey = SurveyConfig(
        tx_power_dbm=s.number("tx_power_dbm", required=True, low=-100.0, high=60.0),
        pattern=s.string("pattern", required=True),
        interpolation=s.string("interpolation", "cubic", choices=("cubic", "linear")),
        outside=s.string("outside", "nearest", choices=("nearest", "exclude")),
    )
    if not _safe_pattern_name(survey.pattern):
        raise s.error("pattern", f"pattern name {survey.pattern!r} is not a plain file name")
    s.finish()
    root.finish()
    return _SiteToml(name, area, orient, survey, a, s)


def _percent(fraction: float) -> str:
    """``0.4996`` → ``"49.9%"``: rounded down, so a rejected value never reads as the limit."""
    return f"{math.floor(fraction * 1000) / 10:g}%"


def _check_survey_geometry(st: Table, rows: SurveyRows, toml: _SiteToml) -> None:
    """Each receiver's survey spans an area whose hull covers enough of the grid.

    Raises :class:`InputError` naming survey.csv (the receiver's first row) or,
    when the whole survey misses the area, site.toml's ``[area]``.
    """
    gx, gy = toml.area.x_m(), toml.area.y_m()
    xy = np.unique(np.round(rows.xyz_m[:, :2], 6), axis=0)
    per_rx: list[tuple[str, int, FloatArray]] = []
    for rid in dict.fromkeys(rows.receiver_id):
        sel = rows.receiver_id == rid
        first = int(np.argmax(sel))
        pts = np.unique(np.round(rows.xyz_m[sel, :2], 6), axis=0)
        if not spans_two_dimensions(pts):
            raise st.error(
                first,
                "receiver_id",
                f"receiver {rid!r}: its {len(pts)} surveyed point(s) do not span an area "
                "(need at least 3 points (x_m, y_m) not on one line)",
            )
        per_rx.append((str(rid), first, pts))
    cover = hull_coverage(xy, gx, gy)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if cover < MIN_SURVEY_COVERAGE:
        raise toml.area_section.table_error(
            f"only {_percent(cover)} of the candidate positions lie inside the surveyed "
            f"convex hull (survey.csv spans x {lo[0]:g}..{hi[0]:g} m, y {lo[1]:g}..{hi[1]:g} m); "
            f"at least {_percent(MIN_SURVEY_COVERAGE)} must"
        )
    for rid, first, pts in per_rx:
        cover = hull_coverage(pts, gx, gy)
        if cover < MIN_SURVEY_COVERAGE:
            raise st.error(
                first,
                "receiver_id",
                f"receiver {rid!r}: only {_percent(cover)} of the candidate positions (site.toml "
                f"[area]) lie inside the convex hull of its survey points; at least "
                f"{_percent(MIN_SURVEY_COVERAGE)} must",
            )


def load_site(directory: str | os.PathLike[str]) -> Site:
    """Load and validate a site directory; build its survey map.

    Raises
    ------
    InputError
        One line naming the file (and line/column or key) of the first problem.
    """
    root = Path(directory)
    if not root.is_dir():
        raise InputError("site directory not found", path=root)
    toml = _read_site_toml(root / "site.toml")

    rt = read_table(root / "receivers.csv", RECEIVER_COLUMNS)
    if len(rt) == 0:
        raise InputError("no receivers", path=rt.path, line=2)
    receivers = []
    seen: dict[str, int] = {}
    for i in range(len(rt)):
        rid = str(rt["receiver_id"][i])
        if rid in seen:
            raise rt.error(i, "receiver_id", f"duplicate receiver id {rid!r}")
        seen[rid] = i
        receivers.append(
            Receiver(  # type: ignore[misc]  # mypy cannot count a generator's star-args
                rid,
                *(  # type: ignore[arg-type]
                    float(rt[c][i])
                    for c in ("x_m", "y_m", "z_m", "azimuth_deg", "pitch_deg", "roll_deg")
                ),
                pattern=str(rt["pattern"][i]),
            )
        )

    dt = read_table(root / "devices.csv", DEVICE_COLUMNS)
    devices = []
    seen_tx: set[str] = set()
    for i in range(len(dt)):
        tx = str(dt["transmitter"][i])
        if tx.lower() in seen_tx:
            raise dt.error(i, "transmitter", f"duplicate transmitter {tx!r}")
        seen_tx.add(tx.lower())
        devices.append(Device(tx, str(dt["pattern"][i]), float(dt["tx_power_dbm"][i])))

    # Patterns: every referenced name must exist as patterns/<name>.csv.
    survey_key = toml.survey_section
    wanted: dict[str, InputError] = {}
    for i, r in enumerate(receivers):
        wanted.setdefault(r.pattern, rt.error(i, "pattern", ""))
    for i, d in enumerate(devices):
        wanted.setdefault(d.pattern, dt.error(i, "pattern", ""))
    wanted.setdefault(toml.survey.pattern, survey_key.error("pattern", ""))
    patterns: dict[str, Pattern] = {}
    for pname, where in wanted.items():
        ppath = root / "patterns" / f"{pname}.csv"
        if not _safe_pattern_name(pname):
            problem = f"pattern name {pname!r} is not a plain file name"
        elif not ppath.is_file():
            problem = f"unknown pattern {pname!r}: no file patterns/{pname}.csv"
        else:
            patterns[pname] = read_pattern_csv(ppath, name=pname)
            continue
        raise InputError(problem, path=where.path, line=where.line, column=where.column)

    st = read_table(root / "survey.csv", SURVEY_COLUMNS)
    if len(st) == 0:
        raise InputError("no survey rows", path=st.path, line=2)
    for i, rid in enumerate(st["receiver_id"]):
        if rid not in seen:
            raise st.error(i, "receiver_id", f"unknown receiver {rid!r} (not in receivers.csv)")
    rows = SurveyRows(
        xyz_m=np.column_stack([st["x_m"], st["y_m"], st["z_m"]]),
        receiver_id=st["receiver_id"],
        rss_dbm=st["rss_dbm"],
        orientation_deg=np.column_stack([st["azimuth_deg"], st["pitch_deg"], st["roll_deg"]]),
    )
    for i, r in enumerate(receivers):
        if not np.any(rows.receiver_id == r.receiver_id):
            raise rt.error(
                i, "receiver_id", f"receiver {r.receiver_id!r} has no survey rows in survey.csv"
            )
    _check_survey_geometry(st, rows, toml)
    return assemble_site(
        toml.name,
        toml.area,
        toml.orientations,
        toml.survey,
        tuple(receivers),
        tuple(devices),
        patterns,
        rows,
        path=str(root),
    )


def assemble_site(
    name: str,
    area: AreaGrid,
    orientations: OrientationGrid,
    survey_config: SurveyConfig,
    receivers: tuple[Receiver, ...],
    devices: tuple[Device, ...],
    patterns: Mapping[str, Pattern],
    survey_rows: SurveyRows,
    path: str | None = None,
) -> Site:
    """Build a :class:`Site` from validated parts: correct and interpolate the survey."""
    m_db = correct_survey(
        survey_rows, survey_config.tx_power_dbm, patterns[survey_config.pattern], receivers
    )
    ids = tuple(r.receiver_id for r in receivers)
    points = survey_points_by_receiver(survey_rows, m_db, ids)
    smap = build_survey_map(
        ids,
        points,
        area.x_m(),
        area.y_m(),
        survey_config.interpolation,  # type: ignore[arg-type]
        survey_config.outside,  # type: ignore[arg-type]
    )
    return Site(
        name,
        area,
        orientations,
        survey_config,
        receivers,
        devices,
        dict(patterns),
        survey_rows,
        smap,
        path,
    )


# ----------------------------------------------------------------------------- writing
def _toml_number(x: float) -> str:
    return repr(float(x))


def _toml_string(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's; DEL must be escaped too)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def write_site_toml(
    path: str | os.PathLike[str],
    name: str,
    area: AreaGrid,
    orientations: OrientationGrid,
    survey: SurveyConfig,
) -> None:
    """Write ``site.toml`` (atomically)."""
    heights = _HEIGHT_KEYS if area.has_height_range else ("z_m",)
    lines = [
        f"name = {_toml_string(name)}",
        "",
        "[area]",
        *(
            f"{k} = {_toml_number(getattr(area, k))}"
            for k in ("x_min_m", "x_max_m", "y_min_m", "y_max_m", *heights, "step_m")
        ),
        "",
        "[orientations]",
        f"azimuth_step_deg = {_toml_number(orientations.azimuth_step_deg)}",
        f"pitch_deg = [{', '.join(_toml_number(p) for p in orientations.pitch_deg)}]",
        f"roll_deg = [{', '.join(_toml_number(r) for r in orientations.roll_deg)}]",
        "",
        "[survey]",
        f"tx_power_dbm = {_toml_number(survey.tx_power_dbm)}",
        f"pattern = {_toml_string(survey.pattern)}",
        f'interpolation = "{survey.interpolation}"',
        f'outside = "{survey.outside}"',
        "",
    ]
    with atomic_writer(path) as fh:
        fh.write("\n".join(lines))


def write_site(site: Site, directory: str | os.PathLike[str]) -> None:
    """Write a site directory in the contract layout (each file atomically)."""
    root = Path(directory)
    receivers, devices, survey_rows = site.receivers, site.devices, site.survey_rows
    write_site_toml(root / "site.toml", site.name, site.area, site.orientations, site.survey_config)
    write_table(
        root / "receivers.csv",
        {
            "receiver_id": [r.receiver_id for r in receivers],
            **{
                c: np.array([getattr(r, c) for r in receivers], float)
                for c in ("x_m", "y_m", "z_m", "azimuth_deg", "pitch_deg", "roll_deg")
            },
            "pattern": [r.pattern for r in receivers],
        },
    )
    write_table(
        root / "devices.csv",
        {
            "transmitter": [d.transmitter for d in devices],
            "pattern": [d.pattern for d in devices],
            "tx_power_dbm": np.array([d.tx_power_dbm for d in devices], float),
        },
    )
    for pname, pat in site.patterns.items():
        write_pattern_csv(pat.renamed(pname), root / "patterns" / f"{pname}.csv")
    write_table(
        root / "survey.csv",
        {
            "x_m": survey_rows.xyz_m[:, 0],
            "y_m": survey_rows.xyz_m[:, 1],
            "z_m": survey_rows.xyz_m[:, 2],
            "receiver_id": survey_rows.receiver_id,
            "rss_dbm": survey_rows.rss_dbm,
            "azimuth_deg": survey_rows.orientation_deg[:, 0],
            "pitch_deg": survey_rows.orientation_deg[:, 1],
            "roll_deg": survey_rows.orientation_deg[:, 2],
        },
    )
