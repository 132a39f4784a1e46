"""The filter's speed mechanics give the same numbers as what they replace:
per-offset threshold hints and concurrent searches (``ShiftScorer.score_heard_slot``,
``score_heard_many``, ``FilterModel.search``), a smaller screened shortlist, the
σ differences in one compiled call, the outlier mixture with one exponential
fewer, and a smoother ring sized for the re-entries; and (fourth pass) the
vectorisable ``exp``/``log``/``atan2``/``sin``/``cos`` and the receiver-major
likelihood and expected RSS, within ulps of the C library's numbers; and
(sixth pass) a search's starting threshold lowered on the other slots' hints
(``ShiftScorer.borrow_hints``), a valid bound that changes no result.

Seeds 4321-4329, 4340-4345 and (sixth pass: thresholds borrowed from the
other slots' hints) 4346-4349 are used here only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

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
    assert model.scorer.borrow_hints and not scorer.borrow_hints


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


@pytest.mark.parametrize("seed", [4346, 4347])
def test_borrowed_threshold_is_a_bound_and_changes_no_result(space, seed):
    """A slot's search may start from the other slots' hints
    (``ShiftScorer._borrowed_threshold``): the bound lies between the true
    ``kk``-th best screened value and the slot's own threshold, is lower than
    it somewhere (else borrowing does nothing), and every result equals the
    reference's and the scorer's without borrowing."""
    offsets = [0.0, 6.0, -9.0, 3.0]
    slots = [round(o / 1.5) for o in offsets]
    ref = ReferenceScorer(space)
    plain = ShiftScorer(space, parallel=False).with_parallel(False, oversample=16)
    borrow = plain.with_parallel(False, borrow_hints=True)
    assert borrow.borrow_hints and not plain.borrow_hints and borrow.oversample == 16
    k = 20
    kk = k + borrow.oversample
    lowered = 0
    for rep in range(3):  # later rounds start from the slots' hints
        heards = _shifted_packets(space, seed + 100 * rep, offsets)
        for h, slot in zip(heards, slots, strict=True):
            r = h.receiver_index
            w = (h.rss_dbm - borrow.centre_db[r]).astype(np.float32)
            args = (w, r, borrow.all_positions, 0, borrow.n_az, kk)
            own = borrow._threshold(*args, borrow._slot_hints.get(slot, compiled._NO_HINT))
            got = borrow._borrowed_threshold(*args, slot, own)
            every = compiled._dense(
                w, r, *borrow._kernel_args(), borrow.all_positions, 0, borrow.n_az
            )
            true_kk = float(np.partition(every, kk - 1)[kk - 1])
            assert true_kk <= got <= own
            lowered += got < own
        for h, a, b in zip(
            heards,
            borrow.score_heard_many(heards, k, slots),
            plain.score_heard_many(heards, k, slots),
            strict=True,
        ):
            _same(a, b)
            _same(a, ref.score_heard(h, k))
    assert lowered >= 2


def test_borrowed_thresholds_leave_the_filter_bit_identical(monkeypatch):
    from radiopose.tracker import TrackerConfig, locate

    sim = simulate(
        ScenarioConfig(size_m=6.0, step_m=0.25, duration_s=0.4, min_receiver_spacing_m=2.0),
        seed=4348,
    )
    calls = []
    real = compiled.ShiftScorer._borrowed_threshold

    def counted(self, *a):  # type: ignore[no-untyped-def]
        out = real(self, *a)
        calls.append(out < a[-1])
        return out

    monkeypatch.setattr(compiled.ShiftScorer, "_borrowed_threshold", counted)
    a = locate(sim.site, sim.packets, "filter", TrackerConfig()).estimates
    assert sum(calls) > 0  # the filter's searches borrowed, and it lowered a bound
    monkeypatch.setattr(compiled.ShiftScorer, "_borrowed_threshold", lambda self, *a: a[-1])
    b = locate(sim.site, sim.packets, "filter", TrackerConfig()).estimates
    assert len(a) == len(b) > 50
    np.testing.assert_array_equal(a.position_m, b.position_m)
    np.testing.assert_array_equal(a.orientation_deg, b.orientation_deg)
    np.testing.assert_array_equal(a.position_std_m, b.position_std_m)
    np.testing.assert_array_equal(a.azimuth_std_deg, b.azimuth_std_deg)


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


def test_spare_core_follows_the_other_processes_once_a_second(monkeypatch):
    """A core is spare while the other processes leave 1.5 of this process's
    cores free (looked at once a second); never with one numba thread."""
    free = [2.0]
    monkeypatch.setattr(compiled, "threads", lambda: 2)
    monkeypatch.setattr(compiled, "free_cores", lambda: free[0])
    monkeypatch.setattr(compiled, "_SPARE", [-math.inf, False])
    assert compiled.spare_core() is True
    free[0] = 1.0  # another process took a core
    assert compiled.spare_core() is True  # read at most once a second
    compiled._SPARE[0] = -math.inf
    assert compiled.spare_core() is False
    free[0] = 1.6
    compiled._SPARE[0] = -math.inf
    assert compiled.spare_core() is True
    monkeypatch.setattr(compiled, "threads", lambda: 1)
    free[0] = 2.0
    compiled._SPARE[0] = -math.inf
    assert compiled.spare_core() is False  # NUMBA_NUM_THREADS=1: never


def test_free_cores_subtracts_the_other_processes_cpu(monkeypatch):
    """Free cores: the affinity's cores minus the busy CPU seconds per second
    not spent by this process; the load average (plus this process's own core)
    stands in without /proc/stat or a long enough interval."""
    monkeypatch.setattr(compiled.os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(compiled.os, "getloadavg", lambda: (1.7, 0.0, 0.0))
    samples = iter([(10.0, 100.0, 5.0), (12.0, 103.0, 6.0), (12.1, 103.2, 6.1), None])
    monkeypatch.setattr(compiled, "cpu_sample", lambda: next(samples))
    monkeypatch.setattr(compiled, "_STAT_SAMPLE", [None])
    assert compiled.free_cores() == pytest.approx(2 - 1.7 + 1)  # no earlier look: the load
    # 2 s later: 3 busy CPU s, 1 of them this process's -> others used 1 core
    assert compiled.free_cores() == pytest.approx(1.0)
    # 0.1 s later: too short an interval, the load; the last sample stays
    assert compiled.free_cores() == pytest.approx(1.3)
    assert compiled._STAT_SAMPLE[0] == (12.0, 103.0, 6.0)
    assert compiled.free_cores() == pytest.approx(1.3)  # /proc/stat unreadable


STAT = """cpu  900 10 300 5000 40 0 5 7 0 0
cpu0 400 5 100 2500 20 0 2 3 0 0
cpu1 500 5 200 2500 20 0 3 4 0 0
intr 12345 0 0
ctxt 999
"""


def test_busy_cpu_s_reads_the_processors_of_the_affinity():
    """Busy = user + nice + system + irq + softirq + steal of the listed
    processors (not idle, iowait, or the machine's total line), in seconds."""
    assert compiled.busy_cpu_s(STAT, {0}, 100.0) == pytest.approx(5.10)
    assert compiled.busy_cpu_s(STAT, {0, 1}, 100.0) == pytest.approx(5.10 + 7.12)
    assert compiled.busy_cpu_s(STAT, {1, 7}, 50.0) == pytest.approx(14.24)
    with pytest.raises(ValueError, match="none of this process"):
        compiled.busy_cpu_s(STAT, {5}, 100.0)
    with pytest.raises(ValueError, match="cpu0 has 3 columns"):
        compiled.busy_cpu_s("cpu0 1 2 3\n", {0}, 100.0)


@given(
    ticks=st.lists(
        st.lists(st.integers(0, 10**9), min_size=5, max_size=10), min_size=1, max_size=8
    ),
    data=st.data(),
)
def test_busy_cpu_s_is_every_column_but_idle_and_iowait(ticks, data):
    lines = [f"cpu{i} " + " ".join(map(str, t)) for i, t in enumerate(ticks)]
    cpus = data.draw(st.sets(st.integers(0, len(ticks) - 1), min_size=1))
    want = sum(sum(ticks[i][:8]) - ticks[i][3] - ticks[i][4] for i in cpus)
    text = "cpu  1 2 3 4 5\n" + "\n".join(lines) + "\nintr 1 2\n"
    assert compiled.busy_cpu_s(text, cpus, 100.0) == pytest.approx(want / 100.0)


@pytest.mark.skipif(compiled.cpu_sample() is None, reason="no /proc/stat here")
def test_cpu_sample_sees_another_process_burn_cpu():
    """A child that burns 0.5 CPU s shows as at least 0.4 s of busy CPU not spent
    by this process, between two samples (whatever else the machine runs)."""
    import subprocess
    import sys

    burn = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.5: pass"
    a = compiled.cpu_sample()
    subprocess.run([sys.executable, "-c", burn], check=True)
    b = compiled.cpu_sample()
    assert a is not None and b is not None
    assert (b[1] - a[1]) - (b[2] - a[2]) >= 0.4


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


# ----------------------------------------------------------------------------- fourth pass
# Vectorisable exp/log/atan2 (radiopose.filtering.vmath) and the receiver-major
# likelihood and expected RSS: within ulps of the C library's numbers, and the
# loops over particles actually vectorise.


def _ulps(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    return np.abs(got - want) / np.spacing(np.abs(want))


@pytest.fixture(scope="module")
def vmath_loops():
    import numba

    from radiopose.filtering import vmath

    @numba.njit(error_model="numpy")
    def apply(kind, x, y, out):  # pragma: no cover - compiled
        for i in range(x.shape[0]):
            if kind == 0:
                out[i] = vmath.vexp(x[i])
            elif kind == 1:
                out[i] = vmath.vlog(x[i])
            elif kind == 2:
                out[i] = vmath.vatan2(y[i], x[i])
            elif kind == 3:
                out[i] = vmath.vsincos(x[i])[0]
            else:
                out[i] = vmath.vsincos(x[i])[1]

    def run(kind: int, x: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
        out = np.empty_like(x)
        apply(kind, x, x if y is None else y, out)
        return out

    return run


def test_vexp_vlog_within_two_ulp_of_libm(vmath_loops):
    rng = np.random.default_rng(4340)
    for x in (rng.uniform(-708.0, 709.0, 100_000), rng.uniform(-40.0, 0.0, 100_000)):
        got = vmath_loops(0, x)
        assert _ulps(got, np.exp(x)).max() <= 2.0
    assert vmath_loops(0, np.array([0.0]))[0] == 1.0
    # clamped below -708 and above 709 (the filter never goes there: documented)
    np.testing.assert_allclose(vmath_loops(0, np.array([-1e4, 1e4])), np.exp([-708.0, 709.0]))
    for x in (np.exp(rng.uniform(-700.0, 700.0, 100_000)), rng.uniform(0.5, 2.0, 100_000)):
        got = vmath_loops(1, x)
        want = np.log(x)
        assert (np.abs(got - want) <= 2.0 * np.spacing(np.maximum(np.abs(want), 0.5))).all()
    assert vmath_loops(1, np.array([1.0]))[0] == 0.0


def test_vatan2_within_two_ulp_of_libm_and_on_the_axes(vmath_loops):
    rng = np.random.default_rng(4341)
    scale = 10.0 ** rng.uniform(-6, 3, 100_000)
    x, y = rng.normal(0, 1, 100_000) * scale, rng.normal(0, 1, 100_000) * scale
    got = vmath_loops(2, x, y)
    want = np.arctan2(y, x)
    assert (np.abs(got - want) <= 2.0 * np.spacing(np.abs(want))).all()
    assert np.abs(got - want).max() < 5e-16
    ax = np.array([1.0, -1.0, 0.0, 0.0, 0.0, 3.0, -2.0, 1.0, 1e-300])
    ay = np.array([0.0, 0.0, 1.0, -1.0, 0.0, 3.0, -2.0, 1e-300, 1.0])
    np.testing.assert_array_equal(vmath_loops(2, ax, ay), np.arctan2(ay, ax))


def test_vsincos_within_two_ulp_of_libm(vmath_loops):
    rng = np.random.default_rng(4345)
    for x in (rng.uniform(0.0, 2 * np.pi, 100_000), rng.uniform(-60.0, 60.0, 100_000)):
        for kind, ref in ((3, np.sin(x)), (4, np.cos(x))):
            err = np.abs(vmath_loops(kind, x) - ref)
            assert (err <= 2.0 * np.spacing(np.maximum(np.abs(ref), 0.25))).all()
            assert err.max() <= 2.3e-16
    # exact where the kernels rely on it (a frozen pitch or roll of 0)
    assert vmath_loops(3, np.array([0.0, -0.0]))[0] == 0.0
    assert (vmath_loops(4, np.array([0.0, -0.0])) == 1.0).all()
    axes = np.array([np.pi / 2, np.pi, 1.5 * np.pi])
    np.testing.assert_allclose(vmath_loops(3, axes), np.sin(axes), rtol=0, atol=1e-30 + 2e-16)
    np.testing.assert_allclose(vmath_loops(4, axes), np.cos(axes), rtol=0, atol=1e-30 + 2e-16)


def _expected_row_reference(S, i, heard, rx, chan, grid, tx_dbm, d, pat) -> list[float]:
    """A particle's expected RSS as the particle-major kernel computed it before
    (the C library's atan2), from the kernels' own Python lookups."""
    x0, dx, nx, y0, dy, ny = grid[0], grid[1], int(grid[2]), grid[3], grid[4], int(grid[5])
    x, y, z = S[i, K.X_M], S[i, K.Y_M], S[i, K.Z_M]
    a, p, r = S[i, K.AZIMUTH_RAD], S[i, K.PITCH_RAD], S[i, K.ROLL_RAD]
    rot = K.body_rotation.py_func(
        math.cos(a), math.sin(a), math.cos(p), math.sin(p), math.cos(r), math.sin(r)
    )
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
    out = []
    for rr in heard:
        ddx, ddy, ddz = rx[rr, 0] - x, rx[rr, 1] - y, rx[rr, 2] - z
        vx = ddx * r00 + ddy * r10 + ddz * r20
        vy = ddx * r01 + ddy * r11 + ddz * r21
        vz = ddx * r02 + ddy * r12 + ddz * r22
        if vx == 0.0 and vy == 0.0 and vz == 0.0:
            phi, theta = 0.0, 90.0
        else:
            phi = math.degrees(math.atan2(vy, vx))
            nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
            theta = math.degrees(math.acos(min(max(vz / nrm, -1.0), 1.0)))
        m = K._map_db.py_func(chan, rr, x, y, x0, dx, nx, y0, dy, ny)
        out.append(m + tx_dbm + K._pattern_dbi.py_func(d, phi, theta, pat[0], pat[1], pat[2]))
    return out


@pytest.mark.parametrize("sphere", [False, True])
def test_receiver_major_expected_rss_matches_the_particle_major_one(sphere):
    rng = np.random.default_rng(4342 + sphere)
    n = 400
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M] = rng.uniform(-1.0, 21.0, n)  # some outside the map: clamped
    S[:, K.Y_M] = rng.uniform(-1.0, 21.0, n)
    S[:, K.Z_M] = 1.0
    S[:, K.AZIMUTH_RAD] = rng.uniform(0, 2 * np.pi, n)
    S[:, K.PITCH_RAD] = np.where(rng.random(n) < 0.5, 0.0, rng.normal(0, 0.3, n))
    S[:, K.ROLL_RAD] = np.where(rng.random(n) < 0.5, 0.0, rng.normal(0, 0.3, n))
    rx = np.array([[0.0, 0.0, 2.0], [20.0, 0.0, 2.0], [10.0, 20.0, 1.0], [5.0, 5.0, 1.0]])
    S[0, K.X_M : K.Z_M + 1] = rx[3]  # on a receiver: direction (0, 0, 0)
    S[1, K.X_M : K.Z_M + 1] = (rx[2, 0], rx[2, 1], 0.0)  # straight below one
    chan = rng.normal(-60, 5, (4, 21, 21))
    chan[1, 3, 4] = np.nan  # a hole in one receiver's map: NaN near it
    grid = np.array([0.0, 1.0, 21, 0.0, 1.0, 21])
    d = rng.normal(0, 4, (36, 19 if sphere else 1))
    pat = np.array([5.0, 10.0, 10.0 if sphere else 1.0])
    heard = np.array([0, 1, 3, 2], np.int64)
    got = np.empty((n, heard.size))
    K.expected_rss_into(S, heard, rx, chan, grid, -3.0, d, pat, got)
    want = np.array(
        [_expected_row_reference(S, i, heard, rx, chan, grid, -3.0, d, pat) for i in range(n)]
    )
    assert np.isnan(want).any()
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.skipif(
    __import__("platform").machine() not in ("x86_64", "AMD64"), reason="x86 assembly"
)
def test_the_likelihood_and_expected_rss_loops_vectorise():
    """The point of the receiver-major kernels: their loops over particles hold
    no library call, so LLVM vectorises them (a packed ``divpd``: vexp, vlog and
    vatan2 divide). The C library's exp/log in the outlier mixture, or its atan2
    in the expected RSS (whose other loops call cos/sin or gather, and stay
    scalar), fail this."""
    import re

    import numba

    @numba.njit(error_model="numpy")
    def mixture(u, log_eps, out):  # pragma: no cover - compiled
        for i in range(u.shape[0]):
            rho, w = K._inlier(u[i], log_eps)
            out[i] = rho + w

    rng = np.random.default_rng(4344)
    n, h = 64, 3
    S = np.zeros((n, K.N_COLUMNS))
    rx = rng.uniform(0, 5, (h, 3))
    chan = rng.normal(-60, 5, (h, 6, 6))
    grid = np.array([0.0, 1.0, 6, 0.0, 1.0, 6])
    d = rng.normal(0, 4, (36, 1))
    pat = np.array([0.0, 10.0, 1.0])
    heard = np.arange(h, dtype=np.int64)
    expected = numba.njit(error_model="numpy")(K.expected_rss_into.py_func)
    for g, args in (
        (mixture, (rng.normal(0, 3, n), math.log(0.01), np.empty(n))),
        (expected, (S, heard, rx, chan, grid, 0.0, d, pat, np.empty((n, h)))),
    ):
        g(*args)
        asm = "".join(g.inspect_asm().values())
        assert re.search(r"\bv?divpd\b", asm)
