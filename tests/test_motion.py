"""Motion models: the rotation bound (with the gap cap) and the movement bound."""

from __future__ import annotations

import numpy as np
import pytest

from radiopose.motion import MovementModel, RotationModel, axis_change_deg


def test_rotation_bound_is_360_deg_per_second_by_default():
    m = RotationModel()
    assert m.allowed_deg(0.005) == pytest.approx(1.8)
    assert m.gap_s == pytest.approx(0.25)


def test_rotation_model_accepts_within_and_rejects_beyond_the_bound():
    m = RotationModel()
    prev = np.array([10.0, 0.0, 0.0])
    o = np.array([[11.7, 0.0, 0.0], [12.0, 0.0, 0.0], [8.3, 0.0, 0.0]])
    np.testing.assert_array_equal(m.valid(o, prev, 0.005), [True, False, True])


def test_rotation_model_is_wrap_aware():
    m = RotationModel()
    ok = m.valid(np.array([[1.0, 0.0, 0.0]]), np.array([359.5, 0.0, 0.0]), 0.005)
    assert ok.all()  # 359.5° → 1° is a 1.5° turn
    np.testing.assert_allclose(
        axis_change_deg(np.array([[1.0, -5.0, 350.0]]), np.array([359.0, 5.0, 10.0])),
        [[2.0, 10.0, 20.0]],
    )


def test_rotation_model_any_axis_rejects():
    m = RotationModel()
    assert not m.valid(np.array([[10.0, 5.0, 0.0]]), np.array([10.0, 0.0, 0.0]), 0.005)[0]


def test_rotation_model_reacquires_past_the_gap_and_without_history():
    m = RotationModel()
    far = np.array([[190.0, 0.0, 0.0]])
    prev = np.array([10.0, 0.0, 0.0])
    assert not m.valid(far, prev, 0.2)[0]  # 72° allowed at 0.2 s
    assert m.valid(far, prev, 0.26)[0]  # past t/2: unconstrained
    assert m.valid(far, None, 0.001)[0]
    assert not RotationModel(max_gap_s=10.0).valid(far, prev, 0.26)[0]


def test_movement_model():
    m = MovementModel()
    prev = np.array([1.0, 1.0, 1.0])
    p = np.array([[1.04, 1.0, 1.0], [1.06, 1.0, 1.0]])
    np.testing.assert_array_equal(m.valid(p, prev, 0.005), [True, False])
    assert m.valid(p, None, 0.005).all()
    assert MovementModel(max_gap_s=1.0).valid(np.array([[19.0, 19.0, 1.0]]), prev, 1.5).all()
