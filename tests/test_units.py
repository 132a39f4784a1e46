import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from radiopose.units import (
    angle_diff_deg,
    circular_mean_deg,
    db_to_linear,
    dbm_to_mw,
    linear_to_db,
    mw_to_dbm,
    wrap_deg,
    wrap_signed_deg,
)

finite = st.floats(-1e6, 1e6, allow_nan=False)


def test_angle_diff_knows_the_wrap():
    assert angle_diff_deg(359.0, 1.0) == -2.0
    assert angle_diff_deg(1.0, 359.0) == 2.0
    assert angle_diff_deg(180.0, 0.0) == -180.0  # half-open [-180, 180)


def test_db_identities():
    assert dbm_to_mw(0.0) == 1.0
    assert dbm_to_mw(30.0) == 1000.0
    assert np.isclose(mw_to_dbm(2.0), 3.0103, atol=1e-4)
    assert db_to_linear(10.0) == 10.0
    assert mw_to_dbm(0.0) == -np.inf


@given(finite)
def test_wrap_ranges(a):
    w = float(wrap_deg(a))
    s = float(wrap_signed_deg(a))
    assert 0.0 <= w < 360.0
    assert -180.0 <= s < 180.0
    assert np.isclose(np.cos(np.deg2rad(w)), np.cos(np.deg2rad(a)), atol=1e-6)


@given(finite, finite)
def test_angle_diff_is_smallest(a, b):
    d = float(angle_diff_deg(a, b))
    assert -180.0 <= d < 180.0
    assert np.isclose(float(wrap_deg(b + d)), float(wrap_deg(a)), atol=1e-6) or np.isclose(
        abs(float(wrap_deg(b + d)) - float(wrap_deg(a))), 360.0, atol=1e-6
    )


@given(st.floats(-200, 100, allow_nan=False))
def test_db_round_trip(x):
    assert np.isclose(float(linear_to_db(db_to_linear(x))), x, atol=1e-9)
    assert np.isclose(float(mw_to_dbm(dbm_to_mw(x))), x, atol=1e-9)


def test_circular_mean_across_wrap():
    assert np.isclose(circular_mean_deg([350.0, 10.0]), 0.0, atol=1e-9) or np.isclose(
        circular_mean_deg([350.0, 10.0]), 360.0, atol=1e-9
    )
    assert np.isclose(circular_mean_deg([350.0, 10.0], [3.0, 1.0]), 355.0, atol=0.1)
