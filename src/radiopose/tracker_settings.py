"""Optional per-site tracker settings: ``SITE/tracker.toml``.

A site may carry the noise and motion priors that suit it (a real site's RSS
noise and a walking person's motion differ from the simulator's). The file is
optional; ``radiopose locate`` reads it when present and says so. Format::

    smoothing_lag_s = 10.0      # the filter's fixed lag in batch runs (optional)
    live_method = "filter"      # the live server's method at this site (optional)

    [filter]                    # any field of radiopose.filtering.FilterConfig
    huber_c = 1.0
    sigma_prior_db = 5.0
    offset_scan_db = [3.0, -3.0]  # list fields are arrays ([] allowed where it switches off)

    [filter.pose3d]             # the 3-D filter (a site with a height range or
    n_particles = 3000          # several pitches/rolls): any field of
    acquisition_step_m = 2.0    # radiopose.filtering.particle3d.Pose3dConfig

Every key is checked: an unknown key, a value of the wrong type, a non-finite
number or a value out of range is a one-line error naming the file, line and
key. ``[filter.pose3d]`` is read at every site but used only at a 3-D one
(docs/pose3d.md, "Settings").
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from radiopose.config import Section, find_key_line, load_toml
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.config import MAX_LAG_S, MIN_REENTRY_INTERVAL_S, SMOOTHERS
from radiopose.filtering.particle import LIKELIHOODS
from radiopose.filtering.particle3d import ESTIMATES as POSE3D_ESTIMATES
from radiopose.filtering.particle3d import MAX_COARSE_PATHS, Pose3dConfig

if TYPE_CHECKING:  # the tracker package loads the registry: imported only when asked
    from radiopose.tracker.config import TrackerConfig

FILE_NAME = "tracker.toml"

FilterOverrides = dict[str, Any]
"""``FilterConfig`` field name -> int, float, str or bool value. The keys are checked against the
fields at run time, so the values are typed ``Any`` for ``dataclasses.replace(**overrides)``."""


_STRING_CHOICES: dict[str, tuple[str, ...]] = {"likelihood": LIKELIHOODS, "smoother": SMOOTHERS}
"""The values a string field of FilterConfig may take."""

FILTER_ZERO_ALLOWED_INTS = frozenset({"offset_scans_per_reentry", "difference_memory"})
"""Integer ``[filter]`` keys for which 0 is a value (it switches the part off)."""

FILTER_EMPTY_ALLOWED_LISTS = frozenset(
    {"offset_scan_db", "offset_selection_grid_db", "live_resolve_times_s"}
)
"""List-valued ``[filter]`` keys that may be empty (``[]`` switches the part off)."""


FILTER_LIST_RANGES: dict[str, tuple[float, float]] = {"live_resolve_times_s": (0.0, MAX_LAG_S)}
"""List-valued ``[filter]`` keys that are not dB offsets (±60 dB): their items'
range, in their own units (seconds here; ``FilterConfig`` refuses 0 itself)."""


POSE3D_TABLE = "pose3d"
"""The sub-table of ``[filter]`` holding :class:`Pose3dConfig` fields (``[filter.pose3d]``)."""

POSE3D_RANGES: dict[str, tuple[float, float]] = {
    "n_particles": (10, 1_000_000),
    "angular_accel_noise_dps2": (0.0, 100_000.0),
    "height_noise_mps": (0.0, 10.0),
    "tilt_noise_dps": (0.0, 3600.0),
    "acquisition_step_m": (0.0, 100.0),
    "acquisition_azimuth_step_deg": (0.0, 360.0),
    "acquisition_heights": (1, 1000),
    "acquisition_sigma_db": (0.0, 60.0),
    "acquisition_k": (1, 10_000_000),
    "acquisition_tilts": (1, 1000),
    "reentry_interval_s": (MIN_REENTRY_INTERVAL_S, 3600.0),
    "proposal_window_s": (0.0, 3600.0),
    "sigma_floor_db": (0.0, 60.0),
    "refine_steps": (0, 100),
    "max_table_entries": (1000, 1_000_000_000),
    "heading_prior_deg": (0.0, 180.0),
    "refine_heading_deg": (0.0, 180.0),
    "refine_escalate_ratio": (0.0, 1000.0),
    "refine_escalate_restarts": (1, 100),
    "mode_radius_deg": (0.0, 180.0),
    "offset_bank_db": (-60.0, 60.0),
    "refine_max_nfev": (1, 100_000),
    "refine_hybrid_segment_s": (0.0, 3600.0),
    "refine_height_accel_noise_mps2": (0.0, 1000.0),
    "refine_tilt_accel_noise_dps2": (0.0, 100_000.0),
    "refine_polish_starts": (0, 1000),
    "refine_polish_margin": (0.0, 1e9),
    "refine_polish_switch": (0.0, 1e9),
    "refine_restarts": (0, 100),
    "refine_coarse_paths": (1, MAX_COARSE_PATHS),
    "offline_n_particles": (0, 1_000_000),
}
"""Accepted range of each ``[filter.pose3d]`` key: ``[low, high]`` for an integer field,
``(low, high]`` for a real one (every real setting of the 3-D filter is a positive
density, step, σ or interval). A field without a row here (one added to
:class:`Pose3dConfig` later) is read as a positive number of its type, and the
dataclass's own checks apply to every value."""


