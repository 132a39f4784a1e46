"""Patterns built, looked up, enrolled and written from Python are checked like
pattern files: bad input gives a one-line :class:`InputError` naming what and
where, never a deep numpy/scipy traceback, a MemoryError, a hang or a silently
wrong pattern; good input gives the same numbers as before."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.patterns import (
    EnrolConfig,
    Measurements,
    Pattern,
    dipole,
    enrol,
    isotropic,
    simulate_positioner_measurements,
    smartphone_like,
    write_measurements_csv,
    write_pattern_csv,
)
from radiopose.patterns.importers import read_msi
from radiopose.patterns.pattern import MAX_AZIMUTHS, pattern_from_samples
from radiopose.units import wrap_deg

SPHERE = dipole(azimuth_step_deg=10, polar_step_deg=10)
PHONE = smartphone_like(np.random.default_rng(5), azimuth_step_deg=5.0, polar_step_deg=7.5)
SLICE = smartphone_like(np.random.default_rng(6), azimuth_step_deg=3.0)


def _one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    assert isinstance(err.value, InputError), repr(err.value)
    text = str(err.value)
    assert "\n" not in text
    return text


def _reference_lookup(p: Pattern, phi_deg, theta_deg, method: str) -> np.ndarray:
    """``Pattern.lookup_dbi`` as it was before its input was checked (finite input)."""
    phi, theta = np.broadcast_arrays(np.asarray(phi_deg, float), np.asarray(theta_deg, float))
    n_az = p.azimuth_deg.size
    u = wrap_deg(phi - p.azimuth_deg[0]) / p.azimuth_step_deg
    w = np.zeros_like(u) if p.is_slice else np.clip(theta, 0.0, 180.0) / p.polar_step_deg
    d = p.directivity_dbi
    if method == "nearest":
        return d[np.rint(u).astype(np.int64) % n_az, np.rint(w).astype(np.int64)]
    i0 = np.floor(u).astype(np.int64)
    fu = u - i0
    i0 %= n_az
    i1 = (i0 + 1) % n_az
    j0 = np.minimum(np.floor(w).astype(np.int64), d.shape[1] - 1)
    fw = w - j0
    j1 = np.minimum(j0 + 1, d.shape[1] - 1)
    top = d[i0, j0] * (1 - fu) + d[i1, j0] * fu
    bot = d[i0, j1] * (1 - fu) + d[i1, j1] * fu
    return top * (1 - fw) + bot * fw


# ------------------------------------------------------------------ 1. grid size
@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: isotropic().resampled(1e-6), "pattern azimuth step 1e-06 deg is finer than"),
        (lambda: isotropic().resampled(0), "pattern azimuth step 0 deg does not divide 360"),
        (lambda: isotropic().resampled(-10), "pattern azimuth step -10 deg does not divide 360"),
        (lambda: isotropic().resampled(math.nan), "pattern azimuth step nan is not a finite"),
        (lambda: isotropic().resampled("5"), "pattern azimuth step '5' is not a number"),
        (lambda: isotropic(azimuth_step_deg=1e-5), "azimuth step 1e-05 deg is finer than"),
        (lambda: dipole(polar_step_deg=1e-3), "pattern polar step 0.001 deg is finer than"),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), azimuth_step_deg=1e-4
            ),
            "positioner azimuth step 0.0001 deg is finer than the 0.1 deg limit",
        ),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), samples_per_direction=10**9
            ),
            "more than 10000000 packets",
        ),
    ],
)
def test_grid_too_fine_or_malformed_is_refused_before_allocating(make, match):
    with pytest.raises(InputError, match=match) as err:
        make()
    _one_line(err)


def test_pattern_beyond_the_grid_limit_is_refused():
    n = MAX_AZIMUTHS + 1
    with pytest.raises(InputError, match=r"3601 azimuths × 1 polar angles, more than") as err:
        Pattern("big", np.arange(n) * (360.0 / n), [90.0], np.zeros(n))
    _one_line(err)
    n = MAX_AZIMUTHS  # the limit itself (0.1 deg) is allowed
    assert Pattern("ok", np.arange(n) * 0.1, [90.0], np.zeros(n)).azimuth_deg.size == n
    assert isotropic().resampled(0.1).azimuth_deg.size == n


def test_resampled_good_step_is_unchanged():
    r = PHONE.resampled(2.5)
    phi, theta = np.meshgrid(np.arange(144) * 2.5, PHONE.polar_deg, indexing="ij")
    want = _reference_lookup(PHONE, phi, theta, "bilinear")
    np.testing.assert_array_equal(r.directivity_dbi, want)


# ------------------------------------------------------------------ 2. NaN angles
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: SPHERE.lookup_dbi([10.0], [math.nan]), r"polar angle\[0\] is nan"),
        (lambda: SPHERE.lookup_dbi([10.0], [math.nan], method="nearest"), "polar angle"),
        (lambda: SPHERE.lookup_dbi([math.nan], [45.0], method="nearest"), r"azimuth\[0\] is nan"),
        (lambda: SPHERE.lookup_dbi([math.nan], [45.0]), "azimuth"),
        (lambda: SPHERE.lookup_dbi([0.0, math.inf], 45.0), r"azimuth\[1\] is inf"),
        (lambda: SPHERE.lookup_dbi(0.0, [[1.0, -math.inf]]), r"polar angle\[0, 1\] is -inf"),
        (lambda: SLICE.lookup_dbi([math.nan]), "azimuth"),
        (lambda: SLICE.lookup_dbi([1.0], [math.nan]), "polar angle"),
        (lambda: SPHERE.slice_dbi(math.nan), "slice polar angle nan is not a finite number"),
        (lambda: SPHERE.lookup_dbi([1.0, 2.0], [1.0, 2.0, 3.0]), "do not broadcast"),
        (lambda: SPHERE.lookup_dbi(["a"], [1.0]), "is not an array of numbers"),
        (lambda: SPHERE.lookup_dbi([1.0], [1.0], method="cubic"), "unknown lookup method"),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), elevations_deg=[90.0, math.nan]
            ),
            r"elevations_deg\[1\] = nan deg is not in \[0, 180\]",
        ),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), elevations_deg=[]
            ),
            "elevations_deg is empty",
        ),
    ],
)
def test_non_finite_lookup_angle_is_an_input_error(call, match):
    with pytest.raises(InputError, match=match) as err:
        call()
    _one_line(err)


_ANGLE = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=150, deadline=None)
@given(
    phi=st.lists(_ANGLE, min_size=1, max_size=20),
    theta=st.lists(st.floats(-360, 360, allow_nan=False), min_size=1, max_size=20),
    method=st.sampled_from(["bilinear", "nearest"]),
    which=st.sampled_from(["sphere", "phone", "slice"]),
)
def test_finite_lookups_are_unchanged(phi, theta, method, which):
    p = {"sphere": SPHERE, "phone": PHONE, "slice": SLICE}[which]
    n = min(len(phi), len(theta))
    a, t = np.array(phi[:n]), np.array(theta[:n])
    got = p.lookup_dbi(a, t, method=method)
    np.testing.assert_array_equal(got, _reference_lookup(p, a, t, method))
    assert np.isfinite(got).all()


@settings(max_examples=100, deadline=None)
@given(
    phi=st.lists(_ANGLE, min_size=1, max_size=10),
    bad=st.sampled_from([math.nan, math.inf, -math.inf]),
    at=st.integers(0, 9),
    polar=st.booleans(),
    method=st.sampled_from(["bilinear", "nearest"]),
)
def test_a_non_finite_angle_anywhere_raises(phi, bad, at, polar, method):
    a = np.array(phi)
    t = np.full(a.size, 45.0)
    (t if polar else a)[at % a.size] = bad
    for p in (SPHERE, SLICE):
        with pytest.raises(InputError, match="not a finite angle") as err:
            p.lookup_dbi(a, t, method=method)
        _one_line(err)


# ------------------------------------------------------------------ 3, 4. measurements, Pattern
@pytest.mark.parametrize(
    ("arrays", "column", "match"),
    [
        (([0, 10, 100], [90] * 3, [1e6, -60, -55]), "rss_dbm", r"rss_dbm\[0\] = 1e\+06 is out"),
        (([0, 10], [90] * 2, [-60, 61]), "rss_dbm", r"out of range \[-200, 60\]"),
        (([0, 10], [90, 500], [-60, -61]), "motor_elevation_deg", r"elevation_deg\[1\] = 500"),
        (([0, -10], [90, 90], [-60, -61]), "motor_azimuth_deg", r"\[0, 360\]"),
        (([0.0], [90.0], [math.nan]), "rss_dbm", "not a finite number"),
        (([0.0], [90.0], ["x"]), "rss_dbm", "not an array of numbers"),
    ],
)
def test_measurements_outside_the_csv_ranges_are_refused(arrays, column, match):
    with pytest.raises(InputError, match=match) as err:
        Measurements(*arrays)
    _one_line(err)
    assert err.value.column == column
    assert isinstance(err.value, ValueError)  # as before


def test_measurements_of_different_lengths():
    with pytest.raises(InputError, match=r"differ in length \(.*, rss_dbm 1\)") as err:
        Measurements([0.0, 1.0], [90.0, 90.0], [-50.0])
    _one_line(err)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([0.0], [90.0], [math.nan]), r"directivity has NaN/inf \(nan dBi at azimuth 0"),
        (([0.0], [math.nan], [0.0]), r"slice polar angle nan deg is not in \[0, 180\]"),
        (([0.0], [500.0], [0.0]), "slice polar angle 500 deg"),
        (([0.0], [-1.0], [0.0]), "slice polar angle -1 deg"),
        (([0.0, 180.0], [90.0], [0.0]), "does not match"),
        (([0.0], [], []), "does not match"),
        (([5.0, 10.0], [90.0], [0.0, 0.0]), "constant step covering"),
        (([0.0], [0.0, 90.0, 181.0], [[0.0, 0.0, 0.0]]), "must cover"),
        ((["a"], [90.0], [0.0]), "azimuth_deg is not an array of numbers"),
    ],
)
def test_pattern_constructor_errors_are_input_errors(args, match):
    with pytest.raises(InputError, match=match) as err:
        Pattern("p", *args)
    _one_line(err)


def test_enrolment_at_an_impossible_elevation_is_refused():
    with pytest.raises(InputError, match="motor_elevation_deg") as err:
        enrol(Measurements([0, 10, 100], [500] * 3, [-50.0, -60, -55]))
    _one_line(err)


# ------------------------------------------------------------------ 5. steps, ranges
@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: isotropic(azimuth_step_deg=7), "pattern azimuth step 7 deg does not divide 360"),
        (lambda: dipole(azimuth_step_deg=7), "does not divide 360"),
        (lambda: dipole(polar_step_deg=200), "pattern polar step 200 deg does not divide 180"),
        (lambda: dipole(polar_step_deg=7), "pattern polar step 7 deg does not divide 180"),
        (lambda: isotropic(azimuth_step_deg=True), "is not a number"),
        (lambda: dipole(axis=(0, 0, 0)), "dipole axis"),
        (lambda: dipole(axis=(0, 1)), "dipole axis"),
        (lambda: dipole(floor_dbi=math.nan), "dipole floor_dbi nan"),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), azimuth_step_deg=7
            ),
            "positioner azimuth step 7 deg does not divide 360",
        ),
        (
            lambda: simulate_positioner_measurements(SPHERE, np.random.default_rng(0), noise_db=-1),
            "noise_db -1 dB is negative",
        ),
        (
            lambda: simulate_positioner_measurements(
                SPHERE, np.random.default_rng(0), samples_per_direction=0
            ),
            "samples_per_direction 0 is not a positive integer",
        ),
        (
            lambda: smartphone_like(np.random.default_rng(0), range_db=-5),
            r"range_db -5 dB is out of range \[0, 200\]",
        ),
        (lambda: smartphone_like(np.random.default_rng(0), range_db=math.inf), "range_db inf"),
        (lambda: smartphone_like(np.random.default_rng(0), n_lobes=0), "n_lobes 0"),
        (lambda: smartphone_like(np.random.default_rng(0), azimuth_step_deg=7), "divide 360"),
        (lambda: smartphone_like(0), "needs a numpy Generator"),
    ],
)
def test_builder_settings_are_checked(make, match):
    with pytest.raises(InputError, match=match) as err:
        make()
    _one_line(err)


def test_builders_with_good_settings_keep_their_grids():
    assert isotropic(azimuth_step_deg=7.5).azimuth_deg.size == 48
    d = dipole(polar_step_deg=180)
    np.testing.assert_array_equal(d.polar_deg, [0.0, 180.0])
    flat = smartphone_like(np.random.default_rng(2), range_db=0.0)
    np.testing.assert_allclose(flat.directivity_dbi, 0.0, atol=1e-12)


# ------------------------------------------------------------------ 6. samples
@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([], [], []), "pattern samples: no samples"),
        (([0.0, 180.0], [90.0], [0.0, 0.0]), "have 2, 1, 2 values"),
        (([0.0, math.nan], [90.0, 90.0], [0.0, 0.0]), r"azimuth_deg\[1\] is nan"),
        (([0.0, 180.0], [90.0, 90.0], [0.0, math.inf]), r"directivity_dbi\[1\] is inf"),
        (([[0.0]], [[90.0]], [[0.0]]), r"shape \(1, 1\), expected \(n,\)"),
    ],
)
def test_pattern_from_samples_input(args, match):
    with pytest.raises(InputError, match=match) as err:
        pattern_from_samples("p", *args)
    _one_line(err)


def test_pattern_from_samples_grid_errors_are_input_errors():
    with pytest.raises(InputError, match="duplicate grid point") as err:
        pattern_from_samples("p", [0.0, 0.0], [90.0, 90.0], [1.0, 2.0])
    assert isinstance(err.value, ValueError) and err.value.row == 1
    assert err.value.column == "azimuth_deg[1]"


# ------------------------------------------------------------------ 7. EnrolConfig
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"smooth_deg": "5"}, "enrolment setting smooth_deg = '5' must be a finite number"),
        ({"azimuth_step_deg": None}, "azimuth_step_deg = None must be a finite number"),
        ({"azimuth_step_deg": True}, "azimuth_step_deg = True must be a finite number"),
        ({"polar_step_deg": "1"}, "polar_step_deg = '1' must be a finite number or None"),
        ({"smooth_deg": math.nan}, "smooth_deg = nan must be a finite number"),
        ({"azimuth_step_deg": 7.0}, "azimuth step 7 deg does not divide 360"),
        ({"interpolation": 3}, "unknown interpolation 3"),
    ],
)
def test_enrol_config_types(kwargs, match):
    with pytest.raises(InputError, match=match) as err:
        EnrolConfig(**kwargs)
    _one_line(err)


def test_enrol_config_good_settings_still_pass():
    EnrolConfig(smooth_deg=0, azimuth_step_deg=2, polar_step_deg=None)
    EnrolConfig(smooth_deg=np.float64(5.0), azimuth_step_deg=0.1, polar_step_deg=0.1)


# ------------------------------------------------------------------ 8. writers
def test_writing_onto_a_directory_is_one_line(tmp_path):
    with pytest.raises(InputError, match="is a directory, expected a CSV file") as err:
        write_pattern_csv(SPHERE, tmp_path)
    assert _one_line(err).startswith(str(tmp_path))
    m = Measurements([0.0], [90.0], [-50.0])
    with pytest.raises(InputError, match="is a directory") as err:
        write_measurements_csv(m, tmp_path)
    _one_line(err)
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="a parent is not a directory") as err:
        write_pattern_csv(SPHERE, tmp_path / "f" / "p.csv")
    _one_line(err)


# ------------------------------------------------------------------ 9. MSI
def test_msi_duplicate_horizontal_angle_is_reported_as_a_duplicate(tmp_path):
    text = "NAME t\nGAIN 0 dBi\nHORIZONTAL 3\n0 0\n180 1\n180 2\nVERTICAL 2\n0 0\n180 1\n"
    path = tmp_path / "d.msi"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        read_msi(path)
    assert _one_line(err) == (
        f"{path}:6, column 'HORIZONTAL angle': duplicate angle 180 (first at line 5)"
    )
    # 359.9999999 repeats 0
    path.write_text(text.replace("180 2", "359.9999999 2"))
    with pytest.raises(InputError, match=r"duplicate angle 360 \(first at line 4\)"):
        read_msi(path)
