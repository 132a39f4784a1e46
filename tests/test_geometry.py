"""Geometry: known cases by hand, round trips, wrap-around, seeded properties."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from radiopose.geometry import (
    direction_to_pattern_angles_deg,
    euler_deg_from_rotation,
    orientation_error_deg,
    orientation_matrices,
    pattern_angles_deg,
    relative_rotation_angle_deg,
    rotation_from_euler_deg,
)


def angles(device, orient_deg, target):
    rot = orientation_matrices(*orient_deg)
    phi, theta = pattern_angles_deg(device, rot, target)
    return float(phi[0, 0, 0]), float(theta[0, 0, 0])


@pytest.mark.parametrize(
    ("orient", "target", "expected"),
    [
        # At rest: receiver due +x → azimuth 0, polar 90; +y (top) → 90; -x → 180.
        ((0, 0, 0), (1, 0, 0), (0, 90)),
        ((0, 0, 0), (0, 1, 0), (90, 90)),
        ((0, 0, 0), (-1, 0, 0), (180, 90)),
        ((0, 0, 0), (0, 0, 1), (0, 0)),  # straight up = out of the screen
        ((0, 0, 0), (0, 0, -1), (0, 180)),
        # Yawed +90° (top now points to world -x): world +x is body -y → 270.
        ((90, 0, 0), (1, 0, 0), (270, 90)),
        ((90, 0, 0), (0, 1, 0), (0, 90)),
        # Pitched +90° about body x: screen faces world -y, top points up (+z).
        ((0, 90, 0), (0, 0, 1), (90, 90)),
        ((0, 90, 0), (0, -1, 0), (0, 0)),
        # Rolled +90° about body y: screen (body z) turns to world +x.
        ((0, 0, 90), (1, 0, 0), (0, 0)),
        ((0, 0, 90), (0, 0, 1), (180, 90)),
    ],
)
def test_known_cases(orient, target, expected):
    phi, theta = angles(np.zeros(3), orient, np.asarray(target, float))
    assert phi == pytest.approx(expected[0], abs=1e-9) or (
        expected[1] in (0, 180)  # azimuth undefined on the poles
    )
    assert theta == pytest.approx(expected[1], abs=1e-9)


def test_matches_contract_formula():
    """R = Rz(az)·Rx(pitch)·Ry(roll), written out by hand."""
    az, pi, ro = np.deg2rad([30.0, -20.0, 50.0])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(pi), -np.sin(pi)], [0, np.sin(pi), np.cos(pi)]])
    ry = np.array([[np.cos(ro), 0, np.sin(ro)], [0, 1, 0], [-np.sin(ro), 0, np.cos(ro)]])
    assert np.allclose(orientation_matrices(30.0, -20.0, 50.0)[0], rz @ rx @ ry)


def test_zero_vector_and_translation():
    phi, theta = direction_to_pattern_angles_deg(np.zeros((2, 3)))
    assert np.all(phi == 0) and np.all(theta == 90)
    p1 = angles(np.array([5.0, 5.0, 1.0]), (0, 0, 0), np.array([6.0, 5.0, 1.0]))
    assert p1 == pytest.approx((0.0, 90.0))


def test_vectorised_shapes_and_agreement():
    rng = np.random.default_rng(3)
    dev = rng.uniform(-5, 5, (7, 3))
    tgt = rng.uniform(-5, 5, (4, 3))
    o = rng.uniform(-80, 80, (5, 3))
    rot = orientation_matrices(*o.T)
    phi, theta = pattern_angles_deg(dev, rot, tgt)
    assert phi.shape == theta.shape == (7, 5, 4)
    for n, m, k in [(0, 0, 0), (6, 4, 3), (3, 2, 1)]:
        v = Rotation.from_euler("ZXY", o[m], degrees=True).inv().apply(tgt[k] - dev[n])
        assert phi[n, m, k] == pytest.approx(np.rad2deg(np.arctan2(v[1], v[0])) % 360)
        assert theta[n, m, k] == pytest.approx(np.rad2deg(np.arccos(v[2] / np.linalg.norm(v))))


angle = st.floats(-179.0, 179.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(angle, st.floats(-89.0, 89.0), angle)
def test_euler_round_trip(az, pitch, roll):
    r = rotation_from_euler_deg(az, pitch, roll)
    back = euler_deg_from_rotation(r)
    assert np.allclose(rotation_from_euler_deg(*back).as_matrix(), r.as_matrix(), atol=1e-9)
    assert -90.0 <= back[1] <= 90.0 and 0.0 <= back[0] < 360.0 and 0.0 <= back[2] < 360.0


@settings(max_examples=100, deadline=None)
@given(st.floats(0, 360), st.floats(-720, 720))
def test_azimuth_only_error_is_wrapped_difference(a, b):
    e = orientation_error_deg([a, 0, 0], [b, 0, 0])[0]
    r = relative_rotation_angle_deg([a, 0, 0], [b, 0, 0])[0]
    assert 0.0 <= e <= 180.0
    assert e == pytest.approx(r, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(st.floats(0, 360), st.floats(-89, 89), st.floats(-180, 180))
def test_a_flat_estimate_of_a_tilted_pose_counts_the_tilt(az, pitch, roll):
    """A flat (azimuth-only) estimate scored against a tilted truth, or the
    reverse, is the relative rotation angle, not the azimuth difference: the
    shortcut is for poses flat on both sides (a mutant applying it when only
    one side was flat scored a 2-D method on hand-held data as perfect)."""
    for est, true in (([az, 0, 0], [az, pitch, roll]), ([az, pitch, roll], [az, 0, 0])):
        e = orientation_error_deg(est, true)[0]
        assert e == pytest.approx(relative_rotation_angle_deg(est, true)[0], abs=1e-9)
    assert orientation_error_deg([10, 0, 0], [10, 30, 0])[0] == pytest.approx(30.0, abs=1e-9)
    assert orientation_error_deg([0, 0, 0], [0, 0, 20])[0] == pytest.approx(20.0, abs=1e-9)


def test_seeded_rotation_invariance():
    """Rotating device and target together leaves pattern angles unchanged."""
    rng = np.random.default_rng(11)
    for _ in range(50):
        o = rng.uniform(-60, 60, 3)
        extra = rng.uniform(0, 360)
        tgt = rng.normal(size=3)
        base = angles(np.zeros(3), o, tgt)
        spin = Rotation.from_euler("z", extra, degrees=True)
        r_new = spin * rotation_from_euler_deg(*o)
        phi, theta = pattern_angles_deg(np.zeros(3), r_new.as_matrix(), spin.apply(tgt))
        assert phi[0, 0, 0] == pytest.approx(base[0], abs=1e-7) or abs(
            phi[0, 0, 0] - base[0]
        ) == pytest.approx(360.0, abs=1e-7)
        assert theta[0, 0, 0] == pytest.approx(base[1], abs=1e-7)


def test_a_non_finite_angle_gives_nan_in_its_row_only():
    """scipy refused the whole call ("zero norm quaternions")."""
    from radiopose.geometry import orientation_error_deg, relative_rotation_angle_deg

    est = np.array([[10.0, 20.0, 0.0], [np.nan, 1.0, 1.0], [30.0, 0.0, np.inf], [5.0, 0.0, 0.0]])
    true = np.zeros((4, 3))
    for f in (orientation_error_deg, relative_rotation_angle_deg):
        out = f(est, true)
        assert np.isnan(out[1:3]).all()
        np.testing.assert_allclose(out[[0, 3]], f(est[[0, 3]], true[[0, 3]]))
    np.testing.assert_allclose(
        relative_rotation_angle_deg([10.0, 0, 0], [[0, 0, 0], [20, 0, 0]]), [10, 10]
    )


def test_a_non_finite_direction_gives_nan_pattern_angles():
    """It gave (0, 90), a valid-looking direction a lookup would use."""
    from radiopose.geometry import direction_to_pattern_angles_deg

    phi, theta = direction_to_pattern_angles_deg(
        [[np.nan, 0, 1], [0, 0, 0], [1, 0, 0], [np.inf, 0, 0]]
    )
    assert np.isnan(phi[[0, 3]]).all() and np.isnan(theta[[0, 3]]).all()
    np.testing.assert_array_equal(phi[1:3], [0.0, 0.0])
    np.testing.assert_array_equal(theta[1:3], [90.0, 90.0])
