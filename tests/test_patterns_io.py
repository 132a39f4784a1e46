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


def test_missing_grid_point_is_named(tmp_path):
    text = "azimuth_deg,polar_deg,directivity_dbi\n0,0,1\n0,90,1\n0,180,1\n180,0,1\n180,180,1\n"
    path = _write(tmp_path, text)
    with pytest.raises(InputError, match=r"missing grid point azimuth 180, polar 90") as err:
        read_pattern_csv(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_irregular_grid_and_empty_file(tmp_path):
    irregular = "azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n100,90,1\n240,90,1\n"
    with pytest.raises(InputError, match="constant step"):
        read_pattern_csv(_write(tmp_path, irregular))
    with pytest.raises(InputError, match="no pattern samples"):
        read_pattern_csv(_write(tmp_path, "azimuth_deg,polar_deg,directivity_dbi\n"))
    with pytest.raises(InputError, match="file not found"):
        read_pattern_csv(tmp_path / "nope.csv")


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
