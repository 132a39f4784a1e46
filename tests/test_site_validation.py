"""load_site validation: site.toml values (with lines), limits, survey geometry, CLI, fuzzing.

The small site (conftest ``small_site_dir``): a 10 m x 10 m area at 0.25 m, a
1 m survey grid of 11 x 11 points, 4 receivers. Its site.toml (write_site_toml):
line 3 ``[area]``, 4 x_min_m, 5 x_max_m, 6 y_min_m, 7 y_max_m, 8 z_m, 9 step_m,
11 ``[orientations]``, 12 azimuth_step_deg, 13 pitch_deg, 14 roll_deg,
16 ``[survey]``, 17 tx_power_dbm, 18 pattern, 19 interpolation, 20 outside.
"""

import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose import site as site_module
from radiopose.cli import main
from radiopose.errors import InputError
from radiopose.site import load_site


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path.name}"
    path.write_text(text.replace(old, new, 1))


def load_error(site_dir: Path) -> InputError:
    with pytest.raises(InputError) as exc:
        load_site(site_dir)
    assert "\n" not in str(exc.value)
    return exc.value


def keep_survey_rows(site_dir: Path, keep) -> None:
    """Rewrite survey.csv keeping rows ``keep(x, y, receiver_id)`` is true for."""
    lines = (site_dir / "survey.csv").read_text().splitlines(keepends=True)
    out = [lines[0]]
    for ln in lines[1:]:
        x, y, _, rid = ln.split(",")[:4]
        if keep(float(x), float(y), rid):
            out.append(ln)
    (site_dir / "survey.csv").write_text("".join(out))


def first_survey_line(site_dir: Path, rid: str) -> int:
    lines = (site_dir / "survey.csv").read_text().splitlines()
    return next(i + 1 for i, ln in enumerate(lines) if ln.split(",")[3] == rid)


