"""The filter's speed mechanics give the same numbers as what they replace:
per-offset threshold hints and concurrent searches (``ShiftScorer.score_heard_slot``,
``score_heard_many``, ``FilterModel.search``), a smaller screened shortlist, the
σ differences in one compiled call, the outlier mixture with one exponential
fewer, and a smoother ring sized for the re-entries.

Seeds 4321-4329 are used here only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from radiopose.filtering import FilterModel
from radiopose.filtering import kernels as K  # noqa: N812
from radiopose.filtering.lineage import Lineage
from radiopose.likelihood import ReferenceScorer, candidate_space, compiled
from radiopose.likelihood.candidates import HeardRss, expected_rss_dbm
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.simulate import ScenarioConfig, simulate


@pytest.fixture(scope="module")
def space():
    cfg = ScenarioConfig(
        size_m=6.0, step_m=0.25, duration_s=0.05, min_receiver_spacing_m=2.0, n_receivers=4
    )
    sim = simulate(cfg, seed=4321)
    return candidate_space(sim.site, sim.site.devices[0].transmitter)


def _shifted_packets(space, seed: int, offsets_db: list[float]) -> list[HeardRss]:
    """One packet near a random candidate, searched at several power offsets."""
    rng = np.random.default_rng(seed)
    c = rng.integers(space.n_candidates)
    pos, ori = space.split(np.array([c]))
    rss = expected_rss_dbm(space, pos, ori)[0] + rng.normal(0, 1.5, space.n_receivers)
    return [HeardRss(np.arange(space.n_receivers), rss - o) for o in offsets_db]


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.candidate_idx, b.candidate_idx)
    np.testing.assert_array_equal(a.mse_db2, b.mse_db2)


@pytest.mark.parametrize("seed", [4322, 4323])
def test_slot_hints_and_concurrent_searches_equal_the_reference(space, seed, monkeypatch):
    monkeypatch.setattr(compiled, "spare_core", lambda: True)  # threads even on a busy machine
    offsets = [0.0, 6.0, -9.0, 3.0]
    ref = ReferenceScorer(space)
    fast = ShiftScorer(space, parallel=False).with_parallel(False, oversample=16)
    for rep in range(3):  # later rounds start from the slots' hints
        heards = _shifted_packets(space, seed + 100 * rep, offsets)
        many = fast.score_heard_many(heards, 20, [round(o / 1.5) for o in offsets])
        assert len(many) == len(heards)
        for h, got in zip(heards, many, strict=True):
            _same(got, ref.score_heard(h, 20))
            _same(fast.score_heard_slot(h, 20, "another slot"), got)
            _same(fast.score_heard(h, 20), got)
    assert fast._slot_hints  # each slot kept its own hint
    assert fast.oversample == 16


def test_filter_model_search_matches_the_scorer_and_keeps_the_slots(space):
    site = simulate(
        ScenarioConfig(size_m=6.0, step_m=0.25, duration_s=0.05, min_receiver_spacing_m=2.0),
        seed=4321,
    ).site
    scorer = ShiftScorer(space, parallel=True)
    model = FilterModel.build(site, space, scorer)
    assert not model.scorer.parallel and model.scorer.posf is scorer.posf
    heards = _shifted_packets(space, 4324, [0.0, 4.5, -4.5])
    got = model.search(heards, 30, [0, 3, -3])
    for h, g in zip(heards, got, strict=True):
        _same(g, scorer.score_heard(h, 30))
    assert set(model.scorer._slot_hints) == {0, 3, -3}
    assert not scorer._slot_hints  # the caller's scorer is untouched


@pytest.mark.parametrize("seed", [4327, 4328])
def test_shared_chunk_threshold_keeps_the_same_best_and_prunes_more(space, seed):
    """``shift_topk_shared`` (one thread: the chunks share their threshold) keeps the
    screened best ``kk`` of ``shift_topk_serial`` (to float32 rounding: where a run
    of surviving blocks splits into SIMD body and tail depends on the bound),
    reports a bound covering what it kept, and keeps fewer candidates; the scorer
    built on it still equals the reference exactly, at the data's offset and far
    from it."""
    from radiopose.likelihood import shift_kernels as sk

    fast = ShiftScorer(space, parallel=False)
    ref = ReferenceScorer(space)
    kk = 24

    def best(v, i):
        ok = i.ravel() >= 0
        vv, ii = v.ravel()[ok], i.ravel()[ok]
        order = np.lexsort((ii, vv))[:kk]
        return vv[order], ii[order], ok.sum()

    for heard in _shifted_packets(space, seed, [0.0, 7.5, -9.0]):
        r = heard.receiver_index
        w = (heard.rss_dbm - fast.centre_db[r]).astype(np.float32)
        args = (*fast._kernel_args(), fast.all_positions, 0, fast.n_az, kk, fast.block)
        v0, i0 = sk.shift_topk_serial(w, r, *args, np.float32(np.inf))
        v1, i1, thr = sk.shift_topk_shared(w, r, *args, np.float32(np.inf))
        assert np.isfinite(thr)  # a cold start (no threshold given) gets one from the chunks
        b0, _, n0 = best(v0, i0)
        b1, _, n1 = best(v1, i1)
        np.testing.assert_allclose(b1, b0, rtol=1e-5, atol=1e-6)
        assert n1 < n0  # the shared threshold dropped what the earlier chunks beat
        assert b1[-1] <= thr  # the kept best kk are within the bound it reports
        _same(fast.score_heard(heard, 20), ref.score_heard(heard, 20))


def _push_differences_numpy(heard, rss, t_s, max_dt_s, last_rss, last_t, diff2, count):
    """The σ differences as :meth:`ParticleFilter._update_sigma` computed them in numpy."""
    gap = t_s - last_t[heard]
    ok = (gap > 0) & (gap <= max_dt_s)
    for d in rss[ok] - last_rss[heard[ok]]:
        diff2[count % diff2.size] = d * d
        count += 1
    last_rss[heard] = rss
    last_t[heard] = t_s
    return count


@pytest.mark.parametrize("seed", [4325, 4326])
def test_push_differences_and_median_match_numpy(seed):
    rng = np.random.default_rng(seed)
    n_rx, memory = 5, 37
    state_a = [np.zeros(n_rx), np.full(n_rx, -math.inf), np.zeros(memory)]
    state_b = [a.copy() for a in state_a]
    count_a = count_b = 0
    t = 0.0
    for _ in range(200):
        t += float(rng.choice([0.0, 0.004, 0.02, 0.07]))  # repeats, near and far gaps
        heard = np.sort(rng.choice(n_rx, size=rng.integers(1, n_rx + 1), replace=False))
        rss = rng.normal(-60, 4, heard.size)
        count_a = _push_differences_numpy(heard, rss, t, 0.05, *state_a, count_a)
        count_b = int(K.push_differences(heard.astype(np.int64), rss, t, 0.05, *state_b, count_b))
        assert count_a == count_b
        for a, b in zip(state_a, state_b, strict=True):
            np.testing.assert_array_equal(a, b)
        used = min(count_b, memory)
        if used:
            assert K.median_of_first(state_b[2], used) == np.median(state_a[2][:used])
    assert count_b > memory  # the ring wrapped


def _inlier_before(u: float, log_eps: float) -> tuple[float, float]:
    """The outlier mixture's cost and inlier weight as first written (two exps in the sum)."""
    g = -0.5 * u * u
    m = max(g, log_eps)
    lse = m + math.log(math.exp(g - m) + math.exp(log_eps - m))
    return -lse, math.exp(g - lse)


