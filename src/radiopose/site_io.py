"""Site directories: read, validate and write them (:class:`~radiopose.site.Site`).

A site directory (interchange contract, "Site")::

    site.toml            area, candidate grid, survey transmitter
    receivers.csv        receiver_id, x_m, y_m, z_m, azimuth_deg, pitch_deg, roll_deg, pattern
    devices.csv          transmitter, pattern, tx_power_dbm
    patterns/<name>.csv  every pattern named above
    survey.csv           x_m, y_m, z_m, receiver_id, rss_dbm, azimuth_deg, pitch_deg, roll_deg

:func:`load_site` validates all of it (the limits are documented in
:mod:`radiopose.site`, whose value objects it builds) and builds the survey map
(:mod:`radiopose.survey`); :func:`assemble_site` builds a site from objects
already in memory with the same checks (one set, :func:`_check_site`, whose
errors name the file, line and column for a directory and the argument, index
and field for objects); :func:`write_site` writes one (atomically, file by
file) after the same checks, so it never writes a site :func:`load_site`
refuses. Split from :mod:`radiopose.site` so that the value
objects and their geometry read apart from the file formats; the old names
stay importable from there.
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.config import Section, load_toml
from radiopose.errors import InputError
from radiopose.ids import (
    check_receiver_ids,
    check_transmitter_ids,
    receiver_id_problem,
    transmitter_id_problem,
)
from radiopose.patterns.pattern import Pattern, read_pattern_csv, write_pattern_csv
from radiopose.site import (
    COORD_LIMIT_M,
    DEVICE_COLUMNS,
    MAX_CANDIDATES,
    MAX_GRID_POINTS,
    MAX_HEIGHTS,
    MAX_ORIENTATIONS,
    MIN_SURVEY_COVERAGE,
    RECEIVER_COLUMNS,
    SURVEY_COLUMNS,
    SURVEY_HEIGHT_DECIMALS,
    AreaGrid,
    Device,
    OrientationGrid,
    Receiver,
    Site,
    SurveyConfig,
    SurveyRows,
    correct_survey,
    grid_steps,
    height_range_middle_m,
    missing_survey_height,
    parts_are_3d,
    survey_points_by_receiver,
)
from radiopose.survey import (
    METHODS,
    OUTSIDE_POLICIES,
    build_survey_map,
    hull_coverage,
    spans_two_dimensions,
)
from radiopose.tables import Column, Table, atomic_writer, read_table, write_table
from radiopose.units import FloatArray, wrap_signed_deg


@dataclass(frozen=True)
class _SiteToml:
    name: str
    area: AreaGrid
    orientations: OrientationGrid
    survey: SurveyConfig
    area_section: Section
    orientations_section: Section
    survey_section: Section


@dataclass(frozen=True)
class _SiteParts:
    """The parts of a site before its survey map is built (:func:`_check_site`)."""

    name: str
    area: AreaGrid
    orientations: OrientationGrid
    survey_config: SurveyConfig
    receivers: tuple[Receiver, ...]
    devices: tuple[Device, ...]
    patterns: Mapping[str, Pattern]
    survey_rows: SurveyRows


# ----------------------------------------------------------------------------- where
ErrorAt = Callable[[str, str], InputError]
"""``(key, message) -> InputError`` at one setting of a site part."""


class _Where:
    """Where a site's parts came from, for the one-line errors of the checks:
    the files of a site directory (:class:`_InFiles`) or a function's arguments
    (:class:`_InArguments`). Parts: ``area``, ``orientations``,
    ``survey_config`` (settings, by key), ``receivers``, ``devices``,
    ``survey_rows`` (rows, by index and column), ``patterns``, ``name``."""

    def row(self, part: str, i: int, column: str | None, message: str) -> InputError:
        raise NotImplementedError

    def whole(self, part: str, message: str) -> InputError:
        raise NotImplementedError

    def key(self, part: str, key: str | None, message: str) -> InputError:
        raise NotImplementedError

    def name(self, part: str) -> str:
        """How messages name a part (``receivers.csv`` or ``receivers``)."""
        raise NotImplementedError

    def at(self, part: str) -> ErrorAt:
        """:meth:`key` of one part."""
        return lambda key, message: self.key(part, key, message)


_FILE_NAMES = {
    "receivers": "receivers.csv",
    "devices": "devices.csv",
    "survey_rows": "survey.csv",
    "area": "site.toml [area]",
    "orientations": "site.toml [orientations]",
    "survey_config": "site.toml [survey]",
    "patterns": "patterns/",
}


class _InFiles(_Where):
    """A site directory's files: file, line and column (or dotted key)."""

    def __init__(self, sections: Mapping[str, Section], tables: Mapping[str, Table]) -> None:
        self.sections, self.tables = sections, tables

    def row(self, part: str, i: int, column: str | None, message: str) -> InputError:
        return self.tables[part].error(i, column, message)

    def whole(self, part: str, message: str) -> InputError:
        if part in self.tables:
            return InputError(message, path=self.tables[part].path, line=2)
        return InputError(f"{_FILE_NAMES.get(part, part)}: {message}")

    def key(self, part: str, key: str | None, message: str) -> InputError:
        sec = self.sections[part]
        return sec.table_error(message) if key is None else sec.error(key, message)

    def name(self, part: str) -> str:
        return _FILE_NAMES.get(part, part)