# ------------------------------------------------- gaps 1, 2, 4: site.toml values
TOML_CASES = [
    # (old, new, line, key, what) -- gap 1: every value error names line and key
    ("step_m = 0.25", "step_m = -0.25", 9, "area.step_m", "must be > 0, got -0.25"),
    ("x_max_m = 10.0", "x_max_m = -5.0", 5, "area.x_max_m", "must be >= x_min_m"),
    ("y_max_m = 10.0", "y_max_m = -5.0", 7, "area.y_max_m", "must be >= y_min_m"),
    ("pitch_deg = [0.0]", "pitch_deg = [100.0]", 13, "orientations.pitch_deg", "out of range"),
    ("azimuth_step_deg = 1.0", "azimuth_step_deg = 7.0", 12,
     "orientations.azimuth_step_deg", "7 does not divide 360"),
    ("outside = ", "outsid = ", 20, "survey.outsid", "unknown key"),
    ('pattern = "survey-tx"', 'pattern = "nope"', 18, "survey.pattern", "unknown pattern"),
    ('pattern = "survey-tx"', 'pattern = "../survey-tx"', 18, "survey.pattern",
     "not a plain file name"),
    ('interpolation = "cubic"', 'interpolation = "spline"', 19, "survey.interpolation",
     "expected one of cubic, linear"),
    ("tx_power_dbm = 20.0", "tx_power_dbm = nan", 17, "survey.tx_power_dbm", "finite"),
    ('name = "simulated"', "name = 3", 1, "name", "expected a non-empty string"),
    ("z_m = 1.0\n", "", 3, None, "missing key 'area.z_m'"),  # a missing key: the header
    # gap 2: no overflow, no huge allocation, all numbers finite and bounded
    ("x_min_m = 0.0", "x_min_m = -1e308", 4, "area.x_min_m", "out of range [-1e+06, 1e+06]"),
    ("x_max_m = 10.0", "x_max_m = 1e308", 5, "area.x_max_m", "out of range"),
    ("z_m = 1.0", "z_m = inf", 8, "area.z_m", "expected a finite number"),
    ("step_m = 0.25", "step_m = 1e-320", 9, "area.step_m", "more than 25,000,000"),
    ("step_m = 0.25", "step_m = 0.001", 9, "area.step_m", "exceeds 25,000,000"),
    ("step_m = 0.25", "step_m = 1" + "0" * 400, 9, "area.step_m", "expected a finite number"),
    ("step_m = 0.25", "step_m = nan", 9, "area.step_m", "expected a finite number"),
    ("azimuth_step_deg = 1.0", "azimuth_step_deg = 1e-300", 12,
     "orientations.azimuth_step_deg", "more than 100,000 candidate orientations"),
    ("azimuth_step_deg = 1.0", "azimuth_step_deg = 0.001", 12,
     "orientations.azimuth_step_deg", "more than 100,000"),
    ("azimuth_step_deg = 1.0", "azimuth_step_deg = 0.0", 12,
     "orientations.azimuth_step_deg", "must be > 0"),
    ("pitch_deg = [0.0]\nroll_deg = [0.0]", f"pitch_deg = {list(range(-80, 90, 6))}\n"
     f"roll_deg = {list(range(0, 100, 10))}", 11, "orientations",
     "360 azimuths x 29 pitches x 10 rolls = 104,400 candidate orientations, more than 100,000"),
    # gap 4: truncated grids, repeated and out-of-range angles
    ("step_m = 0.25", "step_m = 0.3", 9, "area.step_m", "must be a whole number of steps"),
    ("pitch_deg = [0.0]", "pitch_deg = [0.0, 0.0]", 13, "orientations.pitch_deg",
     "item 1 = 0 is the same as item 0"),
    ("roll_deg = [0.0]", "roll_deg = [0.0, 10.0, 0.0]", 14, "orientations.roll_deg",
     "must be distinct"),
    ("roll_deg = [0.0]", "roll_deg = [180.0, -180.0]", 14, "orientations.roll_deg",
     "equal modulo 360"),
    ("roll_deg = [0.0]", "roll_deg = [-90.0, 270.0]", 14, "orientations.roll_deg",
     "equal modulo 360"),
    ("roll_deg = [0.0]", "roll_deg = [400.0]", 14, "orientations.roll_deg",
     "out of range [-360, 360]"),
    ("pitch_deg = [0.0]", "pitch_deg = []", 13, "orientations.pitch_deg", "non-empty list"),
    # a bare number is not a list (docs/site.md): rejected, not read as [0.0]
    ("pitch_deg = [0.0]", "pitch_deg = 0.0", 13, "orientations.pitch_deg",
     "non-empty list of numbers, got a single number (write [0.0])"),
    ("roll_deg = [0.0]", "roll_deg = 90", 14, "orientations.roll_deg",
     "got a single number"),
    # the same roll modulo 360, within float noise of +-180
    ("roll_deg = [0.0]", "roll_deg = [179.99999999999, -180.0]", 14, "orientations.roll_deg",
     "equal modulo 360 to item 0"),
    ("pitch_deg = [0.0]", 'pitch_deg = [0.0, "a"]', 13, "orientations.pitch_deg", "item 1"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "line", "key", "what"), TOML_CASES)
def test_site_toml_value_error_names_line_and_key(small_site_dir, old, new, line, key, what):
    edit(small_site_dir / "site.toml", old, new)
    err = load_error(small_site_dir)
    assert what in err.reason
    assert (Path(err.path).name, err.line, err.column) == ("site.toml", line, key)
    where = f"site.toml:{line}" + (f", column '{key}'" if key else "")
    assert str(err).startswith(str(small_site_dir / where)), str(err)


def test_too_many_candidate_poses(small_site_dir):
    """41² positions fit, 40,401 x 7,200 orientations (2.9e8) exceed MAX_CANDIDATES."""
    edit(small_site_dir / "site.toml", "step_m = 0.25", "step_m = 0.05")
    edit(small_site_dir / "site.toml", "azimuth_step_deg = 1.0", "azimuth_step_deg = 0.05")
    err = load_error(small_site_dir)
    assert (err.line, err.column) == (11, "orientations")
    assert "more than 250,000,000" in err.reason


