"""Simulator: determinism, contract conformance, motion options."""

import argparse
import csv
import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.packets import read_packets_csv, read_truth_csv
from radiopose.simulate import MotionConfig, ScenarioConfig, seed_range, simulate
from radiopose.simulate.channel import LogDistance
from radiopose.site import load_site
from radiopose.units import angle_diff_deg

SMALL = ScenarioConfig(size_m=10.0, step_m=0.5, duration_s=0.5, min_receiver_spacing_m=3.0)


def digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_same_seed_byte_identical(tmp_path):
    simulate(SMALL, seed=42).write(tmp_path / "a")
    simulate(SMALL, seed=42).write(tmp_path / "b")
    simulate(SMALL, seed=43).write(tmp_path / "c")
    assert digest(tmp_path / "a") == digest(tmp_path / "b")
    assert digest(tmp_path / "a")["packets.csv"] != digest(tmp_path / "c")["packets.csv"]


def test_contract_files(tmp_path):
    simulate(replace(SMALL, n_receivers=5), seed=3).write(tmp_path)
    header = {
        "packets.csv": "packet_id,timestamp_s,transmitter,receiver_id,rss_dbm",
        "truth.csv": "timestamp_s,transmitter,x_m,y_m,z_m,azimuth_deg,pitch_deg,roll_deg",
        "site/receivers.csv": "receiver_id,x_m,y_m,z_m,azimuth_deg,pitch_deg,roll_deg,pattern",
        "site/devices.csv": "transmitter,pattern,tx_power_dbm",
        "site/survey.csv": "x_m,y_m,z_m,receiver_id,rss_dbm,azimuth_deg,pitch_deg,roll_deg",
        "site/patterns/device.csv": "azimuth_deg,polar_deg,directivity_dbi",
    }
    for name, cols in header.items():
        with open(tmp_path / name, newline="") as fh:
            assert next(csv.reader(fh)) == cols.split(","), name
    site = load_site(tmp_path / "site")  # full validation
    assert len(site.receivers) == 5
    packets = read_packets_csv(tmp_path / "packets.csv")
    truth = read_truth_csv(tmp_path / "truth.csv")
    n = len(truth)
    assert n == 100  # 0.5 s at 5 ms
    assert len(packets) == 5 * n
    assert set(packets.receiver_id) == set(site.receiver_ids)
    assert np.all(np.diff(truth.timestamp_s) > 0)
    np.testing.assert_allclose(np.diff(truth.timestamp_s), 0.005, atol=1e-9)
    assert np.all((truth.position_m[:, :2] >= 0) & (truth.position_m[:, :2] <= 10))
    assert np.all((truth.orientation_deg[:, 0] >= 0) & (truth.orientation_deg[:, 0] < 360))


def test_receivers_spaced_and_patterns_phone_like():
    sim = simulate(ScenarioConfig(duration_s=0.05), seed=9)
    rx = sim.site.receiver_positions_m()
    d = np.linalg.norm(rx[:, None] - rx[None], axis=-1)
    assert np.min(d[np.triu_indices(4, 1)]) >= 4.0
    lo, hi = sim.site.patterns["device"].range_dbi
    assert 14.0 <= hi - lo <= 20.0 + 1e-9


def rates(sim) -> np.ndarray:
    az = sim.truth.orientation_deg[:, 0]
    return angle_diff_deg(az[1:], az[:-1]) / np.diff(sim.truth.timestamp_s)


def test_rotation_kinds():
    lin = simulate(replace(SMALL, motion=MotionConfig(rotation="linear")), seed=1)
    r = rates(lin)
    assert np.allclose(r, r[0]) and 10 <= abs(r[0]) <= 90
    per = simulate(replace(SMALL, duration_s=3.0, motion=MotionConfig(rotation="periodic")), seed=1)
    r = rates(per)
    assert r.max() > 0 > r.min()  # sways both ways
    assert np.abs(r).max() < 360.0  # within the rotation model
    fast = simulate(replace(SMALL, motion=MotionConfig(rotation="fast")), seed=1)
    assert np.all(np.abs(rates(fast)) > 360.0)


def test_straight_line_constant_speed():
    sim = simulate(SMALL, seed=5)
    v = np.diff(sim.truth.position_m, axis=0) / 0.005
    assert np.allclose(v, v[0], atol=1e-6)
    assert 0.5 <= np.linalg.norm(v[0]) <= 1.5


def test_loss_fraction():
    sim = simulate(replace(SMALL, duration_s=2.0, loss_fraction=0.3), seed=2)
    heard = len(sim.packets) / (4 * len(sim.truth))
    assert heard == pytest.approx(0.7, abs=0.04)


def test_noise_level():
    a = simulate(replace(SMALL, noise_db=0.0, duration_s=2.0), seed=8)
    b = simulate(replace(SMALL, noise_db=2.0, duration_s=2.0), seed=8)
    diff = b.packets.rss_dbm - a.packets.rss_dbm
    assert np.std(diff) == pytest.approx(2.0, rel=0.05)