class _InArguments(_Where):
    """A function's arguments: ``assemble_site: receivers[2].x_m: …``."""

    def __init__(self, function: str, prefix: str = "") -> None:
        self.function, self.prefix = function, prefix

    def _error(self, at: str, message: str) -> InputError:
        return InputError(f"{self.function}: {self.prefix}{at}: {message}")

    def row(self, part: str, i: int, column: str | None, message: str) -> InputError:
        if part == "survey_rows" and column is not None:
            return self._error(f"{part}.{column}[{i}]", message)
        return self._error(f"{part}[{i}]" + (f".{column}" if column else ""), message)

    def whole(self, part: str, message: str) -> InputError:
        return self._error(part, message)

    def key(self, part: str, key: str | None, message: str) -> InputError:
        return self._error(part if key is None else f"{part}.{key}", message)

    def name(self, part: str) -> str:
        return self.prefix + part


# ----------------------------------------------------------------------------- checks
def _safe_pattern_name(name: str) -> bool:
    """A pattern name is a plain file name: ``patterns/<name>.csv`` stays in ``patterns/``."""
    return "/" not in name and "\\" not in name and "\0" not in name and name not in (".", "..")


def _bound(x: float | None, default: str) -> str:
    return default if x is None else f"{x:g}"


def _number_problem(
    v: object, low: float | None = None, high: float | None = None, positive: bool = False
) -> str | None:
    """Why a setting is not a finite number in ``[low, high]`` (``> 0`` if
    ``positive``), in the words of :meth:`Section.number`; ``None`` if it is."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return f"expected a number, got {type(v).__name__} {v!r:.40}"
    x = float(v)
    if not math.isfinite(x):
        return f"expected a finite number, got {v!r:.40}"
    if positive and x <= 0:
        return f"must be > 0, got {x:g}"
    if (low is not None and x < low) or (high is not None and x > high):
        return f"value {x:g} out of range [{_bound(low, '-inf')}, {_bound(high, 'inf')}]"
    return None


def _number(err: ErrorAt, key: str, v: object, **limits: Any) -> float:
    problem = _number_problem(v, **limits)
    if problem is not None:
        raise err(key, problem)
    return float(v)  # type: ignore[arg-type]


def _text_problem(v: object) -> str | None:
    """Why a text field of a site (an id, a pattern name) is not one, as a CSV reads it."""
    if not isinstance(v, str):
        return f"expected text, got {type(v).__name__} {v!r:.40}"
    if not v.strip() or v != v.strip():
        return f"expected non-empty text without surrounding spaces, got {v!r:.40}"
    return None


def _column_problem(col: Column, v: object) -> str | None:
    """Why a value does not fit a contract column (:func:`radiopose.tables.read_table`)."""
    if col.kind == "str":
        return _text_problem(v)
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return f"not a number: {type(v).__name__} {v!r:.40}"
    x = float(v)
    if not math.isfinite(x):
        return f"not a finite number: {x!r}"
    below = col.low is not None and x < col.low
    above = col.high is not None and (x >= col.high if col.high_open else x > col.high)
    if below or above:
        return f"value {x:g} out of range {col.describe_range()}"
    return None


def _axis_steps(err: ErrorAt, axis: str, lo: float, hi: float, step: float) -> int:
    """Steps along one area axis; the span must be a whole number of steps."""
    if hi < lo:
        raise err(f"{axis}_max_m", f"must be >= {axis}_min_m ({lo:g}), got {hi:g}")
    k = (hi - lo) / step  # inf when a subnormal step overflows the division
    if not np.isfinite(k) or k + 1 > MAX_GRID_POINTS:
        raise err(
            "step_m",
            f"{axis} span {hi - lo:g} m / step {step:g} m gives more than "
            f"{MAX_GRID_POINTS:,} candidate positions",
        )
    n, exact = grid_steps(hi - lo, step)
    if not exact:
        raise err(
            "step_m",
            f"the {axis} span {hi - lo:g} m ({axis}_min_m to {axis}_max_m) must be a whole "
            f"number of steps of {step:g} m, got {k:.6g} steps",
        )
    return n


def _check_grid(err: ErrorAt, area: AreaGrid) -> int:
    """The area's spans are whole numbers of steps; returns the number of candidate positions."""
    nx = _axis_steps(err, "x", area.x_min_m, area.x_max_m, area.step_m) + 1
    ny = _axis_steps(err, "y", area.y_min_m, area.y_max_m, area.step_m) + 1
    if nx * ny > MAX_GRID_POINTS:
        raise err("step_m", f"grid of {nx}x{ny} candidates exceeds {MAX_GRID_POINTS:,}")
    return nx * ny