POSE3D_ZERO_ALLOWED = frozenset(
    {
        "heading_prior_deg",
        "refine_heading_deg",
        "refine_escalate_ratio",
        "refine_hybrid_segment_s",
        "refine_height_accel_noise_mps2",
        "refine_tilt_accel_noise_dps2",
        "refine_polish_margin",
        "refine_polish_switch",
    }
)
"""Real ``[filter.pose3d]`` keys for which 0 is a value (it switches the part off)."""

_POSE3D_STRING_CHOICES: dict[str, tuple[str, ...]] = {"estimate": POSE3D_ESTIMATES}


def _filter_fields() -> dict[str, type]:
    # an optional number (``float | None``, default None) is read as a number
    return {
        f.name: float if str(f.type) == "float | None" else type(f.default)
        for f in dataclasses.fields(FilterConfig)
    }


def _pose3d_fields() -> dict[str, type]:
    return {f.name: type(f.default) for f in dataclasses.fields(Pose3dConfig)}


@dataclasses.dataclass(frozen=True)
class TrackerSettings:
    """What a ``tracker.toml`` sets (every value checked; see the module docstring).

    Attributes
    ----------
    filter_overrides
        ``[filter]``: :class:`FilterConfig` field -> value.
    pose3d_overrides
        ``[filter.pose3d]``: :class:`Pose3dConfig` field -> value.
    smoothing_lag_s
        The filter's fixed lag in batch runs, seconds (``None``: not set).
    live_method
        The live server's method at this site (``None``: not set).
    """

    filter_overrides: FilterOverrides = dataclasses.field(default_factory=dict)
    pose3d_overrides: FilterOverrides = dataclasses.field(default_factory=dict)
    smoothing_lag_s: float | None = None
    live_method: str | None = None

    def pose3d(self) -> Pose3dConfig:
        """The 3-D filter's settings: the defaults with ``[filter.pose3d]`` applied."""
        return dataclasses.replace(Pose3dConfig(), **self.pose3d_overrides)


