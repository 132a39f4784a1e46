"""The 3-D filter's offline reversed pass (radiopose.filtering.reverse.reversed_tracks3d;
docs/pose3d.md, "Reversed pass, 2026-11-27"): it tracks the time-reversed packets
(its estimates belong to the packets' own times), it reaches the refinement as
more starts only offline and only when switched on, the heading prior is off in
it, and the setting is a validated boolean.

Seeds: 424242 (tests/test_refine3d.py's noise-free scene) and 18018's small
scene; the end-to-end check uses tuning seed 7114 only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from filter_support import (
    SCENE_3D,
    SEED_3D,
    require_wrong_mode,
    scene_3d_records,
    track_axis_errors,
)
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.particle3d import ParticleFilter3d, Pose3dConfig
from radiopose.filtering.reverse import reversed_records, reversed_tracks3d
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings, write_tracker_toml

SCENE, SEED = SCENE_3D, SEED_3D  # filter_support's noise-free 3-D scene


@pytest.fixture(scope="module")
def scene():
    return scene_3d_records()


def test_the_reversed_pass_tracks_the_packets_backwards(scene):
    """On the noise-free walk the reversed pass's smoothed track (and each bank
    member's) covers every packet once under its own key and follows the truth
    at the packets' own times; read at the mirrored times instead (an estimate
    filed under the wrong packet) it is far off."""
    sim, model, p3, records = scene
    pf = ParticleFilter3d(model, FilterConfig(), 1.0, p3)
    keys = sorted(k for _, _, k in records)
    found = None
    # one pass over 1 s may end in a wrong mode, and which seed does depends on the
    # host's floating point (docs/testing.md "Host-dependent wrong modes": seed 11
    # followed the truth on earlier hosts, 0.22 m / 4.5°; on a znver3 host 13 does)
    for seed in (11, 12, 13):
        tracks = reversed_tracks3d(pf, records, seed=seed, members=True)
        assert len(tracks) == 1 + len(p3.offset_bank_db)
        for tr in tracks:
            assert sorted(k for k, _ in tr) == keys
        e = track_axis_errors(tracks[0], sim)
        if e.position_m.mean() < 0.35 and e.rotation_deg.mean() < 12.0:
            found = seed, tracks[0], e
            break
    assert found is not None, "no seed's reversed pass followed the noise-free walk"
    seed, track, e = found
    # the same estimates filed under the mirrored packet: the walk moves ~1 m in 1 s
    mirrored = [(k, est) for (k, _), (_, est) in zip(track, reversed(track), strict=True)]
    bad = track_axis_errors(mirrored, sim)
    # measured: 0.22 m / 4.5° against 0.50 m / 17.2° mirrored (seed 11, earlier
    # hosts); 0.25 m / 3.1° against 0.46 m / 16.1° (seed 13, znver3)
    assert bad.rotation_deg.mean() > e.rotation_deg.mean() + 8.0
    assert len(reversed_tracks3d(pf, records, seed=seed, members=False)) == 1
    # deterministic in its seed
    again = reversed_tracks3d(pf, records, seed=seed, members=False)[0]
    assert [est.position_m for _, est in again] == [est.position_m for _, est in track]


def test_the_reversed_records_mirror_the_times(scene):
    """``reversed_records``: the packets last first at ``t_0 + t_end − t`` (the
    3-D pass's input; the same function as the 2-D round 5)."""
    _, _, _, records = scene
    rev = reversed_records(records)
    t = np.array([r[0] for r in records])
    tr = np.array([r[0] for r in rev])
    assert np.all(np.diff(tr) >= 0)
    assert np.allclose(tr, (t[0] + t[-1] - t)[::-1])
    assert [r[2] for r in rev] == [r[2] for r in reversed(records)]


def test_locate_runs_the_reversed_pass_offline_only_when_on(monkeypatch):
    """With ``refine_reverse_pass`` the offline refinement gets the reversed pass's
    track as one more start (its members' too with ``refine_reverse_members``);
    off (the default), causal, or without the refinement it never runs; the
    reversed pass runs without the heading prior."""
    import radiopose.filtering.refine3d as r3
    import radiopose.tracker.filter as tf

    sim = simulate_handheld(replace(HandheldConfig(), n_receivers=6, duration_s=0.3), seed=SEED)
    runs: list[tuple[bool, float]] = []
    starts: list[int] = []
    real_rev, real_rs = tf.reversed_tracks3d, r3.refine_smoothed

    def rev_spy(pf, records, seed, members):
        runs.append((members, pf.pose3d.heading_prior_deg))
        out = real_rev(pf, records, seed, members)
        seen_prior.append(_heading_prior_of_last_filter[0])
        return out

    seen_prior: list[float] = []
    _heading_prior_of_last_filter = [float("nan")]
    real_init = ParticleFilter3d.__init__

    def init_spy(self, model, config, lag_s=None, pose3d=None):
        real_init(self, model, config, lag_s, pose3d)
        _heading_prior_of_last_filter[0] = self.pose3d.heading_prior_deg

    def rs_spy(*args, alternatives=(), **kwargs):
        starts.append(len(alternatives))
        return real_rs(*args, alternatives=alternatives, **kwargs)

    monkeypatch.setattr(tf, "reversed_tracks3d", rev_spy)
    monkeypatch.setattr(r3, "refine_smoothed", rs_spy)
    monkeypatch.setattr(ParticleFilter3d, "__init__", init_spy)
    n_bank = len(Pose3dConfig().offset_bank_db)
    on = TrackerConfig()
    assert on.pose3d.refine_reverse_pass  # on by default
    off = replace(on, pose3d=replace(on.pose3d, refine_reverse_pass=False))
    locate(sim.site, sim.packets, "filter", off)
    assert runs == [] and starts == [n_bank]
    locate(sim.site, sim.packets, "filter", on)
    assert runs == [(False, 0.0)] and starts[-1] == n_bank + 1
    both = replace(on, pose3d=replace(on.pose3d, refine_reverse_members=True))
    locate(sim.site, sim.packets, "filter", both)
    assert runs[-1] == (True, 0.0) and starts[-1] == 2 * n_bank + 1
    heading = replace(on, pose3d=replace(on.pose3d, heading_prior_deg=30.0))
    locate(sim.site, sim.packets, "filter", heading)
    assert runs[-1] == (False, 30.0) and seen_prior[-1] == 0.0  # off in the reversed pass
    runs.clear()
    locate(sim.site, sim.packets, "filter", replace(on, smoothing_lag_s=None))
    no_refine = replace(on, pose3d=replace(on.pose3d, refine=False))
    locate(sim.site, sim.packets, "filter", no_refine)
    assert runs == []


def test_the_setting_is_a_boolean(tmp_path: Path):
    """``refine_reverse_pass`` and ``refine_reverse_members`` read from
    ``[filter.pose3d]`` as booleans and round-trip; a number is a one-line error
    naming the key."""
    assert Pose3dConfig().refine_reverse_pass is True
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\nrefine_reverse_pass = true\nrefine_reverse_members = true\n")
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine_reverse_pass is True and cfg.refine_reverse_members is True
    q = tmp_path / "written.toml"
    write_tracker_toml(q, {}, None, "written by a test", pose3d={"refine_reverse_pass": True})
    assert read_tracker_settings(q).pose3d().refine_reverse_pass is True
    for key in ("refine_reverse_pass", "refine_reverse_members"):
        p.write_text(f"[filter.pose3d]\n{key} = 1\n")
        with pytest.raises(InputError) as exc:
            read_tracker_settings(p)
        assert exc.value.column == f"filter.pose3d.{key}" and "\n" not in str(exc.value)


def test_the_reversed_pass_leaves_a_wrong_mode():
    """Tuning seed 7114 (6 receivers, σ 1 dB, 4 s, offline): every forward start
    ends in a wrong mode (measured 16.7°, 0.50 m: a search failure, the truth's
    basin is lower); the reversed pass's track is refined into the right one
    (measured 4.2°, 0.18 m). Removing the reversed pass breaks the second bound."""
    from radiopose.evaluate.pose3d import axis_errors

    cfg = replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=4.0)
    sim = simulate_handheld(cfg, seed=7114)
    base = TrackerConfig()
    off = replace(base, pose3d=replace(base.pose3d, refine_reverse_pass=False))
    on = replace(base, pose3d=replace(base.pose3d, refine_reverse_pass=True))
    e_off = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", off).estimates)
    require_wrong_mode(e_off.rotation_deg.mean(), 12.0, "seed 7114 without the reversed pass")
    e_on = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", on).estimates)
    assert e_on.rotation_deg.mean() < 8.0 and e_on.position_m.mean() < 0.3
    assert e_on.coverage == 1.0