def _check_height_range(err: ErrorAt, z_lo: float, z_hi: float, z_step: float) -> None:
    """A height range: increasing, at most :data:`MAX_HEIGHTS`, whole steps."""
    if z_hi < z_lo:
        raise err("z_max_m", f"must be >= z_min_m ({z_lo:g}), got {z_hi:g}")
    n_steps = (z_hi - z_lo) / z_step
    if not np.isfinite(n_steps) or n_steps + 1 > MAX_HEIGHTS:
        raise err("z_step_m", f"the height range gives more than {MAX_HEIGHTS} heights")
    if not grid_steps(z_hi - z_lo, z_step)[1]:
        raise err(
            "z_step_m",
            f"the height span {z_hi - z_lo:g} m (z_min_m to z_max_m) must be a whole number "
            f"of steps of {z_step:g} m, got {n_steps:.6g} steps",
        )


def _distinct(err: ErrorAt, name: str, values: tuple[float, ...], periodic: bool) -> None:
    """Reject repeated angles (modulo 360 if ``periodic``: roll 180 = roll -180)."""
    seen: dict[float, int] = {}
    for i, v in enumerate(values):
        key = float(wrap_signed_deg(v)) if periodic else v
        key = round(key, 9) + 0.0  # -0.0 == 0.0; float noise below 1e-9 deg
        if periodic and key == 180.0:  # 179.9999999999 rounds up: the same roll as -180
            key = -key
        if key in seen:
            same = "equal modulo 360 to" if periodic else "the same as"
            raise err(name, f"item {i} = {v:g} is {same} item {seen[key]}; values must be distinct")
        seen[key] = i


def _check_azimuth_step(err: ErrorAt, az_step: float) -> None:
    n_az = 360.0 / az_step
    if n_az > MAX_ORIENTATIONS + 0.5:
        raise err(
            "azimuth_step_deg",
            f"{az_step:g} gives {n_az:.4g} azimuths, more than {MAX_ORIENTATIONS:,} candidate "
            f"orientations (the step must be >= {360.0 / MAX_ORIENTATIONS:g})",
        )
    if abs(round(n_az) * az_step - 360.0) > 1e-6:
        raise err("azimuth_step_deg", f"{az_step:g} does not divide 360")


def _check_orientation_count(where: _Where, orient: OrientationGrid, n_positions: int) -> None:
    """At most :data:`MAX_ORIENTATIONS` orientations and :data:`MAX_CANDIDATES` poses."""
    n_p, n_r = len(orient.pitch_deg), len(orient.roll_deg)
    if len(orient) > MAX_ORIENTATIONS:
        raise where.key(
            "orientations",
            None,
            f"{orient.n_azimuth} azimuths x {n_p} pitches x {n_r} rolls = "
            f"{len(orient):,} candidate orientations, more than {MAX_ORIENTATIONS:,}",
        )
    if n_positions * len(orient) > MAX_CANDIDATES:
        raise where.key(
            "orientations",
            None,
            f"{n_positions:,} positions x {len(orient):,} orientations = "
            f"{n_positions * len(orient):.3g} candidate poses, more than {MAX_CANDIDATES:,}; "
            "use a coarser [area] step_m or fewer orientations",
        )


_ANGLE_LISTS = (("pitch_deg", -90.0, 90.0, False), ("roll_deg", -360.0, 360.0, True))
_COORD: dict[str, Any] = {"low": -COORD_LIMIT_M, "high": COORD_LIMIT_M}
_STEP: dict[str, Any] = {"positive": True, "high": 2 * COORD_LIMIT_M}
_TX_POWER = next(c for c in DEVICE_COLUMNS if c.name == "tx_power_dbm")