def test_mixture_cost_has_the_same_numbers_as_before():
    rng = np.random.default_rng(4327)
    n, h = 300, 4
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.OFFSET_DB] = rng.normal(0, 3, n)
    S[:, K.OFFSET_VAR_DB2] = rng.uniform(0.1, 30, n)
    pred = rng.normal(-60, 6, (n, h))
    pred[0, 1] = np.nan
    rss = rng.normal(-60, 6, h)
    sigma, log_eps = 1.7, math.log(0.01)
    logw = np.zeros(n)
    S_new = S.copy()
    K.measurement_update(S_new, pred, rss, sigma, log_eps, logw)
    # the same update written in Python with the original mixture
    s2 = sigma * sigma
    for i in range(n):
        b, p = S[i, K.OFFSET_DB], S[i, K.OFFSET_VAR_DB2]
        e = [rss[q] - pred[i, q] - b for q in range(h)]
        if math.isnan(sum(e)):
            assert logw[i] == -np.inf
            continue
        ebar = p * sum(e) / s2 / (1.0 + p * h / s2)
        cost = sw = swe = 0.0
        for q in range(h):
            rho, w = _inlier_before((e[q] - ebar) / sigma, log_eps)
            cost, sw, swe = cost + rho, sw + w, swe + w * e[q]
        a = 1.0 + p * sw / s2
        expect = -cost + 0.5 * p * (swe / s2) ** 2 / a - 0.5 * math.log(a)
        assert logw[i] == pytest.approx(expect, rel=1e-13, abs=1e-12)
        assert S_new[i, K.OFFSET_DB] == pytest.approx(b + p * swe / s2 / a, rel=1e-13, abs=1e-12)


