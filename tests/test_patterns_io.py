"""Pattern and enrolment CSVs: round trips (hypothesis) and every bad-input case."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.patterns.enrol import (
    Measurements,
    read_measurements_csv,
    write_measurements_csv,
)
from radiopose.patterns.pattern import Pattern, read_pattern_csv, write_pattern_csv

HYP = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _write(tmp_path: Path, text: str, name: str = "x.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _one_line_error(exc: InputError, path: Path, line: int | None, column: str | None) -> None:
    msg = str(exc)
    assert "\n" not in msg
    assert msg.startswith(str(path))
    assert exc.path == str(path)
    assert exc.line == line
    assert exc.column == column
    if line is not None:
        assert f"{path}:{line}" in msg
    if column is not None:
        assert f"column '{column}'" in msg


# ---------------------------------------------------------------- round trips
@st.composite
def patterns(draw) -> Pattern:
    n_az = draw(st.sampled_from([1, 2, 3, 4, 7, 8, 11, 12, 36, 72, 360]))
    sphere = draw(st.booleans())
    if sphere:
        n_po = draw(st.sampled_from([2, 3, 5, 7, 8, 19]))
        po = np.arange(n_po) * (180.0 / (n_po - 1))
    else:
        po = np.array([draw(st.sampled_from([0.0, 45.0, 90.0, 135.0, 180.0]))])
    vals = draw(
        st.lists(
            st.floats(-60.0, 30.0, allow_nan=False),
            min_size=n_az * po.size,
            max_size=n_az * po.size,
        )
    )
    grid = np.round(np.array(vals).reshape(n_az, po.size), 6)
    return Pattern("p", np.arange(n_az) * (360.0 / n_az), po, grid)


@HYP
@given(pattern=patterns())
def test_pattern_csv_round_trip(tmp_path_factory, pattern):
    path = tmp_path_factory.mktemp("rt") / "p.csv"
    write_pattern_csv(pattern, path)
    back = read_pattern_csv(path)
    assert back.name == "p"
    np.testing.assert_allclose(back.azimuth_deg, pattern.azimuth_deg, atol=1e-6)
    np.testing.assert_allclose(back.polar_deg, pattern.polar_deg, atol=1e-6)
    np.testing.assert_allclose(back.directivity_dbi, pattern.directivity_dbi, atol=1e-6)
    write_pattern_csv(back, path.with_name("q.csv"))  # deterministic bytes
    assert path.read_bytes() == path.with_name("q.csv").read_bytes()


@HYP
@given(
    rows=st.lists(
        st.tuples(
            st.floats(0.0, 360.0, allow_nan=False),
            st.floats(0.0, 180.0, allow_nan=False),
            st.floats(-120.0, 20.0, allow_nan=False),
        ),
        min_size=1,
        max_size=30,
    )
)
def test_measurement_csv_round_trip(tmp_path_factory, rows):
    a = np.round(np.array(rows), 6)
    m = Measurements(a[:, 0], a[:, 1], a[:, 2])
    path = tmp_path_factory.mktemp("m") / "m.csv"
    write_measurements_csv(m, path)
    back = read_measurements_csv(path)
    np.testing.assert_allclose(back.motor_azimuth_deg, m.motor_azimuth_deg, atol=1e-6)
    np.testing.assert_allclose(back.motor_elevation_deg, m.motor_elevation_deg, atol=1e-6)
    np.testing.assert_allclose(back.rss_dbm, m.rss_dbm, atol=1e-6)


_CELL = st.sampled_from(
    ["0", "90", "180", "359", "360", "-1", "1e3", "nan", "inf", "-inf", "", "x", " 5 ", "0.5"]
)


@HYP
@given(
    header=st.permutations(["azimuth_deg", "polar_deg", "directivity_dbi", "extra"]).map(
        lambda h: h[: 3 + (len(h) > 3)]
    ),
    body=st.lists(st.lists(_CELL, min_size=3, max_size=5), max_size=6),
    junk=st.text(max_size=20),
)
def test_pattern_csv_fuzz_only_raises_input_error(tmp_path_factory, header, body, junk):
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in body) + "\n" + junk
    path = tmp_path_factory.mktemp("fz") / "f.csv"
    path.write_text(text, encoding="utf-8")
    try:
        read_pattern_csv(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)


@HYP
@given(body=st.lists(st.lists(_CELL, min_size=3, max_size=4), max_size=6))
def test_measurement_csv_fuzz_only_raises_input_error(tmp_path_factory, body):
    text = "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n" + "\n".join(",".join(r) for r in body)
    path = tmp_path_factory.mktemp("fz") / "m.csv"
    path.write_text(text, encoding="utf-8")
    try:
        m = read_measurements_csv(path)
        assert len(m) >= 1
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)


# ---------------------------------------------------------------- bad pattern CSVs
GOOD_PATTERN = "azimuth_deg,polar_deg,directivity_dbi\n0,90,1.5\n120,90,-2\n240,90,0.5\n"


@pytest.mark.parametrize(
    ("text", "line", "column"),
    [
        ("azimuth_deg,directivity_dbi\n0,1\n", 1, "polar_deg"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,90,abc\n", 2, "directivity_dbi"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n120,90,nan\n", 3, "directivity_dbi"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,90,inf\n", 2, "directivity_dbi"),
        ("azimuth_deg,polar_deg,directivity_dbi\n360,90,1\n", 2, "azimuth_deg"),
        ("azimuth_deg,polar_deg,directivity_dbi\n-1,90,1\n", 2, "azimuth_deg"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,181,1\n", 2, "polar_deg"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,90,\n", 2, "directivity_dbi"),
        ("azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n180,90,2\n0,90,3\n", 4, "azimuth_deg"),
    ],
)
def test_bad_pattern_csv_names_file_line_column(tmp_path, text, line, column):
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        read_pattern_csv(path)
    _one_line_error(err.value, path, line, column)


H = "azimuth_deg,polar_deg,directivity_dbi\n"


def test_missing_grid_point_is_named(tmp_path):
    # azimuth 180 has polar 0 and 180 but not 90: reported after (180, 0), line 5
    text = H + "0,0,1\n0,90,1\n0,180,1\n180,0,1\n180,180,1\n"
    path = _write(tmp_path, text)
    with pytest.raises(InputError, match=r"missing grid point azimuth 180, polar 90 deg") as err:
        read_pattern_csv(path)
    _one_line_error(err.value, path, 5, "polar_deg")
    assert "expected after this row" in str(err.value)
    assert "3 polar angles every 90 deg" in str(err.value)


def test_irregular_grid_and_empty_file(tmp_path):
    path = _write(tmp_path, H + "0,90,1\n100,90,1\n240,90,1\n")
    with pytest.raises(InputError, match="azimuth 100 deg is not on a constant-step grid") as err:
        read_pattern_csv(path)
    _one_line_error(err.value, path, 3, "azimuth_deg")
    assert "closest fit: 3 azimuths every 120 deg from 0" in str(err.value)
    one = _write(tmp_path, H + "0,90,1\n0.5,90,2\n", "one.csv")
    with pytest.raises(InputError, match=r"azimuth 0\.5 deg is not on a constant-step grid") as err:
        read_pattern_csv(one)
    assert str(err.value).endswith("(closest fit: 1 azimuth every 360 deg from 0)")
    empty = _write(tmp_path, H, "empty.csv")
    with pytest.raises(InputError, match="no pattern samples") as err:
        read_pattern_csv(empty)
    _one_line_error(err.value, empty, 2, None)
    with pytest.raises(InputError, match="file not found"):
        read_pattern_csv(tmp_path / "nope.csv")


@pytest.mark.parametrize(
    ("text", "line", "column", "match"),
    [
        # one row of a 90° slice deleted: 180 belongs after line 3 (azimuth 90)
        (
            H + "0,90,1\n90,90,1\n270,90,1\n",
            3,
            "azimuth_deg",
            "azimuth 180, polar 90 deg, expected after",
        ),
        # the very first grid point deleted: reported before the first row
        (
            H + "90,90,1\n180,90,1\n270,90,1\n",
            2,
            "azimuth_deg",
            "azimuth 0, polar 90 deg, expected before",
        ),
        # a whole azimuth of a sphere missing (azimuth-major): the azimuth breaks the grid
        (
            H + "0,0,1\n0,90,1\n0,180,1\n90,0,1\n90,90,1\n90,180,1\n270,0,1\n270,90,1\n270,180,1\n",
            7,
            "azimuth_deg",
            "azimuth 180, polar 0 deg, expected after",
        ),
        # polar-major file, one point missing: within polar 90 the azimuth 180 is missing
        (
            H + "0,0,1\n180,0,1\n0,90,1\n0,180,1\n180,180,1\n",
            4,
            "azimuth_deg",
            "azimuth 180, polar 90 deg, expected after",
        ),
        # polar rows must reach 180: the 180 row is missing
        (H + "0,0,1\n0,90,1\n", 3, "polar_deg", "azimuth 0, polar 180 deg, expected after"),
        # a mistyped polar angle (120 -> 100)
        (
            H + "0,0,1\n0,60,1\n0,100,1\n0,180,1\n",
            4,
            "polar_deg",
            r"polar 100 deg is not on a constant-step grid covering \[0, 180\] "
            r"\(closest fit: 4 polar angles every 60 deg",
        ),
        # a mistyped azimuth (30 -> 31) in a 10° grid
        (
            H + "".join(f"{a if a != 30 else 31},90,1\n" for a in range(0, 360, 10)),
            5,
            "azimuth_deg",
            "azimuth 31 deg is not on a constant-step grid covering",
        ),
        # one stray polar angle among a slice's rows: reported at the stray row
        (
            H + "0,90,1\n90,90,1\n180,80,1\n270,90,1\n",
            4,
            "polar_deg",
            r"polar 80 deg in a slice at polar 90 deg \(3 of 4 rows\)",
        ),
        # a grid finer than the 0.1 deg limit: at the first row of the too-close pair
        (
            H + "".join(f"{k * 0.05:.2f},90,1\n" for k in range(7200)),
            3,
            "azimuth_deg",
            r"azimuths 0 and 0.05 deg imply a grid step of 0.05 deg \(7200 azimuths\), "
            r"finer than the 0.1 deg limit",
        ),
        (
            H + "".join(f"{a},{k * 0.05:.2f},1\n" for k in range(3601) for a in (0, 180)),
            4,
            "polar_deg",
            r"polar angles 0 and 0.05 deg imply a grid step of 0.05 deg",
        ),
        # equal within the grid tolerance (1e-5 deg): a duplicate, naming the first line
        (
            H + "0,90,1\n120,90,1\n0.000001,90,1\n240,90,1\n",
            4,
            "azimuth_deg",
            r"duplicate grid point azimuth 1e-06, polar 90 deg.*\(first at line 2\)",
        ),
    ],
)
def test_grid_errors_name_the_line_where_the_grid_breaks(tmp_path, text, line, column, match):
    path = _write(tmp_path, text)
    with pytest.raises(InputError, match=match) as err:
        read_pattern_csv(path)
    _one_line_error(err.value, path, line, column)


def test_grid_within_tolerance_and_offset_grids_load(tmp_path):
    p = read_pattern_csv(_write(tmp_path, H + "0,90,1\n120.000004,90,2\n240,90,3\n"))
    np.testing.assert_allclose(p.azimuth_deg, [0.0, 120.0, 240.0])
    np.testing.assert_allclose(p.directivity_dbi[:, 0], [1.0, 2.0, 3.0])
    q = read_pattern_csv(_write(tmp_path, H + "250,45,3\n10,45,1\n130,45,2\n", "off.csv"))
    np.testing.assert_allclose(q.azimuth_deg, [10.0, 130.0, 250.0])
    np.testing.assert_allclose(q.directivity_dbi[:, 0], [1.0, 2.0, 3.0])
    assert q.polar_deg.tolist() == [45.0]
    # every azimuth a hair below a multiple of the step: 359.9999999 is azimuth 0
    text = H + "119.9999999,90,2\n239.9999999,90,3\n359.9999999,90,1\n"
    r = read_pattern_csv(_write(tmp_path, text, "hair.csv"))
    np.testing.assert_allclose(r.azimuth_deg, [0.0, 120.0, 240.0])
    np.testing.assert_allclose(r.directivity_dbi[:, 0], [1.0, 2.0, 3.0])


@st.composite
def damaged_grids(draw) -> tuple[str, bool]:
    """A valid grid CSV in shuffled or grid order, maybe damaged: (text, damaged)."""
    pattern = draw(patterns())
    phi, theta = np.meshgrid(pattern.azimuth_deg, pattern.polar_deg, indexing="ij")
    rows = [
        [f"{a:.6f}", f"{t:.6f}", f"{d:.6f}"]
        for a, t, d in zip(phi.ravel(), theta.ravel(), pattern.directivity_dbi.ravel(), strict=True)
    ]
    if draw(st.booleans()):
        rows = draw(st.permutations(rows))
    damage = draw(st.sampled_from(["none", "delete", "duplicate", "azimuth", "polar"]))
    if damage != "none" and len(rows) > 1:
        k = draw(st.integers(0, len(rows) - 1))
        if damage == "delete":
            del rows[k]
        elif damage == "duplicate":
            rows.insert(draw(st.integers(0, len(rows))), list(rows[k]))
        elif damage == "azimuth":
            rows[k][0] = f"{draw(st.floats(0.0, 359.999, allow_nan=False)):.3f}"
        else:
            rows[k][1] = f"{draw(st.floats(0.0, 180.0, allow_nan=False)):.3f}"
    else:
        damage = "none"
    text = H + "".join(",".join(r) + "\n" for r in rows)
    return text, damage != "none"


@HYP
@given(case=damaged_grids())
def test_grid_fuzz_loads_whole_grids_or_names_line_and_column(tmp_path_factory, case):
    text, damaged = case
    path = tmp_path_factory.mktemp("grid") / "g.csv"
    path.write_text(text, encoding="utf-8")
    n_rows = text.count("\n") - 1
    try:
        p = read_pattern_csv(path)
    except InputError as exc:
        assert damaged, str(exc)  # an undamaged grid in any row order always loads
        assert "\n" not in str(exc) and exc.path == str(path)
        assert exc.line is not None and 2 <= exc.line <= n_rows + 1
        assert exc.column in ("azimuth_deg", "polar_deg")
    else:
        assert p.directivity_dbi.size == n_rows  # every grid point exactly once


def test_good_pattern_csv_with_extra_columns_in_any_order(tmp_path):
    text = "note,directivity_dbi,polar_deg,azimuth_deg\na,1.5,90,0\nb,-2,90,120\nc,0.5,90,240\n"
    p = read_pattern_csv(_write(tmp_path, text, "phone.csv"))
    assert p.name == "phone" and p.is_slice
    np.testing.assert_allclose(p.directivity_dbi[:, 0], [1.5, -2.0, 0.5])
    assert read_pattern_csv(_write(tmp_path, GOOD_PATTERN)).azimuth_step_deg == 120.0


# ---------------------------------------------------------------- bad enrolment CSVs
@pytest.mark.parametrize(
    ("text", "line", "column"),
    [
        ("motor_azimuth_deg,rss_dbm\n0,-50\n", 1, "motor_elevation_deg"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-5O\n", 2, "rss_dbm"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-50\n1,90,NaN\n", 3, "rss_dbm"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,inf,-50\n", 2, "motor_elevation_deg"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n361,90,-50\n", 2, "motor_azimuth_deg"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,-0.5,-50\n", 2, "motor_elevation_deg"),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,999\n", 2, "rss_dbm"),
    ],
)
def test_bad_measurement_csv_names_file_line_column(tmp_path, text, line, column):
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        read_measurements_csv(path)
    _one_line_error(err.value, path, line, column)


def test_measurement_csv_without_rows_or_with_ragged_row(tmp_path):
    with pytest.raises(InputError, match="no measurement rows"):
        read_measurements_csv(_write(tmp_path, "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n"))
    ragged = "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-50\n1,90\n"
    with pytest.raises(InputError, match="row has 2 fields") as err:
        read_measurements_csv(_write(tmp_path, ragged))
    assert err.value.line == 3


def test_repeated_directions_are_allowed_in_enrolment_csv(tmp_path):
    text = "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-50\n0,90,-52\n360,90,-51\n"
    m = read_measurements_csv(_write(tmp_path, text))
    assert len(m) == 3


def test_finest_allowed_pattern_grid_loads(tmp_path):
    """0.1 deg steps (3600 azimuths) are within the limit."""
    path = _write(tmp_path, H + "".join(f"{k / 10:.1f},90,1\n" for k in range(3600)))
    p = read_pattern_csv(path)
    assert p.azimuth_deg.size == 3600 and p.is_slice