def _check_area(where: _Where, area: object) -> int:
    """An :class:`AreaGrid` built in Python: the checks of ``site.toml [area]``;
    returns the number of candidate positions."""
    if not isinstance(area, AreaGrid):
        raise where.key("area", None, f"expected an AreaGrid, got {type(area).__name__}")
    err = where.at("area")
    for k in ("x_min_m", "x_max_m", "y_min_m", "y_max_m"):
        _number(err, k, getattr(area, k), **_COORD)
    z_range = (area.z_min_m, area.z_max_m, area.z_step_m)
    _number(err, "z_m", area.z_m, **_COORD)
    if any(v is not None for v in z_range):
        for k, v in zip(_HEIGHT_KEYS, z_range, strict=True):
            if v is None:
                raise err(k, f"missing: a height range needs all of {', '.join(_HEIGHT_KEYS)}")
        z_lo = _number(err, "z_min_m", area.z_min_m, **_COORD)
        z_hi = _number(err, "z_max_m", area.z_max_m, **_COORD)
        z_step = _number(err, "z_step_m", area.z_step_m, **_STEP)
        _check_height_range(err, z_lo, z_hi, z_step)
        mid = height_range_middle_m(z_lo, z_hi, z_step)
        if area.z_m != mid:
            raise err(
                "z_m",
                f"with a height range z_m must be the level nearest its middle, {mid:g}, "
                f"got {area.z_m:g}",
            )
    _number(err, "step_m", area.step_m, **_STEP)
    return _check_grid(err, area)


def _check_orientations(where: _Where, orient: object, n_positions: int) -> None:
    """An :class:`OrientationGrid` built in Python: the checks of ``site.toml [orientations]``."""
    if not isinstance(orient, OrientationGrid):
        raise where.key(
            "orientations", None, f"expected an OrientationGrid, got {type(orient).__name__}"
        )
    err = where.at("orientations")
    _check_azimuth_step(
        err, _number(err, "azimuth_step_deg", orient.azimuth_step_deg, positive=True, high=360.0)
    )
    for name, lo, hi, periodic in _ANGLE_LISTS:
        values = getattr(orient, name)
        if not isinstance(values, tuple | list) or not values:
            raise err(name, f"expected a non-empty list of numbers, got {values!r:.40}")
        for i, v in enumerate(values):
            problem = _number_problem(v, low=lo, high=hi)
            if problem is not None:
                raise err(name, f"item {i}: {problem}")
        _distinct(err, name, tuple(float(v) for v in values), periodic)
    _check_orientation_count(where, orient, n_positions)


def _pattern_name_problem(name: str) -> str | None:
    if not _safe_pattern_name(name):
        return f"pattern name {name!r} is not a plain file name"
    return None


def _check_survey_config(where: _Where, cfg: object) -> None:
    """A :class:`SurveyConfig` built in Python: the checks of ``site.toml [survey]``."""
    if not isinstance(cfg, SurveyConfig):
        raise where.key("survey_config", None, f"expected a SurveyConfig, got {type(cfg).__name__}")
    err = where.at("survey_config")
    _number(err, "tx_power_dbm", cfg.tx_power_dbm, low=_TX_POWER.low, high=_TX_POWER.high)
    problem = _text_problem(cfg.pattern) or _pattern_name_problem(cfg.pattern)
    if problem is not None:
        raise err("pattern", problem)
    for key, choices in (("interpolation", METHODS), ("outside", OUTSIDE_POLICIES)):
        v = getattr(cfg, key)
        if not isinstance(v, str) or v not in choices:
            raise err(key, f"expected one of {', '.join(choices)}, got {v!r:.40}")


def _rows_of(where: _Where, part: str, items: object, kind: type) -> tuple[Any, ...]:
    """``receivers`` or ``devices``: a sequence of ``kind``."""
    if isinstance(items, str | bytes) or not isinstance(items, Sequence):
        raise where.whole(
            part, f"expected a sequence of {kind.__name__}, got {type(items).__name__}"
        )
    for i, item in enumerate(items):
        if not isinstance(item, kind):
            raise where.row(part, i, None, f"expected a {kind.__name__}, got {type(item).__name__}")
    return tuple(items)


def _check_fields(
    where: _Where, part: str, items: tuple[Any, ...], cols: tuple[Column, ...]
) -> None:
    for i, item in enumerate(items):
        for col in cols:
            problem = _column_problem(col, getattr(item, col.name))
            if problem is not None:
                raise where.row(part, i, col.name, problem)