def read_tracker_settings(path: str | os.PathLike[str]) -> TrackerSettings:
    """Every setting of a ``tracker.toml`` (:class:`TrackerSettings`).

    Raises
    ------
    InputError
        Syntax errors, unknown keys, values of the wrong type, non-finite or
        out-of-range values, values FilterConfig or Pose3dConfig rejects
        (file, line and key named).
    """
    doc = load_toml(path)
    root = Section(doc, path)
    lag = root.number("smoothing_lag_s", None, low=0.0, high=MAX_LAG_S)
    live = _live_method(root)
    sec = root.section("filter", required=False)
    kinds = _filter_fields()
    overrides: FilterOverrides = {}
    pose3d: FilterOverrides = {}
    for key in list(sec.data):
        kind = kinds.get(key)
        if kind is int:
            low = 0 if key in FILTER_ZERO_ALLOWED_INTS else 1
            overrides[key] = sec.integer(key, low=low, high=10_000_000)
        elif kind is float:
            overrides[key] = sec.number(key, low=-1e6, high=1e6)
        elif kind is tuple:  # offsets in dB from devices.csv's power (or times)
            empty_ok = key in FILTER_EMPTY_ALLOWED_LISTS
            lo, hi = FILTER_LIST_RANGES.get(key, (-60.0, 60.0))
            overrides[key] = sec.numbers(key, low=lo, high=hi, nonempty=not empty_ok, scalar=False)
        elif kind is bool:
            overrides[key] = sec.boolean(key)
        elif kind is str:
            overrides[key] = sec.string(key, choices=_STRING_CHOICES.get(key))
        elif key == POSE3D_TABLE:
            pose3d = _read_pose3d(sec.section(POSE3D_TABLE))
    top_level = ("smoothing_lag_s", "live_method")  # the keys above [filter]
    sec.finish(
        allowed=[*kinds, POSE3D_TABLE],
        elsewhere={k: "the top level, above [filter]" for k in top_level},
    )
    root.finish(allowed=(*top_level, "filter"))
    for table, cls, given in (
        (("filter",), FilterConfig, overrides),
        (("filter", POSE3D_TABLE), Pose3dConfig, pose3d),
    ):
        try:
            dataclasses.replace(cls(), **given)
        except InputError as exc:  # the dataclass names the field; add the file and its line
            bad = next((k for k in given if f" {k} " in f" {exc.reason} "), None)
            keys = table if bad is None else (*table, bad)
            line = find_key_line(keys, doc.key_lines)
            raise InputError(exc.reason, path=path, line=line, column=".".join(keys)) from None
    return TrackerSettings(overrides, pose3d, lag, live)


def _read_pose3d(sec: Section) -> FilterOverrides:
    """The keys of ``[filter.pose3d]``, each typed and range-checked (:data:`POSE3D_RANGES`)."""
    out: FilterOverrides = {}
    kinds = _pose3d_fields()
    for key in list(sec.data):
        kind = kinds.get(key)
        if kind is int:
            lo, hi = POSE3D_RANGES.get(key, (1, 10**9))
            out[key] = sec.integer(key, low=int(lo), high=int(hi))
        elif kind is float:
            lo, hi = POSE3D_RANGES.get(key, (0.0, 1e6))
            zero_ok = key in POSE3D_ZERO_ALLOWED
            out[key] = sec.number(key, positive=lo == 0.0 and not zero_ok, low=lo, high=hi)
        elif kind is bool:
            out[key] = sec.boolean(key)
        elif kind is str:
            out[key] = sec.string(key, choices=_POSE3D_STRING_CHOICES.get(key))
        elif kind is tuple:
            lo, hi = POSE3D_RANGES.get(key, (-1e6, 1e6))
            out[key] = sec.numbers(key, low=lo, high=hi, nonempty=False, scalar=False)
    sec.finish(allowed=kinds)
    return out


def read_tracker_toml(
    path: str | os.PathLike[str],
) -> tuple[FilterOverrides, float | None]:
    """``(filter overrides, smoothing_lag_s or None)`` from a ``tracker.toml``
    (:func:`read_tracker_settings` has the rest: ``[filter.pose3d]``, ``live_method``).

    Raises
    ------
    InputError
        As :func:`read_tracker_settings`.
    """
    s = read_tracker_settings(path)
    return s.filter_overrides, s.smoothing_lag_s


def _live_method(root: Section) -> str | None:
    from radiopose.tracker import METHODS  # the registry (heavy: loaded only when asked)

    if "live_method" not in root.data:
        return None
    return root.string("live_method", None, choices=tuple(METHODS))


def load_site_live_method(site_dir: str | os.PathLike[str]) -> str | None:
    """The ``live_method`` of ``SITE/tracker.toml`` (``None``: no file or no key).

    Raises
    ------
    InputError
        A method the registry does not know (file, line and key named).
    """
    p = Path(site_dir) / FILE_NAME
    if not p.is_file():
        return None
    return _live_method(Section(load_toml(p), p))


