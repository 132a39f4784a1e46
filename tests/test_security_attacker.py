"""The attacker model on tiny sites whose answer is known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from radiopose.likelihood import ReferenceScorer, candidate_space, expected_rss_dbm
from radiopose.patterns import Pattern
from radiopose.patterns.synthetic import isotropic, smartphone_like
from radiopose.security.attacker import (
    AttackerModel,
    MotionLimits,
    attacker_space,
    best_power_mse_db2,
    brute_force_matches,
    build_match_table,
    find_matches,
    sustain_path,
    system_scorer,
    system_threshold_db2,
)
from radiopose.simulate import LogDistance, ScenarioConfig, link_rss_dbm, simulate
from radiopose.site import (
    AreaGrid,
    Device,
    OrientationGrid,
    Receiver,
    SurveyConfig,
    SurveyRows,
    assemble_site,
)

TX = "02:00:00:00:00:01"


def tiny_site(rx_xy, device_pattern, azimuth_step_deg=30.0, size_m=10.0, step_m=0.5):
    """A hand-built site: isotropic receivers at ``rx_xy``, a noise-free 1 m survey."""
    z = 1.0
    d = device_pattern
    pats = {
        "iso": isotropic("iso"),
        "device": Pattern("device", d.azimuth_deg, d.polar_deg, d.directivity_dbi),
    }
    receivers = tuple(
        Receiver(f"rx{i}", float(x), float(y), z, 0.0, 0.0, 0.0, "iso")
        for i, (x, y) in enumerate(rx_xy)
    )
    axis = np.arange(0.0, size_m + 1e-9, 1.0)
    sx, sy = np.meshgrid(axis, axis, indexing="ij")
    pts = np.column_stack([sx.ravel(), sy.ravel(), np.full(sx.size, z)])
    rx_xyz = np.array([[r.x_m, r.y_m, z] for r in receivers])
    rss = link_rss_dbm(
        LogDistance(),
        pts,
        np.zeros_like(pts),
        pats["iso"],
        20.0,
        rx_xyz,
        np.zeros_like(rx_xyz),
        (pats["iso"],) * len(receivers),
    )
    k = len(receivers)
    rows = SurveyRows(
        xyz_m=np.repeat(pts, k, axis=0),
        receiver_id=np.array([r.receiver_id for r in receivers] * len(pts), dtype=object),
        rss_dbm=rss.reshape(-1),
        orientation_deg=np.zeros((len(pts) * k, 3)),
    )
    site = assemble_site(
        "tiny",
        AreaGrid(0.0, size_m, 0.0, size_m, z, step_m),
        OrientationGrid(azimuth_step_deg),
        SurveyConfig(20.0, "iso"),
        receivers,
        (Device(TX, "device", 15.0),),
        pats,
        rows,
    )
    return candidate_space(site, TX)


def _target(space, x, y, az_index=0):
    pos = int(np.flatnonzero(np.all(np.isclose(space.positions_m[:, :2], [x, y]), axis=1))[0])
    cand = pos * space.n_orientations + az_index
    rss = expected_rss_dbm(space, np.array([pos]), np.array([az_index]))[0]
    return cand, rss, space.positions_m[pos]


def _matches(space, x, y, model, attacker_pattern=None):
    _, rss, pos = _target(space, x, y)
    tau = system_threshold_db2(system_scorer(space), rss, model.k)
    table = build_match_table(attacker_space(space, attacker_pattern))
    return find_matches(table, rss, tau, pos, model), tau, rss, pos


# ----------------------------------------------------------------------------- kernels
def test_best_power_is_the_clipped_mean_residual():
    rng = np.random.default_rng(5)
    e = rng.normal(0.0, 3.0, (40, 4)) + rng.uniform(-15, 15, (40, 1))
    mse, off = best_power_mse_db2(e, 6.0)
    grid = np.linspace(-6.0, 6.0, 24_001)  # 0.0005 dB steps
    for row, m, o in zip(e, mse, off, strict=True):
        brute = np.mean((row[None, :] - grid[:, None]) ** 2, axis=1)
        assert m <= brute.min() + 1e-12  # never worse than any power in range
        assert abs(o - grid[np.argmin(brute)]) <= 0.0005
    assert np.all(np.abs(off) <= 6.0)


def test_zero_power_range_is_the_plain_mse():
    e = np.array([[1.0, -2.0, 3.0], [0.5, 0.5, 0.5]])
    mse, off = best_power_mse_db2(e, 0.0)
    np.testing.assert_allclose(mse, np.mean(e**2, axis=1))
    np.testing.assert_array_equal(off, 0.0)


# ----------------------------------------------------------------------------- known answers
def test_symmetric_layout_with_isotropic_pattern_gives_mirror_matches():
    # Receivers on the line x = 5: (x, y) and (10 − x, y) see identical RSS.
    space = tiny_site([(5.0, 1.0), (5.0, 5.5), (5.0, 9.0)], isotropic())
    model = AttackerModel(min_distance_m=3.0, power_range_db=10.0, k=100)
    res, tau, _, _ = _matches(space, 2.0, 3.0, model)
    assert tau > 0
    pos = space.candidate_positions_m(res.candidate_idx)
    mirror = np.all(np.isclose(pos[:, :2], [8.0, 3.0]), axis=1)
    # every orientation of the mirror position matches (isotropic), with MSE ~ 0 …
    assert mirror.sum() == space.n_orientations
    assert np.all(res.mse_db2[: mirror.sum()] < 1e-9)
    assert np.all(mirror[: mirror.sum()])  # the exact mirror ranks first
    # every other match is a worse fit on the mirror side (the target's side is within d).
    assert np.all(res.mse_db2[mirror.sum() :] > 1e-6)
    assert np.all(pos[:, 0] > 5.0)


def test_asymmetric_pattern_with_many_receivers_gives_no_match():
    rx = [
        (0.5, 0.5),
        (9.5, 0.8),
        (9.2, 9.5),
        (0.7, 9.0),
        (5.0, 0.2),
        (9.8, 5.3),
        (4.6, 9.9),
        (0.1, 4.4),
    ]
    pattern = smartphone_like(np.random.default_rng(11), range_db=20.0, azimuth_step_deg=1.0)
    # Azimuths fine enough that the top k are the target's own neighbourhood.
    space = tiny_site(rx, pattern, azimuth_step_deg=1.0)
    model = AttackerModel(min_distance_m=3.0, power_range_db=10.0, k=10)
    for x, y in [(2.0, 3.0), (7.5, 6.0), (5.0, 5.0), (3.0, 8.0), (1.0, 1.0), (8.0, 2.0)]:
        res, tau, _, _ = _matches(space, x, y, model)
        assert 0 < tau < 2.0
        assert not res.any, (x, y, res.mse_db2[:3], tau)


def test_same_site_symmetric_layout_but_asymmetric_pattern_still_matches_somewhere():
    # The mirror position with a mirrored orientation need not exist for an arbitrary
    # pattern; this only checks the search runs and respects d.
    pattern = smartphone_like(np.random.default_rng(3), range_db=18.0)
    space = tiny_site([(5.0, 1.0), (5.0, 5.5), (5.0, 9.0)], pattern, azimuth_step_deg=10.0)
    model = AttackerModel(min_distance_m=3.0)
    res, _, _, tpos = _matches(space, 2.0, 3.0, model)
    pos = space.candidate_positions_m(res.candidate_idx)
    assert np.all(np.linalg.norm(pos - tpos, axis=1) >= 3.0 - 1e-9)


# ----------------------------------------------------------------------------- exactness
@pytest.fixture(scope="module")
def sim_space():
    sim = simulate(
        ScenarioConfig(
            size_m=8.0,
            step_m=0.25,
            azimuth_step_deg=10.0,
            duration_s=0.005,
            min_receiver_spacing_m=2.5,
        ),
        seed=21,
    )
    return candidate_space(sim.site, sim.site.devices[0].transmitter)


@pytest.mark.parametrize("other_pattern", [False, True])
def test_screened_search_equals_brute_force(sim_space, other_pattern):
    rng = np.random.default_rng(8)
    space = sim_space
    pattern = smartphone_like(rng, "attacker") if other_pattern else None
    att = attacker_space(space, pattern)
    table = build_match_table(att)
    scorer = ReferenceScorer(space)
    model = AttackerModel(min_distance_m=2.0, power_range_db=6.0, k=50)
    n_any = 0
    for cand in rng.integers(0, space.n_candidates, 4):
        p, o = space.split(np.array([cand]))
        rss = expected_rss_dbm(space, p, o)[0] + rng.normal(0, 0.5, space.n_receivers)
        tau = system_threshold_db2(scorer, rss, model.k)
        fast = find_matches(table, rss, tau, space.positions_m[p[0]], model)
        slow = brute_force_matches(att, rss, tau, space.positions_m[p[0]], model)
        np.testing.assert_array_equal(fast.candidate_idx, slow.candidate_idx)
        np.testing.assert_allclose(fast.mse_db2, slow.mse_db2, rtol=0, atol=0)
        np.testing.assert_allclose(fast.offset_db, slow.offset_db, rtol=0, atol=0)
        n_any += fast.any
    assert n_any >= 1  # the comparison is not vacuous


# ----------------------------------------------------------------------------- paths
DT = 0.005


def _path(n, sets):
    t = np.arange(n) * DT
    pos = [np.atleast_2d(sets(i)[0]) for i in range(n)]
    ori = [np.atleast_2d(sets(i)[1]) for i in range(n)]
    return t, pos, ori


def test_stationary_match_sustains_the_whole_path():
    t, p, o = _path(200, lambda i: ([1.0, 1.0, 1.0], [0.0, 0.0, 0.0]))
    res = sustain_path(t, p, o, MotionLimits())
    assert not res.failed
    assert res.packets_until_failure == 200 and res.sustained_packets == 200
    assert res.chain.shape == (200, 2)


def test_unreachable_jump_fails_half_a_period_after_the_last_transmission():
    def sets(i):
        x = 1.0 if i < 60 else 6.0  # a 5 m jump: 10 m/s × 0.25 s = 2.5 m is not enough
        return [x, 1.0, 1.0], [0.0, 0.0, 0.0]

    res = sustain_path(*_path(200, sets), MotionLimits())
    assert res.failed
    assert res.sustained_packets == 60
    # last transmission at packet 59 (0.295 s); silent past 0.25 s from packet 110 (0.550 s)
    assert res.packets_until_failure == 110
    np.testing.assert_array_equal(res.chain[:, 0], np.arange(60))  # transmits every packet


@pytest.mark.parametrize(("scale", "survives"), [(1.0, True), (0.1, False)])
def test_small_jump_needs_enough_speed(scale, survives):
    def sets(i):
        x = 1.0 if i < 60 else 1.5  # 0.5 m: 10 m/s needs 0.05 s; 1 m/s would need 0.5 s
        return [x, 1.0, 1.0], [0.0, 0.0, 0.0]

    res = sustain_path(*_path(200, sets), MotionLimits(scale=scale))
    assert res.failed is not survives
    if survives:
        chain_t = res.chain[:, 0] * DT
        jump = np.flatnonzero(res.chain[:, 0] >= 60)[0]
        assert chain_t[jump] - chain_t[jump - 1] >= 0.05 - 1e-12


@pytest.mark.parametrize(("turn_deg", "survives"), [(45.0, True), (100.0, False)])
def test_rotation_bound(turn_deg, survives):
    def sets(i):
        az = 350.0 if i < 60 else (350.0 + turn_deg) % 360.0  # wraps through 0
        return [1.0, 1.0, 1.0], [az, 0.0, 0.0]

    res = sustain_path(*_path(200, sets), MotionLimits())
    assert res.failed is not survives


def test_no_match_at_all_fails_after_the_initial_silence():
    t = np.arange(100) * DT
    empty = [np.zeros((0, 3))] * 100
    res = sustain_path(t, empty, empty, MotionLimits())
    assert res.failed and res.sustained_packets == 0 and res.chain.shape == (0, 2)
    assert res.packets_until_failure == 51  # 0.255 s > 0.25 s