def _survey_arrays(where: _Where, rows: object) -> SurveyRows:
    """``survey_rows`` as arrays of one row each: ``(n, 3)``, ``(n,)``, ``(n,)``, ``(n, 3)``."""
    if not isinstance(rows, SurveyRows):
        raise where.whole("survey_rows", f"expected SurveyRows, got {type(rows).__name__}")
    try:
        xyz = np.asarray(rows.xyz_m, dtype=float)
        rss = np.asarray(rows.rss_dbm, dtype=float)
        ori = np.asarray(rows.orientation_deg, dtype=float)
    except (TypeError, ValueError) as exc:
        raise where.whole("survey_rows", f"not numbers: {exc}") from None
    rid = np.asarray(rows.receiver_id)
    n = xyz.shape[0] if xyz.ndim == 2 else -1
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rid.shape != (n,) or rss.shape != (n,) \
            or ori.shape != (n, 3):  # fmt: skip
        raise where.whole(
            "survey_rows",
            f"shapes xyz_m {xyz.shape}, receiver_id {rid.shape}, rss_dbm {rss.shape}, "
            f"orientation_deg {ori.shape}; expected (n, 3), (n,), (n,), (n, 3)",
        )
    same = all(isinstance(a, np.ndarray) for a in (rows.xyz_m, rows.rss_dbm, rows.orientation_deg))
    if same and isinstance(rows.receiver_id, np.ndarray):
        return rows
    return SurveyRows(xyz, rid, rss, ori)


def _check_survey_values(where: _Where, rows: SurveyRows) -> None:
    """Every survey value finite and in its column's range (``survey.csv``)."""
    arrays = {
        "x_m": rows.xyz_m[:, 0],
        "y_m": rows.xyz_m[:, 1],
        "z_m": rows.xyz_m[:, 2],
        "rss_dbm": rows.rss_dbm,
        "azimuth_deg": rows.orientation_deg[:, 0],
        "pitch_deg": rows.orientation_deg[:, 1],
        "roll_deg": rows.orientation_deg[:, 2],
    }
    for col in SURVEY_COLUMNS:
        if col.kind == "str":
            continue
        a = np.asarray(arrays[col.name], float)
        bad = ~np.isfinite(a)
        with np.errstate(invalid="ignore"):
            if col.low is not None:
                bad |= a < col.low
            if col.high is not None:
                bad |= a >= col.high if col.high_open else a > col.high
        if bad.any():
            i = int(np.argmax(bad))
            raise where.row("survey_rows", i, col.name, _column_problem(col, float(a[i])) or "")


def _percent(fraction: float) -> str:
    """``0.4996`` → ``"49.9%"``: rounded down, so a rejected value never reads as the limit."""
    return f"{math.floor(fraction * 1000) / 10:g}%"


def _check_survey_geometry(where: _Where, rows: SurveyRows, area: AreaGrid) -> None:
    """Each receiver's survey spans an area whose hull covers enough of the grid.

    Raises :class:`InputError` naming survey.csv (the receiver's first row) or,
    when the whole survey misses the area, site.toml's ``[area]``.
    """
    gx, gy = area.x_m(), area.y_m()
    xy = np.unique(np.round(rows.xyz_m[:, :2], 6), axis=0)
    per_rx: list[tuple[str, int, FloatArray]] = []
    for rid in dict.fromkeys(rows.receiver_id):
        sel = rows.receiver_id == rid
        first = int(np.argmax(sel))
        pts = np.unique(np.round(rows.xyz_m[sel, :2], 6), axis=0)
        if not spans_two_dimensions(pts):
            raise where.row(
                "survey_rows",
                first,
                "receiver_id",
                f"receiver {rid!r}: its {len(pts)} surveyed point(s) do not span an area "
                "(need at least 3 points (x_m, y_m) not on one line)",
            )
        per_rx.append((str(rid), first, pts))
    cover = hull_coverage(xy, gx, gy)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if cover < MIN_SURVEY_COVERAGE:
        raise where.key(
            "area",
            None,
            f"only {_percent(cover)} of the candidate positions lie inside the surveyed "
            f"convex hull ({where.name('survey_rows')} spans x {lo[0]:g}..{hi[0]:g} m, "
            f"y {lo[1]:g}..{hi[1]:g} m); at least {_percent(MIN_SURVEY_COVERAGE)} must",
        )
    for rid, first, pts in per_rx:
        cover = hull_coverage(pts, gx, gy)
        if cover < MIN_SURVEY_COVERAGE:
            raise where.row(
                "survey_rows",
                first,
                "receiver_id",
                f"receiver {rid!r}: only {_percent(cover)} of the candidate positions "
                f"({where.name('area')}) lie inside the convex hull of its survey points; "
                f"at least {_percent(MIN_SURVEY_COVERAGE)} must",
            )