@pytest.mark.parametrize(
    ("old", "new", "check"),
    [
        # 0.1 m steps over 9.6 m: 96.00000000000001 steps, a whole number within tolerance
        ("x_min_m = 0.0", "x_min_m = 0.3", lambda s: s.area.x_m()[-1] == pytest.approx(9.9)),
        ("roll_deg = [0.0]", "roll_deg = [270.0, -45.0]", lambda s: len(s.orientations) == 720),
        ("pitch_deg = [0.0]", "pitch_deg = [-90.0, 0.0, 90.0]", lambda s: s.orientations),
    ],
)
def test_site_toml_accepted_values(small_site_dir, old, new, check):
    edit(small_site_dir / "site.toml", old, new)
    if "x_min_m = 0.3" in new:
        edit(small_site_dir / "site.toml", "step_m = 0.25", "step_m = 0.1")
        edit(small_site_dir / "site.toml", "x_max_m = 10.0", "x_max_m = 9.9")
    assert check(load_site(small_site_dir))


def test_grid_steps_tolerance():
    from radiopose.site import STEP_TOLERANCE, grid_steps

    assert grid_steps(9.6, 0.1) == (96, True)
    assert grid_steps(10.0, 0.3) == (33, False)
    assert grid_steps(0.0, 0.25) == (0, True)
    assert grid_steps(1.0, 1.0 / (1.0 + 0.5 * STEP_TOLERANCE)) == (1, True)
    assert grid_steps(1.0, 1.0 / (1.0 + 2 * STEP_TOLERANCE)) == (1, False)


