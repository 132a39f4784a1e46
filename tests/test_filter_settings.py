"""``[filter]`` of a site's ``tracker.toml``: every :class:`FilterConfig` field is
readable with its type, including the list-valued ones, and 0 where 0 switches a
part off (docs/filter.md, "Settings").

* the offset lists (``initial_offsets_db``, ``offset_scan_db``) read as tuples;
  ``offset_scan_db = []`` switches the scan off, an empty ``initial_offsets_db``
  is a one-line error (the first packet needs an offset to search at);
* ``offset_scans_per_reentry = 0`` and ``difference_memory = 0`` are accepted
  (the dataclass allows them);
* every FilterConfig field written by :func:`write_tracker_toml` reads back as
  written (hypothesis over the list fields);
* a bare number where a list is expected, a non-finite item or an unknown key is
  one line naming the file, the line and the dotted key.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.tracker_settings import _filter_fields, read_tracker_settings, write_tracker_toml

FIELDS = _filter_fields()  # the reader's type of each FilterConfig field


def _write(tmp: Path, body: str) -> Path:
    p = tmp / "tracker.toml"
    p.write_text(body, encoding="utf-8")
    return p


def test_every_field_has_a_reader():
    """No FilterConfig field is of a type the reader cannot read (it would be an
    'unknown key', which is what the list fields were before; an optional number,
    ``float | None``, is read as a number)."""
    assert set(FIELDS) == {f.name for f in dataclasses.fields(FilterConfig)}
    assert set(FIELDS.values()) <= {int, float, bool, str, tuple}
    assert FIELDS["live_resolve_max_sigma_db"] is float


def test_offset_lists_read_as_tuples(tmp_path: Path):
    p = _write(
        tmp_path,
        "[filter]\ninitial_offsets_db = [-3, 0, 3.5]\noffset_scan_db = []\n"
        "offset_scans_per_reentry = 0\ndifference_memory = 0\n",
    )
    o = read_tracker_settings(p).filter_overrides
    assert o == {
        "initial_offsets_db": (-3.0, 0.0, 3.5),
        "offset_scan_db": (),
        "offset_scans_per_reentry": 0,
        "difference_memory": 0,
    }
    cfg = dataclasses.replace(FilterConfig(), **o)
    assert cfg.initial_offsets_db == (-3.0, 0.0, 3.5) and cfg.offset_scan_db == ()


BAD = [
    ("initial_offsets_db = []", "initial_offsets_db", "non-empty list"),
    ("initial_offsets_db = 3.0", "initial_offsets_db", "single number"),
    # a list that may be empty: the message does not ask for a non-empty one
    (
        'live_resolve_times_s = "x"',
        "live_resolve_times_s",
        "expected a list of numbers ([] allowed), got 'x'",
    ),
    (
        "offset_scan_db = 3.0",
        "offset_scan_db",
        "expected a list of numbers ([] allowed), got a single number (write [3.0])",
    ),
    (
        'initial_offsets_db = "x"',
        "initial_offsets_db",
        "expected a non-empty list of numbers, got 'x'",
    ),
    ("offset_scan_db = [1, nan]", "offset_scan_db", "item 1"),
    ("offset_scan_db = [1, 90]", "offset_scan_db", "out of range"),
    ("offset_scan_db = ['a']", "offset_scan_db", "item 0"),
    ("k = 0", "k", "out of range"),
    ("initial_offset_db = [0]", "initial_offset_db", "unknown key"),
]


@pytest.mark.parametrize(("line", "key", "what"), BAD)
def test_bad_lists_are_one_line_errors(tmp_path: Path, line: str, key: str, what: str):
    p = _write(tmp_path, f"[filter]\n{line}\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    msg = str(exc.value)
    assert "\n" not in msg and what in msg
    assert exc.value.path == str(p) and exc.value.line == 2
    assert exc.value.column == f"filter.{key}"


def test_an_unknown_top_level_key_lists_every_valid_one(tmp_path: Path):
    """The top level of tracker.toml holds smoothing_lag_s, live_method and
    [filter]: an unknown key's message lists all three (it left out live_method
    when the file did not set it)."""
    p = tmp_path / "tracker.toml"
    p.write_text("foo = 0.5\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"known here: filter, live_method, smoothing_lag_s\)"):
        read_tracker_settings(p)


@pytest.mark.parametrize("key", ["smoothing_lag_s", "live_method"])
def test_a_top_level_key_under_filter_says_where_it_belongs(tmp_path: Path, key: str):
    """``smoothing_lag_s`` written under ``[filter]`` was 'unknown key (did you mean
    'smoother_ghost_s'?)': the message now says it belongs at the top level."""
    value = "1.0" if key == "smoothing_lag_s" else '"filter"'
    p = _write(tmp_path, f"[filter]\n{key} = {value}\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    assert "belongs at the top level, above [filter]" in exc.value.reason
    assert exc.value.line == 2 and exc.value.column == f"filter.{key}"


_OFFSETS = st.lists(
    st.floats(-60, 60, allow_nan=False).map(lambda x: round(x, 3)), min_size=1, max_size=6
).map(tuple)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(initial=_OFFSETS, scan=_OFFSETS | st.just(()))
def test_round_trip(tmp_path: Path, initial: tuple[float, ...], scan: tuple[float, ...]):
    p = tmp_path / "tracker.toml"
    write_tracker_toml(p, {"initial_offsets_db": initial, "offset_scan_db": scan})
    o = read_tracker_settings(p).filter_overrides
    assert o == {"initial_offsets_db": initial, "offset_scan_db": scan}


def test_script_overrides_parse_or_exit_with_the_usage_error(capsys: pytest.CaptureFixture[str]):
    """The scripts' ``--set`` / ``--pose3d-set``: literals into overrides of the
    named config; an unknown field, a non-literal or a refused value is the
    parser's usage error (exit 2) naming the option and the item."""
    import argparse

    from radiopose.filtering.config import overrides_or_exit
    from radiopose.filtering.particle3d import Pose3dConfig

    ap = argparse.ArgumentParser(prog="script")
    assert overrides_or_exit(ap, ["n_particles=500", "smoother='backward'"]) == {
        "n_particles": 500,
        "smoother": "backward",
    }
    assert overrides_or_exit(ap, ["refine_heading_deg=0.0"], "--pose3d-set", Pose3dConfig) == {
        "refine_heading_deg": 0.0
    }
    for items, option, config, what in (
        (["no_such_field=1"], "--set", FilterConfig, "no_such_field"),
        (["n_particles=abc"], "--set", FilterConfig, "n_particles=abc"),
        (["n_particles=3"], "--set", FilterConfig, "n_particles"),
        (["refine_heading_deg=200.0"], "--pose3d-set", Pose3dConfig, "refine_heading_deg"),
    ):
        with pytest.raises(SystemExit) as exc:
            overrides_or_exit(ap, items, option, config)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"error: {option} " in err and what in err