def _check_site(where: _Where, parts: _SiteParts, settings_checked: bool = False) -> _SiteParts:
    """The checks of a site's contents, wherever it came from (one set for
    :func:`load_site`, :func:`assemble_site` and :func:`write_site`).

    ``settings_checked``: the area, orientations and survey settings were checked
    as they were read (``site.toml``, in the order of its keys). Returns the parts
    with the survey rows as arrays.

    Raises
    ------
    InputError
        The first problem, located by ``where``.
    """
    if not settings_checked:
        if not isinstance(parts.name, str):
            raise where.whole("name", f"expected text, got {type(parts.name).__name__}")
        n_positions = _check_area(where, parts.area)
        _check_orientations(where, parts.orientations, n_positions)
        _check_survey_config(where, parts.survey_config)
    receivers = _rows_of(where, "receivers", parts.receivers, Receiver)
    if not receivers:
        raise where.whole("receivers", "no receivers")
    _check_fields(where, "receivers", receivers, RECEIVER_COLUMNS)
    ids: dict[str, int] = {}
    for i, r in enumerate(receivers):
        problem = receiver_id_problem(r.receiver_id)
        if problem is not None:
            raise where.row("receivers", i, "receiver_id", problem)
        if r.receiver_id in ids:
            raise where.row(
                "receivers", i, "receiver_id", f"duplicate receiver id {r.receiver_id!r}"
            )
        ids[r.receiver_id] = i

    devices = _rows_of(where, "devices", parts.devices, Device)
    _check_fields(where, "devices", devices, DEVICE_COLUMNS)
    seen_tx: set[str] = set()
    for i, d in enumerate(devices):
        problem = transmitter_id_problem(d.transmitter)
        if problem is not None:
            raise where.row("devices", i, "transmitter", problem)
        if d.transmitter.lower() in seen_tx:
            raise where.row("devices", i, "transmitter", f"duplicate transmitter {d.transmitter!r}")
        seen_tx.add(d.transmitter.lower())

    # Patterns: plain file names (write_site writes patterns/<name>.csv), every one named present.
    patterns = parts.patterns
    if not isinstance(patterns, Mapping):
        raise where.whole("patterns", f"expected a mapping, got {type(patterns).__name__}")
    for pname, pat in patterns.items():
        problem = _text_problem(pname) or _pattern_name_problem(pname)
        if problem is not None:
            raise where.whole("patterns", problem)
        if not isinstance(pat, Pattern):
            raise where.whole(
                "patterns", f"{pname!r}: expected a Pattern, got {type(pat).__name__}"
            )

    def missing(name: str) -> str | None:
        if name in patterns:
            return None
        return _pattern_name_problem(name) or (
            f"unknown pattern {name!r} (not in {where.name('patterns')})"
        )

    for part, items in (("receivers", receivers), ("devices", devices)):
        for i, item in enumerate(items):
            problem = missing(item.pattern)
            if problem is not None:
                raise where.row(part, i, "pattern", problem)
    problem = missing(parts.survey_config.pattern)
    if problem is not None:
        raise where.key("survey_config", "pattern", problem)

    rows = _survey_arrays(where, parts.survey_rows)
    if rows.xyz_m.shape[0] == 0:
        raise where.whole("survey_rows", "no survey rows")
    _check_survey_values(where, rows)
    first_row: dict[Any, int] = {}
    for i, rid in enumerate(rows.receiver_id.tolist()):
        if rid not in first_row:
            first_row[rid] = i
            if rid not in ids:
                raise where.row(
                    "survey_rows",
                    i,
                    "receiver_id",
                    f"unknown receiver {rid!r} (not in {where.name('receivers')})",
                )
    for i, r in enumerate(receivers):
        if r.receiver_id not in first_row:
            raise where.row(
                "receivers",
                i,
                "receiver_id",
                f"receiver {r.receiver_id!r} has no survey rows in {where.name('survey_rows')}",
            )
    if parts_are_3d(parts.area, parts.orientations):
        gap = missing_survey_height(rows, tuple(ids), SURVEY_HEIGHT_DECIMALS)
        if gap is not None:
            h, rid, row = gap
            raise where.row(
                "survey_rows",
                row,
                "z_m",
                f"receiver {rid!r} has no survey rows at the surveyed height {h:g} m "
                "(z_m rounded to 1 mm); a 3-D site's survey needs rows for every receiver "
                "at every surveyed height",
            )
    _check_survey_geometry(where, rows, parts.area)
    return _SiteParts(
        parts.name,
        parts.area,
        parts.orientations,
        parts.survey_config,
        receivers,
        devices,
        patterns,
        rows,
    )


# ----------------------------------------------------------------------------- reading
_HEIGHT_KEYS = ("z_min_m", "z_max_m", "z_step_m")
_AREA_KEYS = ("x_min_m", "x_max_m", "y_min_m", "y_max_m", "z_m", *_HEIGHT_KEYS, "step_m")
"""Every key ``[area]`` may hold."""