def load_site_settings(
    site_dir: str | os.PathLike[str],
) -> tuple[TrackerSettings, Path | None]:
    """Every setting of ``SITE/tracker.toml`` and its path (empty settings and ``None``
    if there is none)."""
    p = Path(site_dir) / FILE_NAME
    if not p.exists():
        return TrackerSettings(), None
    if not p.is_file():  # a directory (or worse) named like the settings: not ignored
        raise InputError("is not a file (a site's tracker settings are a TOML file)", path=p)
    return read_tracker_settings(p), p


def apply_tracker_settings(
    config: TrackerConfig, settings: TrackerSettings, *, batch: bool = True
) -> TrackerConfig:
    """``config`` with a site's settings applied: ``[filter]`` and ``[filter.pose3d]``
    over its own, and (``batch``: offline :func:`~radiopose.tracker.locate`) the
    fixed lag ``smoothing_lag_s`` when set."""
    lag = settings.smoothing_lag_s
    return dataclasses.replace(
        config,
        filter=dataclasses.replace(config.filter, **settings.filter_overrides),
        pose3d=dataclasses.replace(config.pose3d, **settings.pose3d_overrides),
        smoothing_lag_s=lag if batch and lag is not None else config.smoothing_lag_s,
    )


def load_site_tracker_settings(
    site_dir: str | os.PathLike[str],
) -> tuple[FilterOverrides, float | None, Path | None]:
    """The overrides of ``SITE/tracker.toml`` (empty, None, None if there is none)."""
    p = Path(site_dir) / FILE_NAME
    if not p.is_file():
        return {}, None, None
    overrides, lag = read_tracker_toml(p)
    return overrides, lag, p


def write_tracker_toml(
    path: str | os.PathLike[str],
    overrides: Mapping[str, float | int | str | bool | tuple[float, ...]],
    smoothing_lag_s: float | None = None,
    comment: str = "",
    pose3d: Mapping[str, float | int | str | bool | tuple[float, ...]] | None = None,
) -> None:
    """Write a ``tracker.toml``: ``overrides`` (FilterConfig fields) under ``[filter]``,
    ``pose3d`` (Pose3dConfig fields) under ``[filter.pose3d]``; read back by
    :func:`read_tracker_settings` as given (round trip tested)."""
    lines = [f"# {comment}"] if comment else []
    if smoothing_lag_s is not None:
        lines.append(f"smoothing_lag_s = {float(smoothing_lag_s)!r}")
    lines.append("")
    lines.append("[filter]")
    lines += _toml_lines(overrides, _filter_fields(), "FilterConfig")
    if pose3d:
        lines += ["", f"[filter.{POSE3D_TABLE}]"]
        lines += _toml_lines(pose3d, _pose3d_fields(), "Pose3dConfig")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _toml_lines(
    values: Mapping[str, float | int | str | bool | tuple[float, ...]],
    kinds: Mapping[str, type],
    owner: str,
) -> list[str]:
    """``key = value`` lines of ``values`` (fields of ``owner``, typed by ``kinds``)."""
    lines = []
    for key, value in values.items():
        if key not in kinds:
            raise ValueError(f"{key!r} is not a {owner} field")
        if value is None:  # an optional number at its default: the key left out
            continue
        if kinds[key] is bool:
            lines.append(f"{key} = {'true' if value else 'false'}")
            continue
        if kinds[key] is str:
            lines.append(f'{key} = "{value}"')
            continue
        if isinstance(value, tuple):
            items = [float(x) for x in value]
            if not all(math.isfinite(x) for x in items):
                raise ValueError(f"{key} = {value!r} is not finite")
            lines.append(f"{key} = [{', '.join(repr(x) for x in items)}]")
            continue
        v = int(value) if kinds[key] is int else float(value)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{key} = {v!r} is not finite")
        lines.append(f"{key} = {v!r}")
    return lines