def test_lineage_sized_for_the_reentries_does_not_widen():
    rng = np.random.default_rng(4328)
    n, m, per_lag = 40, 3, 4
    lin = Lineage(n, capacity=8, extra_rows=m * (per_lag + 2))
    width = lin.rows.shape[1]
    for step in range(30):
        lin.push(0.01 * step, rng.normal(size=(n, K.POSE_ROW)))
        if step % 2:
            new = np.zeros((m, K.N_COLUMNS))
            slots = rng.choice(n, m, replace=False)
            lin.inject(0.01 * step, 0.015, new, slots, rng.choice(n, m), box_m=None)
        while lin.size > 2 * per_lag:  # packets leave after the lag
            lin.pop_moments(np.full(n, 1.0 / n), np.empty(9))
    assert lin.rows.shape[1] == width
    assert Lineage(n).rows.shape[1] == n + n // 8  # the default is unchanged


def test_scan_slots_are_offset_bins():
    # the slot of an offset is its bin from the prior's centre, so the scanned
    # offsets (1.5 dB apart) never share one and a drifting belief keeps its own
    from radiopose.filtering.particle import _HINT_BIN_DB, FilterConfig

    scans = FilterConfig().offset_scan_db
    assert len({round(o / _HINT_BIN_DB) for o in scans}) == len(scans)


def test_particles_on_two_threads_give_the_same_estimates(monkeypatch):
    from radiopose.filtering import particle
    from radiopose.tracker import TrackerConfig, locate

    sim = simulate(
        ScenarioConfig(size_m=6.0, step_m=0.25, duration_s=0.4, min_receiver_spacing_m=2.0),
        seed=4329,
    )
    runs = []
    for spare in (False, True):
        monkeypatch.setattr(particle, "spare_core", lambda spare=spare: spare)
        monkeypatch.setattr(compiled, "spare_core", lambda spare=spare: spare)
        est = locate(sim.site, sim.packets, "filter", TrackerConfig()).estimates
        runs.append(est)
    a, b = runs
    assert len(a) == len(b) > 50
    np.testing.assert_array_equal(a.position_m, b.position_m)
    np.testing.assert_array_equal(a.orientation_deg, b.orientation_deg)
    np.testing.assert_array_equal(a.position_std_m, b.position_std_m)


def test_spare_core_follows_the_load_once_a_second(monkeypatch):
    monkeypatch.setattr(compiled, "threads", lambda: 2)
    monkeypatch.setattr(compiled.os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(compiled, "_SPARE", [-math.inf, False])
    monkeypatch.setattr(compiled.os, "getloadavg", lambda: (0.9, 0.0, 0.0))
    assert compiled.spare_core() is True
    monkeypatch.setattr(compiled.os, "getloadavg", lambda: (17.0, 0.0, 0.0))
    assert compiled.spare_core() is True  # read at most once a second
    compiled._SPARE[0] = -math.inf
    assert compiled.spare_core() is False
    monkeypatch.setattr(compiled, "threads", lambda: 1)
    monkeypatch.setattr(compiled.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    compiled._SPARE[0] = -math.inf
    assert compiled.spare_core() is False  # NUMBA_NUM_THREADS=1: never


@pytest.mark.filterwarnings("ignore:.*fork.*:DeprecationWarning")
def test_thread_pool_is_remade_in_a_forked_child():
    import multiprocessing as mp

    pool = compiled.thread_pool(2)
    assert compiled.thread_pool(2) is pool
    assert pool.submit(lambda: 42).result() == 42
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as child:  # the child's copy of the pool has no threads
        assert child.apply_async(_use_pool_in_child).get(timeout=60) == 7


def _use_pool_in_child() -> int:
    return compiled.thread_pool(2).submit(lambda: 7).result(timeout=30)
