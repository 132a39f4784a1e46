"""Optional per-site tracker settings: ``SITE/tracker.toml``.

A site may carry the noise and motion priors that suit it (a real site's RSS
noise and a walking person's motion differ from the simulator's). The file is
optional; ``radiopose locate`` reads it when present and says so. Format::

    smoothing_lag_s = 10.0      # the filter's fixed lag in batch runs (optional)
    live_method = "filter"      # the live server's method at this site (optional)

    [filter]                    # any field of radiopose.filtering.FilterConfig
    huber_c = 1.0
    sigma_prior_db = 5.0

Every key is checked: an unknown key or a value out of range is a one-line
error naming the file, line and key.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from radiopose.config import Section, load_toml
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.config import SMOOTHERS
from radiopose.filtering.particle import LIKELIHOODS

FILE_NAME = "tracker.toml"

FilterOverrides = dict[str, Any]
"""``FilterConfig`` field name -> int, float, str or bool value. The keys are checked against the
fields at run time, so the values are typed ``Any`` for ``dataclasses.replace(**overrides)``."""


_STRING_CHOICES: dict[str, tuple[str, ...]] = {"likelihood": LIKELIHOODS, "smoother": SMOOTHERS}
"""The values a string field of FilterConfig may take."""


def _filter_fields() -> dict[str, type]:
    return {f.name: type(f.default) for f in dataclasses.fields(FilterConfig)}


def read_tracker_toml(
    path: str | os.PathLike[str],
) -> tuple[FilterOverrides, float | None]:
    """``(filter overrides, smoothing_lag_s or None)`` from a ``tracker.toml``.

    Raises
    ------
    InputError
        Syntax errors, unknown keys, non-numbers, values FilterConfig rejects.
    """
    doc = load_toml(path)
    root = Section(doc, path)
    lag = root.number("smoothing_lag_s", None, low=0.0, high=3600.0)
    _live_method(root)
    sec = root.section("filter", required=False)
    kinds = _filter_fields()
    overrides: FilterOverrides = {}
    for key in list(sec.data):
        kind = kinds.get(key)
        if kind is int:
            overrides[key] = sec.integer(key, low=1, high=10_000_000)
        elif kind is float:
            overrides[key] = sec.number(key, low=-1e6, high=1e6)
        elif kind is bool:
            overrides[key] = sec.boolean(key)
        elif kind is str:
            overrides[key] = sec.string(key, choices=_STRING_CHOICES.get(key))
    sec.finish()
    root.finish()
    try:
        dataclasses.replace(FilterConfig(), **overrides)
    except InputError as exc:  # the dataclass names the field; add the file
        raise InputError(exc.reason, path=path, column="filter") from None
    return overrides, lag


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
    overrides: Mapping[str, float | int | str | bool],
    smoothing_lag_s: float | None = None,
    comment: str = "",
) -> None:
    """Write a ``tracker.toml`` (values must be FilterConfig fields)."""
    kinds = _filter_fields()
    lines = [f"# {comment}"] if comment else []
    if smoothing_lag_s is not None:
        lines.append(f"smoothing_lag_s = {float(smoothing_lag_s)!r}")
    lines.append("")
    lines.append("[filter]")
    for key, value in overrides.items():
        if key not in kinds:
            raise ValueError(f"{key!r} is not a FilterConfig field")
        if kinds[key] is bool:
            lines.append(f"{key} = {'true' if value else 'false'}")
            continue
        if kinds[key] is str:
            lines.append(f'{key} = "{value}"')
            continue
        v = int(value) if kinds[key] is int else float(value)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{key} = {v!r} is not finite")
        lines.append(f"{key} = {v!r}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
