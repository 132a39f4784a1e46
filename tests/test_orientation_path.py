"""The orientation path along a fixed position track (:mod:`radiopose.filtering.orientation_path`;
docs/pose3d.md, "An orientation path, 2026-11-28") and its use in the 3-D refinement.

* the one-axis min-plus pass equals a brute-force minimum (hypothesis);
* on a fake model whose expected RSS separates the grid's orientations, a path on the
  grid is recovered cell for cell, wrapping through north, with a frozen pitch and a
  full-circle roll;
* on a simulated scene, the true positions give the true orientations within the grid;
* ``refine_smoothed`` with the path recovers a track turned 180° over its second half,
  which the refinement alone keeps; the path's track replaces the kept one only when its
  objective is lower by more than the switch;
* bad input and the ``[filter.pose3d]`` key are one-line errors.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import radiopose.filtering.orientation_path as op
import radiopose.filtering.refine3d as r3
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.particle3d import FilterModel3d, Pose3dConfig
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import HeardRss, candidate_space
from radiopose.packets import group_packets
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings


@settings(max_examples=60, deadline=None)
@given(
    shape=st.tuples(*(st.integers(1, 6),) * 3),
    axis=st.integers(0, 2),
    wrap=st.booleans(),
    seed=st.integers(0, 2**31),
)
def test_min_plus_is_the_brute_force_minimum(shape, axis, wrap, seed):
    rng = np.random.default_rng(seed)
    value = rng.normal(size=shape) * 5.0
    cost = op._step_costs(6.0)
    best, arg = op._min_plus(value, axis, cost, wrap)
    size = shape[axis]
    for idx in np.ndindex(*shape):
        cands = []
        for j, k in enumerate(range(-op.MAX_STEP_CELLS, op.MAX_STEP_CELLS + 1)):
            src = idx[axis] - k
            if wrap:
                src %= size
            elif not 0 <= src < size:
                continue
            at = list(idx)
            at[axis] = src
            cands.append((value[tuple(at)] + cost[j], k))
        want = min(c for c, _ in cands)
        assert best[idx] == pytest.approx(want)
        # the shift stored is one that attains the minimum
        assert any(c == pytest.approx(want) and k == arg[idx] for c, k in cands)


class _FakeModel:
    """Expected RSS that tells the grid's orientations apart: receiver ``r`` reads a
    smooth function of azimuth, pitch and roll with its own phases (position ignored)."""

    def __init__(self, tilt_deg: tuple[float, float, float, float]):
        self.tilt_rad = np.deg2rad(tilt_deg)
        self.z_box_m = np.array([0.5, 2.0])

    def expected(self, S: np.ndarray, heard: np.ndarray) -> np.ndarray:
        az, pitch, roll = S[:, K.AZIMUTH_RAD], S[:, K.PITCH_RAD], S[:, K.ROLL_RAD]
        cols = []
        for r in np.asarray(heard):
            ph = 0.9 * r
            e = 30 * np.cos(az - ph) + 25 * np.sin(2 * pitch + ph) + 20 * np.cos(roll + 2 * ph)
            cols.append(e)
        return np.column_stack(cols)


def _fake_track(model: _FakeModel, cells_deg: np.ndarray, per_window: int = 4):
    """Packets ``per_window`` per 0.1 s window at each window's grid orientation, read
    noise-free by 5 receivers; returns (times, heard, positions, orientations)."""
    n_win = cells_deg.shape[0]
    t = (np.arange(n_win * per_window) + 0.5) * op.WINDOW_S / per_window
    ori = np.repeat(cells_deg, per_window, axis=0)
    S = np.zeros((t.size, K.N_COLUMNS))
    S[:, K.AZIMUTH_RAD], S[:, K.PITCH_RAD], S[:, K.ROLL_RAD] = np.deg2rad(ori).T
    rx = np.arange(5)
    rss = model.expected(S, rx) + 1.5  # a device offset of 1.5 dB
    heard = [HeardRss(rx, rss[i]) for i in range(t.size)]
    return t, heard, np.tile([1.0, 2.0, 1.2], (t.size, 1)), ori


def test_a_path_on_the_grid_is_recovered_cell_for_cell():
    """Azimuth through north (350° → 10°), pitch and roll moving by at most one cell a
    window: the windows' orientations come back exactly (one packet per window: the
    window's orientation is placed at its packet's time)."""
    model = _FakeModel((0.0, 90.0, 0.0, 45.0))
    az = np.array([340, 345, 350, 355, 0, 5, 10, 10, 15, 15], dtype=float)
    pitch = np.array([30, 35, 35, 40, 45, 45, 50, 55, 55, 60], dtype=float)
    roll = np.array([-10, -5, -5, 0, 5, 10, 10, 15, 15, 20], dtype=float)
    t, heard, pos, _ = _fake_track(model, np.column_stack([az, pitch, roll]), per_window=1)
    got = op.orientation_path(model, t, heard, pos, 1.5, 1.0)
    assert np.allclose(got, np.column_stack([az, pitch, roll]), atol=1e-9)
    assert got[:, 0].min() >= 0.0 and got[:, 0].max() < 360.0


def test_a_frozen_pitch_and_a_full_circle_roll():
    """A point pitch support gives that pitch everywhere; a roll arc of the whole circle
    is searched around it (through ±180°) and returned in (−180°, 180°]."""
    model = _FakeModel((20.0, 20.0, 0.0, 180.0))
    cells = np.column_stack([np.full(6, 100.0), np.full(6, 20.0),
                             [170, 175, 180, -175, -170, -165]])  # fmt: skip
    t, heard, pos, _ = _fake_track(model, cells, per_window=1)
    got = op.orientation_path(model, t, heard, pos, 1.5, 1.0)
    assert np.all(got[:, 1] == 20.0)
    want = np.array([170, 175, 180, -175, -170, -165], dtype=float)
    assert np.allclose(got[:, 2], want, atol=1e-9)
    assert got[:, 2].min() > -180.0 and got[:, 2].max() <= 180.0


def test_bad_input_is_a_one_line_error():
    model = _FakeModel((0.0, 90.0, 0.0, 45.0))
    t, heard, pos, _ = _fake_track(model, np.array([[0.0, 30.0, 0.0]] * 3))
    bad_pos = pos.copy()
    bad_pos[1, 0] = math.nan
    for args in (
        (t[:-1], heard, pos, 0.0, 1.0),  # lengths differ
        (t, heard, bad_pos, 0.0, 1.0),  # NaN position
        (t[::-1], heard, pos, 0.0, 1.0),  # time going backwards
        (t, heard, pos, math.nan, 1.0),  # offset
        (t, heard, pos, 0.0, 0.0),  # σ
        ([], [], np.zeros((0, 3)), 0.0, 1.0),  # empty
    ):
        with pytest.raises(InputError) as exc:
            op.orientation_path(model, *args)
        assert "\n" not in str(exc.value) and "orientation_path" in str(exc.value)


@pytest.fixture(scope="module")
def scene():
    sim = simulate_handheld(
        replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=2.0), seed=18020
    )
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    p3 = Pose3dConfig()
    model = FilterModel3d.build3d(sim.site, space, p3)
    obs = group_packets(sim.packets)
    records = [(o.timestamp_s, space.heard(o), i) for i, o in enumerate(obs)]
    idx = np.searchsorted(sim.truth.timestamp_s, [o.timestamp_s for o in obs])
    return model, p3, records, sim.truth.position_m[idx], sim.truth.orientation_deg[idx]


def test_the_true_positions_give_the_true_orientations(scene):
    """σ 1 dB, 6 receivers: within the 5° grid (measured 3.3° mean, 9.2° at most); no
    orientation goes in."""
    model, _, records, pos, ori = scene
    t = np.array([r[0] for r in records])
    got = op.orientation_path(model, t, [r[1] for r in records], pos, 0.0, 1.0)
    err = orientation_error_deg(got, ori)
    assert err.mean() < 6.0 and err.max() < 20.0


def _refine(scene, start_ori, **kwargs):
    model, p3, records, pos, _ = scene
    est = [(i, FilterEstimate(tuple(p), tuple(o), 0.1, 1.0, 0.0, 1.0))
           for i, (p, o) in enumerate(zip(pos, start_ori, strict=True))]  # fmt: skip
    out = r3.refine_smoothed(
        model, records, est, FilterConfig(), p3.height_noise_mps, p3.tilt_noise_dps,
        p3.refine_max_nfev, height_accel_noise_mps2=p3.refine_height_accel_noise_mps2,
        tilt_accel_noise_dps2=p3.refine_tilt_accel_noise_dps2,
        polish_starts=p3.refine_polish_starts, polish_margin=p3.refine_polish_margin,
        polish_switch=p3.refine_polish_switch, **kwargs,
    )  # fmt: skip
    return np.array([e.orientation_deg for _, e in out])


def test_a_half_turned_track_is_recovered_only_with_the_path(scene):
    """The start turned 180° in azimuth over its second second: the refinement keeps a
    wrong track (measured 76.5° mean), the orientation path's start takes it back
    (12.5°)."""
    *_, ori = scene
    bent = ori.copy()
    half = len(bent) // 2
    bent[half:, 0] = (bent[half:, 0] + 180.0) % 360.0
    off = orientation_error_deg(_refine(scene, bent), ori).mean()
    on = orientation_error_deg(_refine(scene, bent, orientation_path=True), ori).mean()
    assert off > 45.0 and on < 25.0


def test_the_path_replaces_the_kept_track_only_when_clearly_lower(scene, monkeypatch):
    """A fake solve: the path's start (recognised by its orientations) ends ``gain`` below
    the kept track's objective; it is kept at a gain of 6 and not at 4 (the switch is
    5), and without the option the path is never searched."""
    *_, ori = scene
    marker = np.tile([123.0, 45.0, 0.0], (len(ori), 1))
    calls: list[int] = []

    def fake_path(model, t, heard, pos, off, sigma):
        calls.append(1)
        return marker

    gain = [0.0]

    def fake_refine(model, t, heard, pos, o, off, sigma, prior, **kw):
        from_path = np.allclose(np.asarray(o)[:, 0], 123.0)
        cost = 100.0 - (gain[0] if from_path else 0.0)
        return r3.RefinedTrack(np.asarray(pos), np.asarray(o), off, sigma, cost, cost, 1)

    monkeypatch.setattr(op, "orientation_path", fake_path)
    monkeypatch.setattr(r3, "refine_track", fake_refine)
    for g, switched in ((6.0, True), (4.0, False)):
        gain[0] = g
        got = _refine(scene, ori, orientation_path=True)
        assert np.allclose(got[:, 0], 123.0) is switched
    assert len(calls) == 2
    _refine(scene, ori)
    assert len(calls) == 2


def test_the_setting_reads_and_a_bad_value_is_a_one_line_error(tmp_path: Path):
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\nrefine_orientation_path = true\n")
    assert read_tracker_settings(p).pose3d().refine_orientation_path is True
    p.write_text("[filter.pose3d]\nrefine_orientation_path = 1\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    assert exc.value.column == "filter.pose3d.refine_orientation_path"
    assert "\n" not in str(exc.value)


def test_locate_hands_the_setting_to_the_refinement_offline_only(monkeypatch):
    """``Pose3dConfig.refine_orientation_path`` reaches ``refine_smoothed`` from batch
    ``locate``; the causal filter (no smoothing lag) never refines."""
    sim = simulate_handheld(replace(HandheldConfig(), n_receivers=6, duration_s=0.3), seed=18022)
    seen: list[bool] = []
    real = r3.refine_smoothed

    def spy(*args, orientation_path=False, **kwargs):
        seen.append(orientation_path)
        return real(*args, orientation_path=orientation_path, **kwargs)

    monkeypatch.setattr(r3, "refine_smoothed", spy)
    base = TrackerConfig()
    for on in (False, True):
        cfg = replace(base, pose3d=replace(base.pose3d, refine_orientation_path=on,
                                           refine_escalate_ratio=0.0))  # fmt: skip
        locate(sim.site, sim.packets, "filter", cfg)
        assert seen[-1] is on
    n = len(seen)
    causal = replace(base, smoothing_lag_s=None,
                     pose3d=replace(base.pose3d, refine_orientation_path=True))  # fmt: skip
    locate(sim.site, sim.packets, "filter", causal)
    assert len(seen) == n
