"""The compiled shift kernel returns exactly the reference's top-k."""

from dataclasses import replace

import numba
import numpy as np
import pytest

from radiopose.likelihood import ReferenceScorer, candidate_space, exact_mse_db2
from radiopose.likelihood.candidates import HeardRss
from radiopose.likelihood.compiled import ShiftScorer, UnsupportedSpaceError
from radiopose.likelihood.topk import select_topk
from radiopose.patterns import isotropic, smartphone_like
from radiopose.simulate import ScenarioConfig, simulate

TX = "02:00:00:00:00:01"


@pytest.fixture(scope="module")
def space():
    cfg = ScenarioConfig(
        size_m=6.0,
        step_m=0.25,
        duration_s=0.05,
        noise_db=1.0,
        min_receiver_spacing_m=2.0,
        n_receivers=4,
    )
    return candidate_space(simulate(cfg, seed=20261123).site, TX)


def packets(space, rng, n=4):
    """Random RSS near the expected RSS of random true candidates (+ noise)."""
    from radiopose.likelihood.candidates import expected_rss_dbm

    out = []
    for _ in range(n):
        c = rng.integers(space.n_candidates)
        pos, ori = space.split(np.array([c]))
        rss = expected_rss_dbm(space, pos, ori)[0] + rng.normal(0, 1.5, space.n_receivers)
        out.append(HeardRss(np.arange(space.n_receivers), rss))
    return out


def same(a, b):
    np.testing.assert_array_equal(a.candidate_idx, b.candidate_idx)
    np.testing.assert_array_equal(a.mse_db2, b.mse_db2)


@pytest.mark.parametrize(("parallel", "spare"), [(False, True), (True, True), (True, False)])
@pytest.mark.parametrize("k", [1, 100])
def test_equals_reference(space, k, parallel, spare, monkeypatch):
    """Serial, parallel, and parallel on a busy machine (no core spare: the
    serial kernel, and the exact pass on one thread) give the reference's top-k."""
    import radiopose.likelihood.compiled as compiled

    monkeypatch.setattr(compiled, "spare_core", lambda: spare)
    rng = np.random.default_rng(1)
    fast, ref = ShiftScorer(space, parallel=parallel), ReferenceScorer(space)
    calls: list[int] = []
    kernel = fast._kernel
    fast._kernel = lambda *a: calls.append(1) or kernel(*a)
    for heard in packets(space, rng):
        same(fast.score_heard(heard, k), ref.score_heard(heard, k))
    assert bool(calls) == (parallel and spare)  # the parallel region only with a spare core


def test_threshold_pass_through_the_heaps_equals_reference(space, monkeypatch):
    """Threshold passes above DENSE_MAX_VALUES use the per-chunk heaps instead of
    the dense array (pitch/roll grids, cold starts on large sites); forced here."""
    import radiopose.likelihood.compiled as compiled

    monkeypatch.setattr(compiled, "DENSE_MAX_VALUES", 0)
    dense_calls = []
    monkeypatch.setattr(compiled, "_dense", lambda *a: dense_calls.append(a))
    rng = np.random.default_rng(4)
    fast, ref = ShiftScorer(space), ReferenceScorer(space)
    for heard in packets(space, rng):
        same(fast.score_heard(heard, 100), ref.score_heard(heard, 100))
    assert not dense_calls


def test_small_grids_run_serially_by_default(space):
    # 625 positions x 360 azimuths x 4 receivers = 900,000 terms: below PARALLEL_MIN_TERMS
    assert ShiftScorer(space).parallel is False
    assert ShiftScorer(space, parallel=True).parallel is True


@pytest.mark.parametrize("parallel", [False, True])
def test_missing_receivers_and_no_pruning(space, parallel):
    rng = np.random.default_rng(2)
    fast = ShiftScorer(space, parallel=parallel)
    plain, ref = ShiftScorer(space, prune=False, parallel=parallel), ReferenceScorer(space)
    for heard in packets(space, rng, 3):
        sub = HeardRss(heard.receiver_index[[0, 2, 3]], heard.rss_dbm[[0, 2, 3]])
        expect = ref.score_heard(sub, 50)
        same(fast.score_heard(sub, 50), expect)
        same(plain.score_heard(sub, 50), expect)