@pytest.mark.parametrize(
    "bad",
    [
        {"n_receivers": 0},
        {"noise_db": -1.0},
        {"loss_fraction": 1.0},
        {"azimuth_step_deg": 7.0},
        {"interval_ms": 0.0},
    ],
)
def test_bad_config(bad):
    with pytest.raises(InputError):
        simulate(replace(SMALL, **bad))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(0, 1000))
def test_seed_range_reads_first_last_and_one_seed(first: int, span: int) -> None:
    """The scripts' ``--seeds`` type: ``FIRST-LAST`` inclusive, ``SEED`` alone."""
    assert seed_range(f"{first}-{first + span}") == range(first, first + span + 1)
    assert seed_range(str(first)) == range(first, first + 1)
    if span:
        with pytest.raises(argparse.ArgumentTypeError, match="is empty"):
            seed_range(f"{first + span}-{first}")


@pytest.mark.parametrize("bad", ["", "x", "1-x", "1-2-3", "1.5", "-"])
def test_seed_range_refuses_what_is_not_a_seed_set(bad: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="is not FIRST-LAST") as err:
        seed_range(bad)
    assert "\n" not in str(err.value)


# ------------------------------------------------ settings built in Python (QA, session 24)
def _handheld(**kw):
    from radiopose.simulate.handheld import HandheldConfig

    return HandheldConfig(**kw)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        # minutes of relaxing the spacing, or all memory, before
        (lambda: ScenarioConfig(min_receiver_spacing_m=1e300), "min_receiver_spacing_m = 1e\\+300"),
        (
            lambda: ScenarioConfig(motion=MotionConfig(path="walk", walk_corner_m=1e-6)),
            "walk_corner_m = 1e-06 needs 0.01",
        ),
        (lambda: _handheld(min_receiver_spacing_m=1e300), "min_receiver_spacing_m"),
        (lambda: _handheld(pattern_step_deg=0.01), "pattern_step_deg = 0.01 is out of range"),
        (lambda: _handheld(pattern_step_deg=0.0), "pattern_step_deg"),
        (lambda: _handheld(pattern_step_deg=7.0), "pattern_step_deg = 7.0 does not divide 180"),
        (lambda: _handheld(size_m=1000.0, step_m=0.05), "more than 25,000,000 grid points"),
        (lambda: _handheld(azimuth_step_deg=0.0), "azimuth_step_deg = 0.0 is out of range"),
        (lambda: _handheld(azimuth_step_deg=7.0), "azimuth_step_deg = 7.0 does not divide 360"),
        (lambda: _handheld(pitch_deg=()), "pitch_deg = \\(\\) is out of range"),
        (lambda: _handheld(pitch_deg=(500.0,)), "pitch_deg = \\(500.0,\\) is out of range"),
        (lambda: _handheld(z_step_m=1e-6), "heights \\(limit 1,000\\)"),
        (lambda: _handheld(survey_heights_m=(np.nan,)), "survey_heights_m = \\(nan,\\) must be"),
        # types: a numpy or comparison TypeError before
        (lambda: ScenarioConfig(size_m="20"), "size_m = '20' must be a finite number"),
        (lambda: ScenarioConfig(n_receivers=2.5), "n_receivers = 2.5 must be an integer"),
        (lambda: ScenarioConfig(n_receivers=True), "n_receivers = True must be an integer"),
        (lambda: ScenarioConfig(motion=MotionConfig(speed_mps=(1.0,))), "speed_mps = \\(1.0,\\)"),
        # values that reached packets and maps as NaN, -inf or 999,929 dBm
        (lambda: ScenarioConfig(device_range_db=(20.0, 14.0)), "device_range_db"),
        (lambda: ScenarioConfig(device_range_db=(np.nan, np.nan)), "device_range_db"),
        (lambda: ScenarioConfig(tx_power_dbm=np.nan), "tx_power_dbm = nan must be"),
        (lambda: ScenarioConfig(tx_power_dbm=1e6), "tx_power_dbm = 1000000.0 is out of range"),
        (lambda: ScenarioConfig(z_m=np.nan), "z_m = nan must be"),
        (lambda: ScenarioConfig(channel=LogDistance(d0_m=0.0)), "d0_m = 0.0 is out of range"),
        (lambda: ScenarioConfig(channel=LogDistance(exponent=np.nan)), "exponent = nan must be"),
        (lambda: _handheld(channel=LogDistance(exponent=-1.0)), "exponent = -1.0 is out of range"),
    ],
)
def test_a_scenario_setting_built_in_python_is_a_one_line_error(config, message):
    cfg = config()
    with pytest.raises(InputError, match=message) as err:
        cfg.validate()
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("seed", [1.5, -1, True, "7", 2**63])
def test_a_seed_that_is_not_an_integer_in_range_is_an_error(seed):
    from radiopose.simulate.handheld import simulate_handheld

    with pytest.raises(InputError, match="must be an integer in"):
        simulate(ScenarioConfig.smoke(), seed=seed)
    with pytest.raises(InputError, match="must be an integer in"):
        simulate_handheld(_handheld(size_m=6.0, step_m=0.5, duration_s=0.05), seed=seed)
