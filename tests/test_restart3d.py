"""The 3-D filter's offline mid-track restarts (radiopose.filtering.restart3d;
docs/pose3d.md, "Mid-track restarts, 2026-11-27"): where the restarts begin,
that each restart's spliced track covers every packet once and follows the
truth on both sides of its point, that they reach the refinement as more starts
only offline and only when switched on, and that the settings are validated.

Seeds: 424242 (filter_support's noise-free scene) and 18018's small scene; the
end-to-end check uses tuning seed SEED_FIXED only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from filter_support import require_wrong_mode, scene_3d_records, track_axis_errors
from radiopose.errors import InputError
from radiopose.evaluate.pose3d import axis_errors
from radiopose.filtering import FilterConfig
from radiopose.filtering.particle3d import ParticleFilter3d, Pose3dConfig
from radiopose.filtering.restart3d import midtrack_tracks3d, restart_indices
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings, write_tracker_toml

SEED_FIXED = 7133
"""A tuning seed (6 receivers, σ 1 dB, 4 s) whose default track ends in a wrong
mode (the forward filter loses the track mid-way) that two mid-track restarts
fix (docs/pose3d.md, "Mid-track restarts")."""


@pytest.fixture(scope="module")
def scene():
    return scene_3d_records()


def test_restart_points_split_the_time_span():
    """``n`` restarts begin at the first packet at or after ``j/(n+1)`` of the
    span; points leaving a side empty or repeating are dropped."""
    t = np.arange(11) * 0.1  # 0 … 1 s
    assert restart_indices(t, 1) == [5]
    assert restart_indices(t, 3) == [3, 5, 8]  # 0.25 → 3 (0.3), 0.5 → 5, 0.75 → 8
    assert restart_indices(t, 0) == []
    assert restart_indices([0.0], 2) == []
    assert restart_indices([0.0, 1.0], 1) == [1]
    assert restart_indices([0.0, 1.0], 4) == [1]  # one point, not four copies
    uneven = [0.0, 0.01, 0.02, 0.9, 1.0]  # a gap: the restart begins after it
    assert restart_indices(uneven, 1) == [3]
    with pytest.raises(InputError) as exc:
        restart_indices(t, -1)
    assert "\n" not in str(exc.value)


def test_a_restart_covers_every_packet_and_follows_the_truth(scene):
    """On the noise-free walk a restart's spliced track covers every packet once
    under its own key (members' too), follows the truth on both sides of its
    point (the reversed half at the packets' own times, not mirrored) and is
    deterministic in its seed."""
    sim, model, p3, records = scene
    pf = ParticleFilter3d(model, FilterConfig(), 1.0, p3)
    tracks = midtrack_tracks3d(pf, records, seed=5, n_restarts=1, members=True)
    assert len(tracks) == 1 + len(p3.offset_bank_db)
    keys = [k for _, _, k in records]
    for tr in tracks:
        assert sorted(k for k, _ in tr) == sorted(keys)
    i = restart_indices([r[0] for r in records], 1)[0]
    chosen = dict(tracks[0])
    first = [(k, chosen[k]) for k in keys[:i]]
    second = [(k, chosen[k]) for k in keys[i:]]
    e1, e2 = track_axis_errors(first, sim), track_axis_errors(second, sim)
    assert e1.position_m.mean() < 0.5 and e1.rotation_deg.mean() < 15.0
    assert e2.position_m.mean() < 0.5 and e2.rotation_deg.mean() < 15.0
    # the first half's estimates filed under the mirrored packets are far off
    mirrored = [(k, est) for (k, _), (_, est) in zip(first, reversed(first), strict=True)]
    assert track_axis_errors(mirrored, sim).rotation_deg.mean() > e1.rotation_deg.mean() + 5.0
    two = midtrack_tracks3d(pf, records, seed=5, n_restarts=2, members=False)
    assert len(two) == 2
    again = midtrack_tracks3d(pf, records, seed=5, n_restarts=1, members=False)
    assert [e.position_m for _, e in again[0]] == [e.position_m for _, e in tracks[0]]
    assert midtrack_tracks3d(pf, records, seed=5, n_restarts=0) == []


@pytest.mark.slow  # ~30 s for an option that is off (refine_restarts = 0)
def test_locate_restarts_offline_only_when_on(monkeypatch):
    """With ``refine_restarts`` the offline refinement gets one spliced start per
    restart (with ``refine_restart_members`` also one per bank member); off (the
    default), causal, or without the refinement no restart runs; the reversed
    half runs without the heading prior."""
    import radiopose.filtering.refine3d as r3
    import radiopose.filtering.restart3d as rs

    sim = simulate_handheld(replace(HandheldConfig(), n_receivers=6, duration_s=0.3), seed=18018)
    starts: list[int] = []
    priors: list[float] = []
    real_rs, real_pass = r3.refine_smoothed, rs.pass_tracks3d

    def rs_spy(*args, alternatives=(), **kwargs):
        starts.append(len(alternatives))
        return real_rs(*args, alternatives=alternatives, **kwargs)

    def pass_spy(pf, records, seed, members, pose3d=None):
        priors.append((pose3d or pf.pose3d).heading_prior_deg)
        return real_pass(pf, records, seed, members, pose3d)

    monkeypatch.setattr(r3, "refine_smoothed", rs_spy)
    monkeypatch.setattr(rs, "pass_tracks3d", pass_spy)
    n_bank = len(Pose3dConfig().offset_bank_db)
    base = TrackerConfig()
    assert base.pose3d.refine_restarts == 0  # off by default
    fixed = 2 * n_bank if base.pose3d.refine_reverse_members else n_bank + 1
    locate(sim.site, sim.packets, "filter", base)
    assert priors == [] and starts == [fixed]
    assert not base.pose3d.refine_restart_members
    bare = replace(base, pose3d=replace(base.pose3d, refine_restarts=1))
    locate(sim.site, sim.packets, "filter", bare)
    assert len(priors) == 2 and starts[-1] == fixed + 1
    one = replace(bare, pose3d=replace(bare.pose3d, refine_restart_members=True))
    locate(sim.site, sim.packets, "filter", one)
    assert starts[-1] == fixed + 1 + n_bank
    two = replace(bare, pose3d=replace(bare.pose3d, refine_restarts=2))
    locate(sim.site, sim.packets, "filter", two)
    assert starts[-1] == fixed + 2
    heading = replace(bare, pose3d=replace(bare.pose3d, heading_prior_deg=30.0))
    priors.clear()
    locate(sim.site, sim.packets, "filter", heading)
    assert priors == [30.0, 0.0]  # forward half keeps it, reversed half runs without
    priors.clear()
    locate(sim.site, sim.packets, "filter", replace(one, smoothing_lag_s=None))
    locate(sim.site, sim.packets, "filter", replace(one, pose3d=replace(one.pose3d, refine=False)))
    assert priors == []


def test_the_settings_are_validated(tmp_path: Path):
    """``refine_restarts`` (integer 0 … 100) and ``refine_restart_members``
    (boolean) read from ``[filter.pose3d]`` and round-trip; a wrong type or
    value is a one-line error naming the key."""
    assert Pose3dConfig().refine_restarts == 0
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\nrefine_restarts = 2\nrefine_restart_members = false\n")
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine_restarts == 2 and cfg.refine_restart_members is False
    q = tmp_path / "written.toml"
    write_tracker_toml(q, {}, None, "written by a test", pose3d={"refine_restarts": 3})
    assert read_tracker_settings(q).pose3d().refine_restarts == 3
    for key, value in (
        ("refine_restarts", "-1"),
        ("refine_restarts", "101"),
        ("refine_restarts", "1.5"),
        ("refine_restarts", "true"),
        ("refine_restart_members", "1"),
    ):
        p.write_text(f"[filter.pose3d]\n{key} = {value}\n")
        with pytest.raises(InputError) as exc:
            read_tracker_settings(p)
        assert exc.value.column == f"filter.pose3d.{key}" and "\n" not in str(exc.value)
    with pytest.raises(InputError) as exc2:
        Pose3dConfig(refine_restarts=-1)
    assert "refine_restarts" in str(exc2.value)


@pytest.mark.slow  # ~60 s for an option that is off (refine_restarts = 0)
def test_a_restart_leaves_a_wrong_mode():
    """Tuning seed SEED_FIXED (6 receivers, σ 1 dB, 4 s, offline): the forward
    filter loses the track mid-way and every default start (forward, members,
    reversed pass) ends 2 m / 96° off (a search failure); with two mid-track
    restarts a spliced start refines into the right mode (measured 0.08 m /
    1.6°). Removing the restarts breaks the second bound."""
    cfg = replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=4.0)
    sim = simulate_handheld(cfg, seed=SEED_FIXED)
    base = TrackerConfig()
    on = replace(base, pose3d=replace(base.pose3d, refine_restarts=2))
    e_off = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", base).estimates)
    require_wrong_mode(e_off.rotation_deg.mean(), 50.0, f"seed {SEED_FIXED} without restarts")
    e_on = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", on).estimates)
    assert e_on.rotation_deg.mean() < 6.0 and e_on.position_m.mean() < 0.3
    assert e_on.coverage == 1.0