def test_ties_broken_by_index(space):
    """Isotropic pattern: all azimuths of a position tie exactly; lowest index wins."""
    iso = replace(space, pattern=isotropic())
    heard = packets(iso, np.random.default_rng(3), 1)[0]
    top = ShiftScorer(iso).score_heard(heard, 100)
    same(top, ReferenceScorer(iso).score_heard(heard, 100))
    assert np.all(np.diff(top.candidate_idx[top.mse_db2 == top.mse_db2[0]]) > 0)


def test_full_sphere_pattern_and_heights(space):
    """Receivers above and below the candidates: polar angles blend pattern rows."""
    rng = np.random.default_rng(4)
    sphere = smartphone_like(rng, "s", polar_step_deg=5.0)
    rx = space.receiver_positions_m.copy()
    rx[:, 2] += np.array([1.5, -0.7, 0.3, 2.5])
    s3 = replace(space, pattern=sphere, receiver_positions_m=rx)
    fast, ref = ShiftScorer(s3), ReferenceScorer(s3)
    for heard in packets(s3, rng, 3):
        same(fast.score_heard(heard, 60), ref.score_heard(heard, 60))


@pytest.mark.parametrize("step", [2.0, 0.5, 3.0])
def test_other_azimuth_steps(space, step):
    """2° and 3° candidates read a 1° pattern with a stride; 0.5° upsample it (exactly)."""
    n = round(360 / step)
    orient = np.column_stack([np.arange(n) * step, np.zeros(n), np.zeros(n)])
    from radiopose.geometry import orientation_matrices

    s2 = replace(space, orientations_deg=orient, rotations=orientation_matrices(*orient.T))
    rng = np.random.default_rng(5)
    fast, ref = ShiftScorer(s2), ReferenceScorer(s2)
    for heard in packets(s2, rng, 2):
        same(fast.score_heard(heard, 80), ref.score_heard(heard, 80))


