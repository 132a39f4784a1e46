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
already in memory with the same checks; :func:`write_site` writes one
(atomically, file by file). Split from :mod:`radiopose.site` so that the value
objects and their geometry read apart from the file formats; the old names
stay importable from there.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.config import Section, load_toml
from radiopose.errors import InputError
from radiopose.ids import check_transmitter_ids
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
    survey_points_by_receiver,
)
from radiopose.survey import (
    build_survey_map,
    hull_coverage,
    spans_two_dimensions,
)
from radiopose.tables import Table, atomic_writer, read_table, write_table
from radiopose.units import FloatArray, wrap_signed_deg


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
            f"of steps of {z_step:g} m, got {n_steps:.6g} steps",
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
    check_transmitter_ids(dt)
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
