"""Likelihood: the reference scorer, the numpy kernel against it, top-k selection."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.likelihood import (
    SCORERS,
    HeardRss,
    ReferenceScorer,
    TableScorer,
    candidate_mse_db2,
    candidate_space,
    exact_mse_db2,
    expected_rss_dbm,
    make_scorer,
    select_topk,
)
from radiopose.packets import PacketObservation, group_packets
from radiopose.simulate import ScenarioConfig, link_rss_dbm, simulate
from radiopose.site import OrientationGrid


@pytest.fixture(scope="module")
def tiny_sim():
    """6 m area, 0.25 m / 2° grid (625 × 180 candidates), 20 % packet loss."""
    cfg = ScenarioConfig(
        size_m=6.0,
        step_m=0.25,
        azimuth_step_deg=2.0,
        duration_s=0.06,
        noise_db=1.0,
        loss_fraction=0.2,
        min_receiver_spacing_m=2.0,
    )
    return simulate(cfg, seed=11)


def _space(sim):
    return candidate_space(sim.site, sim.site.devices[0].transmitter)


def _assert_same(a, b):
    np.testing.assert_array_equal(a.candidate_idx, b.candidate_idx)
    np.testing.assert_array_equal(a.mse_db2, b.mse_db2)


def test_registry_names_and_unknown():
    assert {"reference", "numpy"} <= set(SCORERS)
    with pytest.raises(ValueError, match="unknown scorer"):
        make_scorer("gpu", None)


def test_noise_free_packet_at_a_survey_point_has_zero_mse_at_truth():
    # Survey points (1 m grid) reproduce the channel exactly, so a noise-free packet
    # from a survey point at a grid azimuth matches its own candidate exactly.
    sim = simulate(
        ScenarioConfig(
            size_m=4.0,
            step_m=0.5,
            azimuth_step_deg=10.0,
            duration_s=0.01,
            min_receiver_spacing_m=1.5,
        ),
        seed=2,
    )
    site = sim.site
    space = _space(sim)
    pos = np.array([[2.0, 3.0, site.area.z_m]])
    ori = np.array([[40.0, 0.0, 0.0]])
    rx = site.receiver_positions_m()
    rx_o = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in site.receivers])
    rss = link_rss_dbm(
        sim.config.channel,
        pos,
        ori,
        site.patterns["device"],
        sim.config.tx_power_dbm,
        rx,
        rx_o,
        tuple(site.patterns[r.pattern] for r in site.receivers),
    )[0]
    pkt = PacketObservation("0", 0.0, space.transmitter, site.receiver_ids, rss)
    top = ReferenceScorer(space).score_topk(pkt, k=5)
    ipos = int(np.flatnonzero(np.all(np.isclose(space.positions_m, pos), axis=1))[0])
    truth_idx = ipos * space.n_orientations + 4  # azimuth 40° at a 10° step
    assert top.candidate_idx[0] == truth_idx
    assert top.mse_db2[0] < 1e-18


def test_missing_receiver_is_left_out_not_zero_filled(tiny_sim):
    space = _space(tiny_sim)
    pos, ori = np.array([3, 40]), np.array([5, 7])
    exp = expected_rss_dbm(space, pos, ori)
    heard = HeardRss(np.array([0, 2, 3]), np.array([-50.0, -60.0, -55.0]))
    mse = candidate_mse_db2(exp, heard)
    manual = np.mean((np.array([-50.0, -60.0, -55.0])[None, :] - exp[:, [0, 2, 3]]) ** 2, axis=1)
    np.testing.assert_allclose(mse, manual, rtol=1e-14)


def test_expected_rss_is_channel_plus_power_plus_directivity(tiny_sim):
    space = _space(tiny_sim)
    exp = expected_rss_dbm(space, np.array([10]), np.array([0]))[0]
    p = space.positions_m[10]
    d = space.receiver_positions_m - p  # orientation 0: body frame = world frame
    phi = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 360
    want = space.channel_db[:, 10] + space.tx_power_dbm + space.pattern.lookup_dbi(phi, 90.0)
    np.testing.assert_allclose(exp, want, atol=1e-9)


def test_numpy_kernel_matches_reference_with_packet_loss(tiny_sim):
    space = _space(tiny_sim)
    ref, fast = ReferenceScorer(space, chunk_terms=50_000), TableScorer(space)
    obs = group_packets(tiny_sim.packets)
    masks = set()
    for o in obs[:8]:
        if len(o.receiver_ids) == 0:
            continue
        masks.add(len(o.receiver_ids))
        _assert_same(ref.score_topk(o, 100), fast.score_topk(o, 100))
    assert len(masks) > 1  # both the full set and a subset were exercised


def test_numpy_kernel_matches_reference_with_pitch_and_roll(tiny_sim):
    site = replace(tiny_sim.site, orientations=OrientationGrid(20.0, (0.0, 30.0), (0.0, -20.0)))
    space = candidate_space(site, site.devices[0].transmitter)
    assert not space.azimuth_only
    ref, fast = ReferenceScorer(space), TableScorer(space)
    for o in group_packets(tiny_sim.packets)[:3]:
        _assert_same(ref.score_topk(o, 50), fast.score_topk(o, 50))


def test_excluded_candidates_are_never_selected(tiny_sim):
    site = tiny_sim.site
    m = np.array(site.survey_map.m_db)
    m[1, :, : m.shape[2] // 2] = np.nan  # receiver 2 unknown in half the area
    site = replace(site, survey_map=replace(site.survey_map, m_db=m))
    space = candidate_space(site, site.devices[0].transmitter)
    bad = ~np.isfinite(space.channel_db[1])
    ref, fast = ReferenceScorer(space), TableScorer(space)
    for o in group_packets(tiny_sim.packets)[:4]:
        a, b = ref.score_topk(o, 100), fast.score_topk(o, 100)
        _assert_same(a, b)
        if "rx2" in o.receiver_ids:
            assert not bad[space.split(a.candidate_idx)[0]].any()


def test_select_topk_breaks_ties_by_index_and_skips_nan():
    idx = np.array([9, 3, 7, 1, 5])
    mse = np.array([1.0, 1.0, np.nan, 0.5, 1.0])
    top = select_topk(idx, mse, 3)
    np.testing.assert_array_equal(top.candidate_idx, [1, 3, 5])
    np.testing.assert_array_equal(top.mse_db2, [0.5, 1.0, 1.0])
    assert len(select_topk(idx, mse, 10)) == 4
    with pytest.raises(ValueError):
        select_topk(idx, mse, 0)


def test_unknown_receiver_in_packet_is_an_input_error(tiny_sim):
    space = _space(tiny_sim)
    pkt = PacketObservation("7", 0.0, space.transmitter, ("rx1", "nope"), np.array([-50.0, -60]))
    with pytest.raises(InputError, match="'nope' is not in the site"):
        space.heard(pkt)


@pytest.mark.parametrize("full_sphere", [False, True])
def test_compiled_exact_rss_matches_the_numpy_geometry(tiny_sim, full_sphere):
    """The compiled exact expected RSS (used by the reference and every rescoring)
    equals the vectorised numpy path through geometry and Pattern.lookup_dbi."""
    from radiopose.likelihood.candidates import directivity_dbi
    from radiopose.patterns import smartphone_like

    site = replace(tiny_sim.site, orientations=OrientationGrid(15.0, (0.0, 30.0), (0.0, -45.0)))
    space = candidate_space(site, site.devices[0].transmitter)
    if full_sphere:
        space = replace(
            space, pattern=smartphone_like(np.random.default_rng(3), polar_step_deg=5.0)
        )
        assert not space.pattern.is_slice
    # a receiver on a candidate position: the zero direction vector (0, 90) case
    rx = space.receiver_positions_m.copy()
    rx[0] = space.positions_m[7]
    space = replace(space, receiver_positions_m=rx)
    rng = np.random.default_rng(11)
    pos = np.r_[7, rng.integers(0, space.n_positions, 500)]
    ori = rng.integers(0, space.n_orientations, pos.size)
    want = space.channel_db[:, pos].T + space.tx_power_dbm + directivity_dbi(space, pos, ori)
    got = expected_rss_dbm(space, pos, ori)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    heard = HeardRss(np.array([0, 2, 3]), np.array([-50.0, -61.5, -55.25]))
    exact = exact_mse_db2(space, heard, pos * space.n_orientations + ori)
    np.testing.assert_array_equal(exact, candidate_mse_db2(got, heard))
    for bad in (-1, space.n_candidates):  # the compiled loops do not check bounds
        with pytest.raises(IndexError, match="candidate index outside"):
            exact_mse_db2(space, heard, np.array([0, bad]))
        with pytest.raises(IndexError, match="candidate index outside"):
            expected_rss_dbm(space, np.array([bad]), np.array([0]))
    with pytest.raises(IndexError, match="orientation index outside"):
        expected_rss_dbm(space, np.array([0]), np.array([space.n_orientations]))


def test_memo_scorer_passes_the_window_through(tiny_sim):
    from radiopose.likelihood.compiled import ShiftScorer
    from radiopose.likelihood.memo import MemoScorer

    space = _space(tiny_sim)
    inner = ShiftScorer(space)
    memo = MemoScorer(inner)
    heard = space.heard(group_packets(tiny_sim.packets)[0])
    positions = np.arange(0, space.n_positions, 3)
    _assert_same(
        memo.score_window(heard, 10, positions, 30.0, 40.0),
        inner.score_window(heard, 10, positions, 30.0, 40.0),
    )
    assert not hasattr(MemoScorer(TableScorer(space)), "score_window")


def test_memo_scorer_hands_out_the_inner_one_thread_twin(tiny_sim):
    """The filter asks its scorer for a one-thread twin (``with_parallel``): behind
    a memo (the demo, ``evaluate``) it gets the inner scorer's, as in a plain
    ``locate``, with the same top-k."""
    from radiopose.filtering import FilterModel
    from radiopose.likelihood.compiled import ShiftScorer
    from radiopose.likelihood.memo import MemoScorer

    space = _space(tiny_sim)
    inner = ShiftScorer(space, parallel=True)
    memo = MemoScorer(inner)
    model = FilterModel.build(tiny_sim.site, space, memo)
    assert isinstance(model.scorer, ShiftScorer) and not model.scorer.parallel
    heard = space.heard(group_packets(tiny_sim.packets)[0])
    _assert_same(model.scorer.score_heard(heard, 10), memo.score_heard(heard, 10))
    assert not hasattr(MemoScorer(TableScorer(space)), "with_parallel")


def test_the_free_power_profile_by_hand():
    """``profile_offset_db`` against two cases worked by hand (its formula was
    covered only through the filter's chaotic runs; helper-65's mutant L01
    dropped the prior's term from the cost):
    residuals (3, 3, 3), 3 readings, σ 1 dB, prior 0 ± 1 dB: λ = 3, λ₀ = 1,
    offset 9/4, cost ½·(3−9/4)²·3 + ½·(9/4)² = 27/8; residuals (1, 2, 6),
    6 readings, σ 2 dB, prior 1 ± 0.5 dB: λ = 3/2, λ₀ = 4, offset 17/11, cost
    ¼·(36 + 25 + 2401)/121 + 2·(6/11)² = 2750/484."""
    from radiopose.likelihood.power import profile_offset_db

    off, cost, lam = profile_offset_db(np.array([[3.0, 3, 3]]), 3, 1.0, 0.0, 1.0)
    assert (off[0], cost[0], lam) == (pytest.approx(9 / 4), pytest.approx(27 / 8), 3.0)
    off, cost, lam = profile_offset_db(np.array([[1.0, 2, 6]]), 6, 2.0, 1.0, 0.5)
    assert (off[0], cost[0], lam) == (pytest.approx(17 / 11), pytest.approx(2750 / 484), 1.5)
