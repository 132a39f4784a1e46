"""Batch MAP refinement of a 3-D track (radiopose.filtering.refine3d; docs/pose3d.md,
"Batch refinement (offline)"): a perturbed truth recovered on a noise-free scene,
the motion prior's part, the site's support, offline only, bad inputs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from filter_support import SCENE_3D, SEED_3D, refine_scene_3d
from radiopose.errors import InputError
from radiopose.evaluate.pose3d import axis_errors_of
from radiopose.filtering import FilterConfig
from radiopose.filtering.particle3d import FilterModel3d, Pose3dConfig
from radiopose.filtering.refine3d import MotionPrior, refine_track
from radiopose.likelihood import HeardRss, candidate_space
from radiopose.packets import group_packets
from radiopose.simulate.handheld import simulate_handheld
from radiopose.tracker import TrackerConfig, locate

SCENE, SEED = SCENE_3D, SEED_3D  # filter_support's noise-free 3-D scene


@pytest.fixture(scope="module")
def scene():
    return refine_scene_3d()


def _errors(res, sim):
    return axis_errors_of(
        res.position_m, res.orientation_deg, sim.truth.position_m, sim.truth.orientation_deg
    )


def test_a_perturbed_truth_is_recovered_noise_free(scene):
    """The truth moved by 0.2 m and 5° on every axis and the offset by 0.5 dB:
    the refinement brings it back to centimetres and a fraction of a degree."""
    sim, model, t, heard, prior = scene
    pos = sim.truth.position_m + np.array([0.2, -0.2, 0.1])
    ori = sim.truth.orientation_deg + np.array([5.0, -5.0, 5.0])
    start = axis_errors_of(pos, ori, sim.truth.position_m, sim.truth.orientation_deg)
    assert start.position_m.mean() > 0.25 and start.rotation_deg.mean() > 7.0
    res = refine_track(model, t, heard, pos, ori, 0.5, 0.5, prior, max_nfev=100)
    e = _errors(res, sim)
    assert e.position_m.mean() < 0.08
    assert e.rotation_deg.mean() < 1.0
    assert abs(res.offset_db) < 0.3
    assert res.cost < res.initial_cost
    # inside the site's support (bounds of the solve), angles in their ranges
    box, zb = model.box_m, model.z_box_m
    assert np.all((res.position_m[:, 0] >= box[0]) & (res.position_m[:, 0] <= box[1]))
    assert np.all((res.position_m[:, 2] >= zb[0]) & (res.position_m[:, 2] <= zb[1]))
    assert np.all((res.orientation_deg[:, 0] >= 0) & (res.orientation_deg[:, 0] < 360))
    assert np.all(np.abs(res.orientation_deg[:, 1]) < 90.0)


def test_without_the_motion_prior_jittered_packets_stay_off(scene):
    """The truth with independent jitter per packet (0.2 m, 5°): with the motion
    prior every packet comes back (worst < 0.2 m, < 3°); without it (each packet
    fitted alone) some packets settle on another pose that fits them."""
    sim, model, t, heard, prior = scene
    rng = np.random.default_rng(1)
    pos = sim.truth.position_m + rng.normal(0.0, 0.2, sim.truth.position_m.shape)
    ori = sim.truth.orientation_deg + rng.normal(0.0, 5.0, sim.truth.orientation_deg.shape)
    with_prior = _errors(refine_track(model, t, heard, pos, ori, 0.5, 0.5, prior), sim)
    assert with_prior.position_m.max() < 0.2 and with_prior.rotation_deg.max() < 3.0
    alone = _errors(refine_track(model, t, heard, pos, ori, 0.5, 0.5, None), sim)
    assert alone.position_m.max() >= 0.2 or alone.rotation_deg.max() >= 3.0


def test_pitch_stays_off_the_gimbal(scene):
    """A start at pitch 90° (the site's pitch support reaches it) comes back
    inside (−90°, 90°): the solve's bound keeps pitch 0.01° off the pole."""
    sim, model, t, heard, prior = scene
    assert math.degrees(model.tilt_rad[1]) >= 90.0
    ori = sim.truth.orientation_deg.copy()
    ori[:, 1] = 90.0
    res = refine_track(model, t[:20], heard[:20], sim.truth.position_m[:20], ori[:20], 0.0, 0.5,
                       prior, max_nfev=5)  # fmt: skip
    assert np.all(res.orientation_deg[:, 1] <= 90.0 - 0.009)


def test_refinement_runs_offline_only(monkeypatch):
    """``locate`` with the smoothing lag refines (once per track); the causal filter
    (no lag) and ``refine = False`` never do; the refined estimates are what
    ``locate`` returns."""
    import radiopose.filtering.refine3d as r3

    sim = simulate_handheld(replace(SCENE, n_receivers=6, duration_s=0.3), seed=SEED)
    calls: list[int] = []
    real = r3.refine_track

    def spy(*args, **kwargs):
        calls.append(len(args[1]))
        res = real(*args, **kwargs)
        return replace(res, position_m=res.position_m * 0 + 1.234)  # a mark to find

    monkeypatch.setattr(r3, "refine_track", spy)
    off = locate(sim.site, sim.packets, "filter", TrackerConfig())
    n_members = len(Pose3dConfig().offset_bank_db)
    n = len(group_packets(sim.packets))
    polish = Pose3dConfig().refine_polish_starts  # the constant-rate prior's polish (default on)
    assert polish == 5
    # the chosen track, each member's (a member's track equal to the chosen one
    # is refined once), the reversed pass's track, the coarse HMM's path, at
    # most one hybrid start spliced from them, then up to five distinct
    # refined tracks polished with the constant-rate prior, then the orientation
    # path's start and its polish
    assert calls and set(calls) == {n}
    assert 3 + n_members + 2 <= len(calls) <= 4 + n_members + polish + 2
    assert np.all(off.estimates.position_m == 1.234)
    calls.clear()
    one = TrackerConfig()
    one = replace(
        one,
        pose3d=replace(one.pose3d, refine_from_members=False, refine_reverse_pass=False,
                       refine_coarse_path=False, refine_orientation_path=False),
    )  # fmt: skip
    locate(sim.site, sim.packets, "filter", one)
    assert calls == [n, n]  # the chosen track, then its polish
    calls.clear()
    locate(sim.site, sim.packets, "filter",
           replace(one, pose3d=replace(one.pose3d, refine_orientation_path=True)))  # fmt: skip
    assert calls == [n, n, n, n]  # … then the orientation path's start and its polish
    calls.clear()
    locate(sim.site, sim.packets, "filter",
           replace(one, pose3d=replace(one.pose3d, refine_coarse_path=True)))  # fmt: skip
    # the chosen track and the coarse path's, at most one hybrid, 1–2 polished
    assert 3 <= len(calls) <= 5 and set(calls) == {n}
    calls.clear()
    walks = replace(one, pose3d=replace(one.pose3d, refine_tilt_accel_noise_dps2=0.0,
                                        refine_height_accel_noise_mps2=0.0))  # fmt: skip
    locate(sim.site, sim.packets, "filter", walks)
    assert calls == [n]  # the random walks only: no polish
    calls.clear()
    causal = locate(sim.site, sim.packets, "filter", TrackerConfig(smoothing_lag_s=None))
    assert calls == [] and len(causal.estimates) > 0
    cfg = TrackerConfig()
    cfg = replace(cfg, pose3d=replace(cfg.pose3d, refine=False))
    plain = locate(sim.site, sim.packets, "filter", cfg)
    assert calls == [] and not np.any(plain.estimates.position_m == 1.234)


def _one():
    return HeardRss(np.array([0, 1]), np.array([-50.0, -60.0]))


@pytest.mark.parametrize(
    ("n_times", "n_heard", "n_poses", "change", "match"),
    [
        (0, 0, 0, {}, "empty"),
        (2, 1, 2, {}, "one row per packet"),
        (2, 2, 3, {}, "one row per packet"),
        (2, 2, 2, {"times": [1.0, 0.5]}, "backwards"),
        (2, 2, 2, {"nan": True}, "non-finite"),
        (2, 2, 2, {"sigma": 0.0}, "σ"),
        (2, 2, 2, {"offset": math.inf}, "offset"),
    ],
)
def test_bad_inputs_are_one_line_errors(scene, n_times, n_heard, n_poses, change, match):
    _, model, _, _, prior = scene
    t = change.get("times", list(np.arange(n_times) * 0.01))
    pos = np.ones((n_poses, 3))
    if change.get("nan"):
        pos[0, 0] = math.nan
    ori = np.zeros((n_poses, 3))
    with pytest.raises(InputError, match=match) as exc:
        refine_track(model, t, [_one()] * n_heard, pos, ori, change.get("offset", 0.0),
                     change.get("sigma", 1.0), prior)  # fmt: skip
    assert "\n" not in str(exc.value)


def test_the_hybrid_start_splices_the_right_halves(scene):
    """Two starts, each 1.5 m and 120° of azimuth off in one half of the walk
    (the other half true): refined alone, each keeps its wrong half's mode;
    the hybrid start, spliced per 0.25 s from their refined tracks where each
    fits the data best, refines to the truth."""
    from radiopose.filtering import FilterEstimate
    from radiopose.filtering.refine3d import refine_smoothed

    sim, model, t, heard, _ = scene
    tp, to = sim.truth.position_m, sim.truth.orientation_deg
    late = t - t[0] >= 0.5

    def start(bad):
        pos, ori = tp.copy(), to.copy()
        pos[bad] += np.array([1.5, -1.5, 0.0])
        ori[bad, 0] += 120.0
        return [((i,), FilterEstimate(tuple(pos[i]), tuple(ori[i]), 0.1, 1.0, 0.0, 0.5))
                for i in range(t.size)]  # fmt: skip

    records = [(t[i], heard[i], (i,)) for i in range(t.size)]
    p3 = Pose3dConfig()
    errors = {}
    for segment_s in (0.0, 0.25):
        out = refine_smoothed(
            model, records, start(~late), FilterConfig(), p3.height_noise_mps,
            p3.tilt_noise_dps, 100, alternatives=[start(late)], hybrid_segment_s=segment_s,
        )  # fmt: skip
        pos = np.array([e.position_m for _, e in out])
        ori = np.array([e.orientation_deg for _, e in out])
        errors[segment_s] = axis_errors_of(pos, ori, tp, to)
    assert errors[0.25].position_m.mean() < 0.1 and errors[0.25].rotation_deg.mean() < 2.0
    assert errors[0.0].position_m.mean() > 0.3 and errors[0.0].rotation_deg.mean() > 20.0


def test_the_constant_rate_prior_charges_rate_changes_not_rates():
    """With ``height_accel_noise_mps2`` and ``tilt_accel_noise_dps2`` > 0 (the
    refinement's own prior, docs/pose3d.md "Refinement prior, 2026-11-26"), a
    steady climb and steady pitch and roll rates cost nothing (the random walks
    charge them) and a change of rate is charged (the random walks do not see
    it beyond its steps); wrapped roll differences are scaled by the tilt
    density."""
    from radiopose.filtering.refine3d import _POSE, _Prior

    t = np.arange(50) * 0.005
    n = t.size
    rw = MotionPrior(1.0, 90.0, 0.2, 20.0)
    rate = replace(rw, height_accel_noise_mps2=1.0, tilt_accel_noise_dps2=400.0)
    X = np.zeros((n, _POSE))
    X[:, 2] = 1.0 + 0.3 * t  # m, 0.3 m/s
    X[:, 4] = np.radians(40.0 + 30.0 * t)  # 30°/s
    X[:, 5] = np.radians(170.0 + 40.0 * t)  # crosses ±180°: wrapped
    X[:, 5] = (X[:, 5] + np.pi) % (2 * np.pi) - np.pi
    x = np.concatenate([X.ravel(), [0.0]])
    steady_rw = _Prior(t, rw, x.size).residuals(x)
    steady_rate = _Prior(t, rate, x.size).residuals(x)
    assert np.abs(steady_rw).max() > 0.1
    assert np.abs(steady_rate).max() < 1e-6
    # a kink of 60°/s in pitch half-way: one velocity change of 60°/s · √(3/(2·5 ms))
    Y = X.copy()
    Y[n // 2 :, 4] += np.radians(60.0) * (t[n // 2 :] - t[n // 2])
    y = np.concatenate([Y.ravel(), [0.0]])
    kink = _Prior(t, rate, y.size).residuals(y)
    expect = 60.0 / (400.0 * math.sqrt(2 * 0.005 / 3.0))
    assert np.abs(kink).max() == pytest.approx(expect, rel=1e-6)


def test_the_constant_rate_tilt_prior_keeps_a_noisy_refinement_near_the_truth():
    """σ = 1 dB, 6 receivers, a 2 s walk, started at the truth: with the filter's
    random walks the MAP wanders off the smooth truth in pitch and roll; the
    constant-rate prior (1 m/s²·√s, 400 °/s²·√s) stays markedly closer (the
    oracle rows of docs/pose3d.md, "Refinement prior, 2026-11-26")."""
    sim = simulate_handheld(
        replace(SCENE, n_receivers=6, noise_db=1.0, duration_s=2.0), seed=SEED + 1
    )
    site = sim.site
    space = candidate_space(site, site.devices[0].transmitter)
    model = FilterModel3d.build3d(site, space, Pose3dConfig())
    obs = group_packets(sim.packets)
    heard = [space.heard(o) for o in obs]
    t = np.array([o.timestamp_s for o in obs])
    tp, to = sim.truth.position_m, sim.truth.orientation_deg
    rw = MotionPrior.of_filter(FilterConfig(), 0.2, 20.0)
    rate = MotionPrior.of_filter(FilterConfig(), 0.2, 20.0, 1.0, 400.0)
    e = {}
    for name, prior in (("rw", rw), ("rate", rate)):
        res = refine_track(model, t, heard, tp, to, 0.0, 1.0, prior, max_nfev=100)
        e[name] = axis_errors_of(res.position_m, res.orientation_deg, tp, to)
    # measured: rotation 4.4° → 3.2°, roll 5.3° → 2.2°
    assert e["rw"].rotation_deg.mean() > 3.9 and e["rw"].roll_deg.mean() > 4.5
    assert e["rate"].rotation_deg.mean() < 3.6 and e["rate"].roll_deg.mean() < 3.0


def test_locate_hands_the_refinement_prior_to_the_solve(monkeypatch):
    """``refine_height_accel_noise_mps2`` and ``refine_tilt_accel_noise_dps2`` of
    ``[filter.pose3d]`` reach the solve: with ``refine_polish_starts = 1`` every
    start is refined with the random walks, then the best one once more with the
    constant-rate prior (and that is what ``locate`` returns); with 0 every start
    uses the constant-rate prior; the random-walk densities stay the filter's."""
    import radiopose.filtering.refine3d as r3

    sim = simulate_handheld(replace(SCENE, n_receivers=6, duration_s=0.2), seed=SEED)
    seen: list[MotionPrior] = []
    real = r3.refine_track

    def spy(*args, **kwargs):
        seen.append(args[7])
        res = real(*args, **kwargs)
        if args[7].tilt_accel_noise_dps2 > 0:
            return replace(res, position_m=res.position_m * 0 + 1.234)  # a mark to find
        return res

    monkeypatch.setattr(r3, "refine_track", spy)
    cfg = TrackerConfig()
    # (the orientation path's start, refined after the mode choice, is off here:
    # tests/test_orientation_path.py)
    p3 = replace(cfg.pose3d, refine_height_accel_noise_mps2=1.5, refine_tilt_accel_noise_dps2=300.0,
                 refine_polish_starts=1, refine_orientation_path=False)  # fmt: skip
    out = locate(sim.site, sim.packets, "filter", replace(cfg, pose3d=p3))
    rates = [(p.height_accel_noise_mps2, p.tilt_accel_noise_dps2) for p in seen]
    n_starts = len(seen) - 1
    assert n_starts >= len(p3.offset_bank_db)  # (a member's track equal to the chosen: once)
    assert rates == [(0.0, 0.0)] * n_starts + [(1.5, 300.0)]
    assert np.all(out.estimates.position_m == 1.234)
    assert all((p.height_noise_mps, p.tilt_noise_dps) == (0.2, 20.0) for p in seen)
    seen.clear()
    direct = replace(p3, refine_polish_starts=0)
    locate(sim.site, sim.packets, "filter", replace(cfg, pose3d=direct))
    assert len(seen) == n_starts
    assert all((p.height_accel_noise_mps2, p.tilt_accel_noise_dps2) == (1.5, 300.0) for p in seen)
    with pytest.raises(InputError, match="refine_tilt_accel_noise_dps2"):
        Pose3dConfig(refine_tilt_accel_noise_dps2=-1.0)
    with pytest.raises(InputError, match="refine_polish_starts"):
        Pose3dConfig(refine_polish_starts=-1)


def _mode_choice(monkeypatch, polish_starts: int, polish_margin: float, switch: float = 0.0):
    """:func:`refine_smoothed` over a fake solve (docs/pose3d.md, "Mode choice,
    2026-11-27"): the starts are the chosen track A, member tracks A (identical),
    C (A 5 cm away: the same mode), B (1 m away) and D (3 m away). The fake
    solve returns its start with an objective per mode and prior: under the
    random walks A 100, C 100.5, B 105, D 200; under the constant-rate prior
    A 150, C 150, B 140, D 100. Returns the kept track's x and the solves made
    as ``(mode, prior kind)``."""
    import radiopose.filtering.refine3d as r3
    from radiopose.filtering.config import FilterEstimate

    n = 12
    t = np.arange(n) * 0.005
    heard = HeardRss(np.array([0, 1]), np.array([-50.0, -60.0]))
    records = [(float(ti), heard, i) for i, ti in enumerate(t)]

    def track(x_m: float) -> list[tuple[object, FilterEstimate]]:
        return [(i, FilterEstimate((x_m, 1.0, 1.2), (10.0, 40.0, 0.0), 0.1, 1.0, 0.0, 1.0))
                for i in range(n)]  # fmt: skip

    modes = {0.0: "A", 0.05: "C", 1.0: "B", 3.0: "D"}
    walk_cost = {"A": 100.0, "C": 100.5, "B": 105.0, "D": 200.0}
    rate_cost = {"A": 150.0, "C": 150.0, "B": 140.0, "D": 100.0}
    calls: list[tuple[str, str]] = []

    def fake(model, times, h, pos, ori, off, sigma, prior, **kw):
        mode = modes[round(float(pos[0, 0]), 2)]
        rate = prior.tilt_accel_noise_dps2 > 0
        calls.append((mode, "rate" if rate else "walk"))
        cost = (rate_cost if rate else walk_cost)[mode]
        return r3.RefinedTrack(np.array(pos), np.array(ori), off, sigma, cost, cost, 1)

    monkeypatch.setattr(r3, "refine_track", fake)
    alts = [track(0.0), track(0.05), track(1.0), track(3.0)]
    out = r3.refine_smoothed(
        None, records, track(0.0), FilterConfig(), 0.2, 20.0, 10, alternatives=alts,
        hybrid_segment_s=0.0, height_accel_noise_mps2=1.0, tilt_accel_noise_dps2=400.0,
        polish_starts=polish_starts, polish_margin=polish_margin, polish_switch=switch,
    )  # fmt: skip
    return out[0][1].position_m[0], calls


def test_the_polish_takes_distinct_modes_within_the_margin(monkeypatch):
    """The chosen member's own track is refined once; the polish skips a refined
    track of the same mode (C beside A), stops at the margin and at the count,
    and keeps the lowest constant-rate objective among the polished unless the
    lowest random-walk track's polish is within the switch of it."""
    walks = [("A", "walk"), ("C", "walk"), ("B", "walk"), ("D", "walk")]
    x, calls = _mode_choice(monkeypatch, 1, 1e9)  # the default before 2026-11-27
    assert calls == [*walks, ("A", "rate")] and x == 0.0
    x, calls = _mode_choice(monkeypatch, 3, 10.0)  # C is A's mode, D beyond the margin
    assert calls == [*walks, ("A", "rate"), ("B", "rate")] and x == 1.0
    x, calls = _mode_choice(monkeypatch, 3, 1e9)
    assert calls == [*walks, ("A", "rate"), ("B", "rate"), ("D", "rate")] and x == 3.0
    x, calls = _mode_choice(monkeypatch, 2, 1e9)  # the count caps the distinct modes
    assert calls == [*walks, ("A", "rate"), ("B", "rate")] and x == 1.0
    x, calls = _mode_choice(monkeypatch, 3, 0.0)
    assert calls == [*walks, ("A", "rate")] and x == 0.0
    # the switch: B (140) replaces A's polish (150) only when lower by more than it
    x, calls = _mode_choice(monkeypatch, 3, 10.0, switch=5.0)
    assert calls == [*walks, ("A", "rate"), ("B", "rate")] and x == 1.0
    x, _ = _mode_choice(monkeypatch, 3, 10.0, switch=15.0)
    assert x == 0.0
    x, _ = _mode_choice(monkeypatch, 3, 1e9, switch=15.0)  # D (100) is lower by 50
    assert x == 3.0
    with pytest.raises(InputError, match="refine_polish_margin"):
        Pose3dConfig(refine_polish_margin=-1.0)
    with pytest.raises(InputError, match="refine_polish_margin"):
        Pose3dConfig(refine_polish_margin=math.nan)
    with pytest.raises(InputError, match="refine_polish_switch"):
        Pose3dConfig(refine_polish_switch=-1.0)