# ------------------------------------------------- gap 3: coordinates in CSV files
def set_cell(path: Path, line: int, column: str, value: str) -> None:
    rows = [ln.split(",") for ln in path.read_text().splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


@pytest.mark.parametrize(
    ("fname", "line", "column", "value"),
    [
        ("survey.csv", 2, "x_m", "1e308"),
        ("survey.csv", 7, "y_m", "-1000000.5"),
        ("survey.csv", 2, "z_m", "-inf"),
        ("receivers.csv", 3, "x_m", "1e7"),
        ("receivers.csv", 2, "z_m", "nan"),
    ],
)
def test_coordinates_bounded(small_site_dir, fname, line, column, value):
    set_cell(small_site_dir / fname, line, column, value)
    err = load_error(small_site_dir)
    assert (Path(err.path).name, err.line, err.column) == (fname, line, column)
    assert re.search(r"out of range \[-1e\+06, 1e\+06\]|not a finite number", err.reason)


# ------------------------------------------------- gap 5: survey geometry policy
def test_area_outside_survey_rejected(small_site_dir):
    """x 50..60 m against a 0..10 m survey (the audit's example)."""
    edit(small_site_dir / "site.toml", "x_min_m = 0.0", "x_min_m = 50.0")
    edit(small_site_dir / "site.toml", "x_max_m = 10.0", "x_max_m = 60.0")
    err = load_error(small_site_dir)
    assert (Path(err.path).name, err.line, err.column) == ("site.toml", 3, "area")
    assert "only 0% of the candidate positions" in err.reason
    assert "at least 50%" in err.reason


@pytest.mark.parametrize(
    ("keep", "what"),
    [
        (lambda x, y, r: r != "rx2" or (x, y) == (0, 0), "its 1 surveyed point(s)"),
        (lambda x, y, r: r != "rx2" or (x, y) in ((0, 0), (5, 5)), "its 2 surveyed point(s)"),
        (lambda x, y, r: r != "rx2" or x == y, "do not span an area"),  # the diagonal
        (lambda x, y, r: r != "rx2" or y == 3, "do not span an area"),
        (lambda x, y, r: r != "rx2" or x <= 3, "only 31.7% of the candidate positions"),
    ],
    ids=["one-point", "two-points", "diagonal", "one-row", "corner"],
)
def test_receiver_survey_geometry_rejected(small_site_dir, keep, what):
    keep_survey_rows(small_site_dir, keep)
    err = load_error(small_site_dir)
    line = first_survey_line(small_site_dir, "rx2")
    assert (Path(err.path).name, err.line, err.column) == ("survey.csv", line, "receiver_id")
    assert "receiver 'rx2'" in err.reason and what in err.reason


@pytest.mark.parametrize("outside", ["nearest", "exclude"])
def test_partly_surveyed_area_follows_outside_policy(small_site_dir, outside):
    """x 0..15 m against a 0..10 m survey: 41 of 61 columns (67%) inside, accepted;
    the rest follows [survey] outside."""
    edit(small_site_dir / "site.toml", "x_max_m = 10.0", "x_max_m = 15.0")
    edit(small_site_dir / "site.toml", 'outside = "nearest"', f'outside = "{outside}"')
    site = load_site(small_site_dir)
    m = site.survey_map.m_db
    assert m.shape[1:] == (61, 41)
    assert np.all(np.isfinite(m[:, :41]))
    assert np.all(np.isfinite(m[:, 41:])) == (outside == "nearest")
    assert np.all(np.isnan(m[:, 41:])) == (outside == "exclude")


def test_survey_helpers():
    from radiopose.survey import hull_coverage, spans_two_dimensions

    g = np.arange(11.0)
    grid = np.array(np.meshgrid(g, g)).reshape(2, -1).T
    axis = np.arange(0.0, 10.01, 0.25)
    assert hull_coverage(grid, axis, axis) == 1.0
    assert hull_coverage(grid, axis + 50, axis) == 0.0
    tri = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    pts = np.array(np.meshgrid(axis, axis)).reshape(2, -1).T
    inside = np.mean(pts.sum(axis=1) <= 10 + 1e-9)
    assert hull_coverage(tri, axis, axis) == pytest.approx(inside)
    assert hull_coverage(tri, axis[:1], axis) == pytest.approx(1.0)  # one column, x = 0
    assert spans_two_dimensions(grid) and spans_two_dimensions(tri)
    assert not spans_two_dimensions(np.c_[g, 2 * g + 1])
    assert not spans_two_dimensions(tri[:2])
    assert not spans_two_dimensions(np.c_[g, 1e-9 * (g % 2)])  # thinner than 1e-6 of its length


# ------------------------------------------------- the CLI: one line, exit 2, no output
@pytest.mark.parametrize(
    ("fname", "old", "new", "where"),
    [
        ("site.toml", "step_m = 0.25", "step_m = 1e-320", "site.toml:9, column 'area.step_m'"),
        ("site.toml", "azimuth_step_deg = 1.0", "azimuth_step_deg = 0.001",
         "site.toml:12, column 'orientations.azimuth_step_deg'"),
        ("site.toml", "x_min_m = 0.0\nx_max_m = 10.0", "x_min_m = 50.0\nx_max_m = 60.0",
         "site.toml:3, column 'area'"),
        ("survey.csv", "\n0,0,1,rx1,", "\n1e308,0,1,rx1,", "survey.csv:2, column 'x_m'"),
    ],
)  # fmt: skip
def test_cli_locate_bad_site(small_site_dir, capsys, fname, old, new, where):
    edit(small_site_dir / fname, old, new)
    out = small_site_dir.parent / "estimates.csv"
    code = main(["locate", str(small_site_dir), str(small_site_dir.parent / "packets.csv"),
                 "-o", str(out)])  # fmt: skip
    _, err = capsys.readouterr()
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("radiopose: ")
    assert where in err and "Traceback" not in err
    assert not out.exists()


# ------------------------------------------------- gap 6: typed-value fuzzing
_KEYS = {
    "name": 1,
    "x_min_m": 4,
    "x_max_m": 5,
    "y_min_m": 6,
    "y_max_m": 7,
    "z_m": 8,
    "step_m": 9,
    "azimuth_step_deg": 12,
    "pitch_deg": 13,
    "roll_deg": 14,
    "tx_power_dbm": 17,
    "pattern": 18,
    "interpolation": 19,
    "outside": 20,
}


def _toml_float(x: float) -> str:
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    r = repr(x)
    return r if any(c in r for c in ".en") else r + ".0"


_special = st.sampled_from(
    [0.0, -0.0, 1e308, -1e308, 5e-324, 1e-320, 1e-300, 1e-3, 0.1, 0.3, 0.25, 1.0, 2.5, 5.0,
     7.0, 10.0, 90.0, 180.0, -180.0, 360.0, 1e6, 1e6 + 1, 2e6, math.nan, math.inf, -math.inf]
)  # fmt: skip
_float = st.one_of(_special, st.floats()).map(_toml_float)
_int = st.one_of(st.integers(-(2**70), 2**70), st.sampled_from([0, 1, 10, 360, -1, 10**400])).map(
    str
)
_scalar = st.one_of(
    _float,
    _int,
    st.sampled_from(["true", "false", "1979-05-27", "07:32:00", "{ a = 1 }", "{}"]),
    st.sampled_from(["survey-tx", "rx1", "device", "cubic", "linear", "exclude", "", "../x"]).map(
        json.dumps
    ),
    st.text(max_size=8).map(lambda t: json.dumps(t, ensure_ascii=False).replace("\x7f", "")),
)
_list = st.lists(st.one_of(_float, _int), max_size=5)
_value = st.one_of(
    _scalar,
    _list.map(lambda v: f"[{', '.join(v)}]"),
    _list.filter(bool).map(lambda v: f"[{', '.join(v + v[:1])}]"),  # a duplicate
    st.lists(_scalar, max_size=3).map(lambda v: f"[{', '.join(v)}]"),  # mixed types
    st.just("[[1.0], [2.0]]"),
)


_floats_list = _list.map(lambda v: f"[{', '.join(v)}]")
_names = st.sampled_from(["survey-tx", "rx1", "device", "cubic", "linear", "nearest", "exclude"])


def _value_for(key: str) -> st.SearchStrategy[str]:
    """Mostly values of the key's own type (to reach range checks), sometimes anything."""
    if key in ("pitch_deg", "roll_deg"):
        own = st.one_of(_floats_list, _float, _value.filter(lambda v: v.startswith("[")))
    elif key in ("name", "pattern", "interpolation", "outside"):
        own = _names.map(json.dumps)
    else:
        own = st.one_of(_float, _int)
    return st.one_of(own, own, _value)


_substitutions = st.lists(st.sampled_from(sorted(_KEYS)), min_size=1, max_size=3, unique=True)


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    subs=_substitutions.flatmap(
        lambda keys: st.tuples(*map(_value_for, keys)).map(
            lambda v: dict(zip(keys, v, strict=True))
        )
    )
)
def test_fuzz_site_toml_typed_values(small_site_dir, subs):
    """A structurally valid site.toml with random typed values: the site loads, or
    the error names site.toml (survey.csv for an area that a receiver's survey
    does not cover) and a line; never another exception."""

    path = small_site_dir / "site.toml"
    original = path.read_text()
    lines = original.splitlines()
    for key, value in subs.items():
        n = _KEYS[key] - 1
        assert lines[n].startswith(f"{key} = ")
        lines[n] = f"{key} = {value}"
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)  # the document stays valid TOML
    path.write_text(text)
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(site_module, "MAX_GRID_POINTS", 200_000)  # keep accepted grids cheap
            load_site(small_site_dir)
    except InputError as exc:
        assert Path(exc.path or "").name in ("site.toml", "survey.csv"), str(exc)
        assert exc.line is not None, str(exc)
        assert "\n" not in str(exc)
    finally:
        path.write_text(original)


_cells = st.one_of(
    _float,
    _int,
    st.sampled_from(["", " ", "abc", "rx9", "rx1", "1e308", "-1e308", "0x10", "1_0", "NaN"]),
    st.text(alphabet='0123456789.-+eE, "\t', max_size=8),
)


@settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    subs=st.lists(st.tuples(st.integers(2, 40), st.integers(0, 7), _cells), min_size=1, max_size=3)
)
def test_fuzz_survey_csv_cells(small_site_dir, subs):
    """Random cells of survey.csv: the site loads, or the error has a line number."""
    path = small_site_dir / "survey.csv"
    original = path.read_text()
    rows = [ln.split(",") for ln in original.splitlines()]
    for line, col, value in subs:
        rows[line - 1][col] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    try:
        load_site(small_site_dir)
    except InputError as exc:
        assert exc.line is not None, str(exc)
        assert "\n" not in str(exc)
    finally:
        path.write_text(original)