def _read_heights(a: Section) -> tuple[float, tuple[float | None, float | None, float | None]]:
    """``[area]`` heights: ``z_m`` alone (2-D) or ``z_min_m``/``z_max_m``/``z_step_m``
    (3-D); returns ``(z_m, (z_min_m, z_max_m, z_step_m))`` (``None`` s without a range)."""
    given = [k for k in _HEIGHT_KEYS if a.has(k)]
    if not given:
        return a.number("z_m", required=True, **_COORD), (None, None, None)
    if a.has("z_m"):
        raise a.error(
            given[0],
            "give either z_m (one candidate height) or z_min_m, z_max_m, z_step_m, not both",
        )
    for k in _HEIGHT_KEYS:
        if k not in given:
            raise a.error(k, f"missing: a height range needs all of {', '.join(_HEIGHT_KEYS)}")
    z_lo = a.number("z_min_m", required=True, **_COORD)
    z_hi = a.number("z_max_m", required=True, **_COORD)
    z_step = a.number("z_step_m", required=True, **_STEP)
    _check_height_range(a.error, z_lo, z_hi, z_step)
    return height_range_middle_m(z_lo, z_hi, z_step), (z_lo, z_hi, z_step)


def _read_site_toml(path: Path) -> _SiteToml:
    root = Section(load_toml(path), path)
    name = root.string("name", path.parent.name)
    a = root.section("area")
    a.reject_unknown(_AREA_KEYS)  # a misspelt key at its line, not as a missing one
    x_min = a.number("x_min_m", required=True, **_COORD)
    x_max = a.number("x_max_m", required=True, **_COORD)
    y_min = a.number("y_min_m", required=True, **_COORD)
    y_max = a.number("y_max_m", required=True, **_COORD)
    z, z_range = _read_heights(a)
    step = a.number("step_m", required=True, **_STEP)
    area = AreaGrid(x_min, x_max, y_min, y_max, z, step, *z_range)
    n_positions = _check_grid(a.error, area)
    a.finish()

    o = root.section("orientations")
    az_step = o.number("azimuth_step_deg", 1.0, positive=True, high=360.0)
    _check_azimuth_step(o.error, az_step)
    pitch = o.numbers("pitch_deg", (0.0,), low=-90.0, high=90.0, scalar=False)
    _distinct(o.error, "pitch_deg", pitch, periodic=False)
    roll = o.numbers("roll_deg", (0.0,), low=-360.0, high=360.0, scalar=False)
    _distinct(o.error, "roll_deg", roll, periodic=True)
    orient = OrientationGrid(az_step, pitch, roll)
    _check_orientation_count(_InFiles({"orientations": o}, {}), orient, n_positions)
    o.finish()

    s = root.section("survey")
    survey = SurveyConfig(
        tx_power_dbm=s.number(
            "tx_power_dbm", required=True, low=_TX_POWER.low, high=_TX_POWER.high
        ),
        pattern=s.string("pattern", required=True),
        interpolation=s.string("interpolation", "cubic", choices=METHODS),
        outside=s.string("outside", "nearest", choices=OUTSIDE_POLICIES),
    )
    problem = _pattern_name_problem(survey.pattern)
    if problem is not None:
        raise s.error("pattern", problem)
    s.finish()
    root.finish()
    return _SiteToml(name, area, orient, survey, a, o, s)


def _check_directory(function: str, directory: object) -> Path:
    if not isinstance(directory, str | os.PathLike):
        raise InputError(
            f"{function}: the site directory must be a path, got "
            f"{type(directory).__name__} {directory!r:.40}"
        )
    return Path(directory)


