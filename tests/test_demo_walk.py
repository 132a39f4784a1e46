"""The demo's walk: ``MotionConfig(path="walk", rotation="heading")``.

A walk between random waypoints with rounded turns stays inside the margin,
keeps one speed, really turns, and its heading rate stays within the rotation
model's bound; the device's top follows the direction of travel within the
sway. The paper's straight path is unchanged (pinned digests).
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.simulate import MotionConfig, ScenarioConfig, simulate
from radiopose.simulate.trajectories import device_path, walk_path, walking_azimuth_deg
from radiopose.units import angle_diff_deg

WALK = MotionConfig(path="walk", rotation="heading")
BOUNDS = (0.0, 20.0, 0.0, 20.0)
T_30S = np.arange(1500) * 0.02
SEEDS = range(40, 70)


def _heading_rate_dps(t_s: np.ndarray, az_deg: np.ndarray) -> np.ndarray:
    return np.abs(angle_diff_deg(az_deg[1:], az_deg[:-1])) / np.diff(t_s)


@pytest.mark.parametrize("seed", SEEDS)
def test_walk_stays_inside_keeps_its_speed_and_turns(seed: int) -> None:
    pos = walk_path(np.random.default_rng(seed), T_30S, BOUNDS, 1.0, WALK)
    assert pos.shape == (T_30S.size, 3)
    assert np.all(pos[:, 2] == 1.0)
    assert np.all((pos[:, :2] >= 1.0 - 1e-9) & (pos[:, :2] <= 19.0 + 1e-9))  # 1 m margin
    speed = np.hypot(*np.diff(pos[:, :2], axis=0).T) / 0.02
    assert speed.min() >= 0.5 - 1e-6 and speed.max() <= 1.5 + 1e-6
    assert np.ptp(speed) < 0.01 * speed.mean()  # one speed along the curve
    az = walking_azimuth_deg(T_30S, pos)
    rate = _heading_rate_dps(T_30S, az)
    # a walk of tens of metres in an 18 m square turns: the direction of travel
    # sweeps well over a right angle in total
    assert np.sum(rate) * 0.02 > 90.0
    # rounded corners: the direction of travel never turns faster than the
    # rotation model's bound less the heading sway (2π · 0.6 Hz · 15° ≈ 57°/s)
    assert rate.max() < 360.0 - 57.0


def test_heading_rotation_follows_the_direction_of_travel() -> None:
    for seed in SEEDS:
        pos, ori = device_path(np.random.default_rng(seed), T_30S, BOUNDS, 1.0, WALK)
        travel = walking_azimuth_deg(T_30S, pos)
        sway = np.abs(angle_diff_deg(ori[:, 0], travel))
        assert sway.max() <= WALK.heading_sway_deg[1] + 1e-9
        assert np.all(ori[:, 1:] == 0.0)
        rate = _heading_rate_dps(T_30S, ori[:, 0])
        assert rate.max() < 360.0  # within the paper's rotation model


def test_walking_azimuth_convention() -> None:
    # walking along +y: the top points to +y, azimuth 0; along −x: azimuth 90
    t = np.arange(5) * 0.1
    along_y = np.column_stack([np.zeros(5), t, np.ones(5)])
    along_minus_x = np.column_stack([-t, np.zeros(5), np.ones(5)])
    np.testing.assert_allclose(walking_azimuth_deg(t, along_y), 0.0, atol=1e-9)
    np.testing.assert_allclose(walking_azimuth_deg(t, along_minus_x), 90.0, atol=1e-9)


def test_walk_in_a_small_area_and_a_short_trace() -> None:
    # the live demo's 10 m area, and traces shorter than one corner
    for t in (np.arange(600) * 0.1, np.arange(3) * 0.02, np.zeros(1)):
        pos = walk_path(np.random.default_rng(3), t, (0.0, 10.0, 0.0, 10.0), 1.0, WALK)
        assert pos.shape == (t.size, 3)
        assert np.all((pos[:, :2] >= 1.0 - 1e-9) & (pos[:, :2] <= 9.0 + 1e-9))


def test_walk_in_an_area_smaller_than_a_corner() -> None:
    # a 0.5 m walkable square: corners shrink with the legs instead of folding the
    # walk onto the centre (which once made the path never long enough: a hang)
    t = np.arange(6000) * 0.01  # steps of ~1 cm: chords follow the tight curves
    pos = walk_path(np.random.default_rng(3), t, (0.0, 2.5, 0.0, 2.5), 1.0, WALK)
    assert np.all((pos[:, :2] >= 1.0 - 1e-9) & (pos[:, :2] <= 1.5 + 1e-9))
    speed = np.hypot(*np.diff(pos[:, :2], axis=0).T) / 0.01
    assert np.ptp(speed) < 0.1 * speed.mean()


def test_walk_scenario_is_deterministic(tmp_path: Path) -> None:
    cfg = ScenarioConfig(size_m=10.0, step_m=0.5, duration_s=5.0, interval_ms=20.0, motion=WALK)
    a = simulate(cfg, seed=9)
    b = simulate(cfg, seed=9)
    np.testing.assert_array_equal(a.truth.position_m, b.truth.position_m)
    np.testing.assert_array_equal(a.truth.orientation_deg, b.truth.orientation_deg)
    c = simulate(replace(cfg, motion=MotionConfig()), seed=9)
    assert not np.array_equal(a.truth.position_m, c.truth.position_m)


# The paper's straight path with its three rotations, 20 s in a 10 m area (so the
# path reflects at the margin): byte-identical to the files before the walk
# existed (commit 3755c84).
PINNED = {
    "linear": "24f7ffec8be7e954d2e9b272db097876ddba27b189b136b93f53704473ef7fa6",
    "periodic": "5383a571b78147075ddb82077e9f65ce08840528abaad9894088536111f8c93c",
    "fast": "40bb1b3a6d6ff7c4f403c1b2f53742cb8b21894c30af5e62ae1f326b79058693",
}


@pytest.mark.parametrize("rotation", sorted(PINNED))
def test_straight_path_unchanged(tmp_path: Path, rotation: str) -> None:
    cfg = ScenarioConfig(
        size_m=10.0,
        step_m=0.5,
        duration_s=20.0,
        min_receiver_spacing_m=3.0,
        motion=MotionConfig(rotation=rotation),
    )
    simulate(cfg, seed=5).write(tmp_path)
    assert hashlib.sha256((tmp_path / "truth.csv").read_bytes()).hexdigest() == PINNED[rotation]


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"path": "zigzag"}, "path = 'zigzag' is unknown"),
        ({"rotation": "spin"}, "rotation = 'spin' is unknown"),
        ({"walk_min_leg_m": 0.0}, "walk_min_leg_m = 0.0"),
        ({"walk_max_turn_deg": 270.0}, "walk_max_turn_deg = 270.0"),
        ({"walk_corner_m": float("nan")}, "walk_corner_m = nan"),
        ({"heading_sway_deg": (10.0, 5.0)}, "heading_sway_deg = (10.0, 5.0)"),
    ],
)
def test_walk_settings_are_checked(change: dict[str, object], needle: str) -> None:
    with pytest.raises(InputError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        replace(WALK, **change).validate()