def test_excluded_positions_never_selected(space):
    chan = space.channel_db.copy()
    chan[1, ::3] = np.nan
    s2 = replace(space, channel_db=chan)
    heard = packets(s2, np.random.default_rng(6), 1)[0]
    top = ShiftScorer(s2).score_heard(heard, 100)
    same(top, ReferenceScorer(s2).score_heard(heard, 100))
    assert not np.any((top.candidate_idx // s2.n_orientations) % 3 == 0)


def test_window_equals_exhaustive_window(space):
    rng = np.random.default_rng(7)
    fast = ShiftScorer(space)
    heard = packets(space, rng, 1)[0]
    positions = rng.choice(space.n_positions, 40, replace=False)
    for lo, span in ((350.0, 30.0), (10.0, 0.0), (0.0, 360.0), (123.4, 45.6)):
        az = np.arange(360.0)
        inside = ((az - lo) % 360.0 <= span + 1e-9) if span < 360 else np.ones(360, bool)
        cand = (np.sort(positions)[:, None] * 360 + np.flatnonzero(inside)[None]).ravel()
        expect = select_topk(cand, exact_mse_db2(space, heard, cand), 20)
        same(fast.score_window(heard, 20, positions, lo, span), expect)


def test_thread_count_does_not_change_results(space):
    heard = packets(space, np.random.default_rng(8), 1)[0]
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = ShiftScorer(space, parallel=True).score_heard(heard, 100)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = ShiftScorer(space, parallel=True).score_heard(heard, 100)
        serial = ShiftScorer(space, parallel=False).score_heard(heard, 100)
    finally:
        numba.set_num_threads(before)
    same(one, many)
    same(one, serial)


def test_unsupported_spaces(space):
    o = space.orientations_deg.copy()
    o[::2, 1] = 10.0  # pitch changing within an azimuth sweep
    with pytest.raises(UnsupportedSpaceError):
        ShiftScorer(replace(space, orientations_deg=o))
    n = 360 // 7 + 1
    o7 = np.column_stack([np.arange(n) * 7.0, np.zeros(n), np.zeros(n)])
    with pytest.raises(UnsupportedSpaceError):
        ShiftScorer(replace(space, orientations_deg=o7))


@pytest.mark.parametrize("sphere", [False, True])
def test_pitch_roll_candidates(space, sphere):
    """3-D orientation candidates: (pitch, roll) combinations × azimuths."""
    from radiopose.geometry import orientation_matrices
    from radiopose.site import OrientationGrid

    grid = OrientationGrid(10.0, (-20.0, 0.0, 30.0), (0.0, 15.0))
    o = grid.orientations_deg()
    rng = np.random.default_rng(9)
    pat = smartphone_like(rng, "s", polar_step_deg=5.0) if sphere else space.pattern
    s3 = replace(space, orientations_deg=o, rotations=orientation_matrices(*o.T), pattern=pat)
    fast, ref = ShiftScorer(s3), ReferenceScorer(s3)
    assert fast.n_q == 6 and fast.n_az == 36
    for heard in packets(s3, rng, 3):
        same(fast.score_heard(heard, 50), ref.score_heard(heard, 50))


def test_spare_core_threads_one_thread_when_busy_then_restored(monkeypatch):
    """On a busy machine the 3-D filter's parallel kernels run on one thread;
    the caller's thread count comes back afterwards (and is untouched when a
    core is spare)."""
    import numba

    import radiopose.likelihood.compiled as compiled

    before = numba.get_num_threads()
    monkeypatch.setattr(compiled, "spare_core", lambda: False)
    with compiled.spare_core_threads():
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    monkeypatch.setattr(compiled, "spare_core", lambda: True)
    with compiled.spare_core_threads():
        assert numba.get_num_threads() == before


@pytest.mark.parametrize("parallel", [False, True])
def test_k_beyond_the_grid_returns_every_candidate_best_first(space, parallel):
    """A k of more candidates than the grid holds (or, with ``search = "bounded"``,
    than the window holds) is every candidate in order, as the reference gives it;
    the kernel once asserted there ("no exclusion possible at full size")."""
    rng = np.random.default_rng(5)
    fast, ref = ShiftScorer(space, parallel=parallel), ReferenceScorer(space)
    k = space.n_candidates + 7
    for heard in packets(space, rng, n=2):
        top = fast.score_heard(heard, k)
        assert top.candidate_idx.size == space.n_candidates
        same(top, ref.score_heard(heard, k))


def test_a_busy_machine_does_not_launch_numbas_threads():
    """With no core spare, a parallel scorer's search (its heaps, main pass and
    exact pass) runs serially without starting numba's threading layer: once
    started as OpenMP, the process may no longer fork the filter's offline
    passes (forked.numba_fork_safe). A fresh process, since this one may have
    started it already."""
    import subprocess
    import sys

    code = f"""
import numba, numpy as np
import radiopose.likelihood.compiled as compiled
from radiopose.likelihood import candidate_space
from radiopose.likelihood.candidates import HeardRss
from radiopose.simulate import ScenarioConfig, simulate
cfg = ScenarioConfig(size_m=6.0, step_m=0.25, duration_s=0.05, min_receiver_spacing_m=2.0)
space = candidate_space(simulate(cfg, seed=20261123).site, {TX!r})
compiled.spare_core = lambda: False
compiled.DENSE_MAX_VALUES = 0  # the threshold pass through the heaps too
sc = compiled.ShiftScorer(space, parallel=True)
top = sc.score_heard(HeardRss(np.arange(4), np.array([-50.0, -55.0, -60.0, -52.0])), 5000)
assert top.candidate_idx.size == 5000
try:
    layer = numba.threading_layer()
except ValueError:
    layer = None
print(layer)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "None", out.stdout + out.stderr


def _tilted(space, pitches_deg, step_deg=10.0):
    """``space`` with the given pitches (roll 0) and its own (slice) pattern."""
    from radiopose.geometry import orientation_matrices
    from radiopose.site import OrientationGrid

    o = OrientationGrid(step_deg, tuple(pitches_deg), (0.0,)).orientations_deg()
    return replace(space, orientations_deg=o, rotations=orientation_matrices(*o.T))


@pytest.mark.parametrize("pitch", [89.0, 90.0])
def test_slice_pattern_at_pitch_near_90_scores_exactly_without_retries(space, pitch):
    """A horizontal slice seen at pitch ±89–90°: the body azimuth of a horizontal
    direction jumps by 180°, the rotated rows cannot be resampled closely
    (several dB), and the screened values cannot single out the k best. The
    scorer then scores its window exactly (bounded memory) instead of retrying
    with ever larger heaps up to the whole grid (2.9 GB and 7 s a packet on
    the paper's grid before); the top-k is the reference's either way."""
    s3 = _tilted(space, (-pitch, 0.0, pitch))
    fast, ref = ShiftScorer(s3), ReferenceScorer(s3)
    assert fast.resample_error_db > 2.0
    for heard in packets(s3, np.random.default_rng(11), 3):
        same(fast.score_heard(heard, 100), ref.score_heard(heard, 100))
    assert fast.exact_fallbacks == 3 and fast.retries == 0
    heard = packets(s3, np.random.default_rng(12), 1)[0]
    positions = np.random.default_rng(13).choice(s3.n_positions, 60, replace=False)
    cand = np.sort(positions)[:, None] * s3.n_orientations
    inside = np.flatnonzero(((np.arange(36) * 10.0 - 300.0) % 360.0) <= 90.0)
    orient = (np.arange(3)[:, None] * 36 + inside[None]).ravel()
    cand = (cand + orient[None]).ravel()
    expect = select_topk(cand, exact_mse_db2(s3, heard, cand), 20)
    same(fast.score_window(heard, 20, positions, 300.0, 90.0), expect)


def test_no_exact_fallback_where_the_rows_resample_closely(space):
    """Pitch 0 and ±80°: the screen works (the fallback is for speed only, and
    would cost speed where the screen prunes)."""
    rng = np.random.default_rng(14)
    for pitches in ((0.0,), (-80.0, 0.0, 80.0)):
        s3 = _tilted(space, pitches)
        fast = ShiftScorer(s3)
        for heard in packets(s3, rng, 3):
            same(fast.score_heard(heard, 100), ReferenceScorer(s3).score_heard(heard, 100))
        assert fast.exact_fallbacks == 0


def test_exact_fallback_skips_excluded_positions(space):
    s3 = _tilted(space, (-90.0, 0.0, 90.0))
    chan = s3.channel_db.copy()
    chan[2, ::4] = np.nan
    s4 = replace(s3, channel_db=chan)
    fast = ShiftScorer(s4)
    heard = packets(s4, np.random.default_rng(15), 1)[0]
    top = fast.score_heard(heard, 100)
    assert fast.exact_fallbacks == 1
    same(top, ReferenceScorer(s4).score_heard(heard, 100))
    assert not np.any((top.candidate_idx // s4.n_orientations) % 4 == 0)


def test_position_lower_bound_is_below_every_orientations_exact_mse(space):
    """The fallback's pruning bound: for every position, at most the exact MSE
    of each of its orientations (pitch ±90 and 0, a slice pattern)."""
    s3 = _tilted(space, (-90.0, 0.0, 90.0))
    fast = ShiftScorer(s3)
    for heard in packets(s3, np.random.default_rng(16), 3):
        lb = fast._position_lower_bound(heard, fast.all_positions)
        mse = exact_mse_db2(s3, heard, np.arange(s3.n_candidates))
        per_position = mse.reshape(s3.n_positions, s3.n_orientations).min(axis=1)
        assert np.all(lb <= per_position + 1e-9)
        assert np.mean(lb > 0) > 0.05  # it prunes something