def load_site(directory: str | os.PathLike[str]) -> Site:
    """Load and validate a site directory; build its survey map.

    The checks (``docs/site.md``) are those of :func:`assemble_site`, located
    in the files; a 3-D site (a height range, or several pitches or rolls) also
    needs survey rows for every receiver at every surveyed height.

    Raises
    ------
    InputError
        One line naming the file (and line/column or key) of the first problem.
    """
    root = _check_directory("load_site", directory)
    if not root.is_dir():
        raise InputError("site directory not found", path=root)
    toml = _read_site_toml(root / "site.toml")

    rt = read_table(root / "receivers.csv", RECEIVER_COLUMNS)
    check_receiver_ids(rt)
    receivers = tuple(
        Receiver(  # type: ignore[misc]  # mypy cannot count a generator's star-args
            str(rt["receiver_id"][i]),
            *(  # type: ignore[arg-type]
                float(rt[c][i])
                for c in ("x_m", "y_m", "z_m", "azimuth_deg", "pitch_deg", "roll_deg")
            ),
            pattern=str(rt["pattern"][i]),
        )
        for i in range(len(rt))
    )

    dt = read_table(root / "devices.csv", DEVICE_COLUMNS)
    check_transmitter_ids(dt)
    devices = tuple(
        Device(str(dt["transmitter"][i]), str(dt["pattern"][i]), float(dt["tx_power_dbm"][i]))
        for i in range(len(dt))
    )

    # Patterns: every referenced name must exist as patterns/<name>.csv.
    wanted: dict[str, InputError] = {}
    for i, r in enumerate(receivers):
        wanted.setdefault(r.pattern, rt.error(i, "pattern", ""))
    for i, d in enumerate(devices):
        wanted.setdefault(d.pattern, dt.error(i, "pattern", ""))
    wanted.setdefault(toml.survey.pattern, toml.survey_section.error("pattern", ""))
    patterns: dict[str, Pattern] = {}
    for pname, where in wanted.items():
        ppath = root / "patterns" / f"{pname}.csv"
        problem = _pattern_name_problem(pname)
        if problem is None and not ppath.is_file():
            problem = f"unknown pattern {pname!r}: no file patterns/{pname}.csv"
        if problem is None:
            patterns[pname] = read_pattern_csv(ppath, name=pname)
            continue
        raise InputError(problem, path=where.path, line=where.line, column=where.column)

    st = read_table(root / "survey.csv", SURVEY_COLUMNS)
    rows = SurveyRows(
        xyz_m=np.column_stack([st["x_m"], st["y_m"], st["z_m"]]).reshape(-1, 3),
        receiver_id=st["receiver_id"],
        rss_dbm=st["rss_dbm"],
        orientation_deg=np.column_stack(
            [st["azimuth_deg"], st["pitch_deg"], st["roll_deg"]]
        ).reshape(-1, 3),
    )
    files = _InFiles(
        {"area": toml.area_section, "orientations": toml.orientations_section,
         "survey_config": toml.survey_section},
        {"receivers": rt, "devices": dt, "survey_rows": st},
    )  # fmt: skip
    parts = _SiteParts(
        toml.name, toml.area, toml.orientations, toml.survey, receivers, devices, patterns, rows
    )
    return _build_site(_check_site(files, parts, settings_checked=True), path=str(root))


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
    """Build a :class:`Site` from parts in memory: check them, correct and interpolate the survey.

    The checks are :func:`load_site`'s (one function, ``_check_site``): the
    ``site.toml`` rules on ``area``, ``orientations`` and ``survey_config``,
    the column ranges of the CSV files on each receiver, device and survey
    row, unique receiver ids and transmitters, plain pattern names present in
    ``patterns``, survey rows naming known receivers and every receiver
    surveyed (at every surveyed height on a 3-D site), and the survey
    coverage (``docs/site.md``).

    Raises
    ------
    InputError
        One line naming the argument and the receiver, row or key of the first
        problem (``assemble_site: survey_rows.rss_dbm[4]: not a finite number: nan``).
    """
    parts = _SiteParts(
        name, area, orientations, survey_config, receivers, devices, patterns, survey_rows
    )
    return _build_site(_check_site(_InArguments("assemble_site"), parts), path=path)


def _build_site(parts: _SiteParts, path: str | None) -> Site:
    """A :class:`Site` of checked parts: correct and interpolate the survey."""
    receivers, rows, cfg = parts.receivers, parts.survey_rows, parts.survey_config
    m_db = correct_survey(rows, cfg.tx_power_dbm, parts.patterns[cfg.pattern], receivers)
    ids = tuple(r.receiver_id for r in receivers)
    points = survey_points_by_receiver(rows, m_db, ids)
    smap = build_survey_map(
        ids,
        points,
        parts.area.x_m(),
        parts.area.y_m(),
        cfg.interpolation,  # type: ignore[arg-type]
        cfg.outside,  # type: ignore[arg-type]
    )
    return Site(
        parts.name,
        parts.area,
        parts.orientations,
        cfg,
        receivers,
        parts.devices,
        dict(parts.patterns),
        rows,
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
    """Write a site directory in the contract layout (each file atomically).

    Raises
    ------
    InputError
        Before anything is written: ``site`` is one :func:`load_site` would
        refuse (the checks of :func:`assemble_site`; a pattern name that is
        not a plain file name would write outside ``patterns/``).
    """
    root = _check_directory("write_site", directory)
    if not isinstance(site, Site):
        raise InputError(f"write_site: expected a Site, got {type(site).__name__}")
    _check_site(
        _InArguments("write_site", "site."),
        _SiteParts(
            site.name, site.area, site.orientations, site.survey_config, site.receivers,
            site.devices, site.patterns, site.survey_rows,
        ),
    )  # fmt: skip
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
