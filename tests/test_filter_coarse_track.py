"""Issue 15, search failures of the offline ``filter``: the whole file's coarse-grid
HMM (:mod:`radiopose.filtering.coarse_track`; ``FilterConfig.offline_coarse_track``;
docs/filter.md "Coarse-grid HMM").

* the compiled random walk (sum and max, with its arg-max shifts) against
  numpy/scipy on random grids;
* on the small site (σ = 0.5 dB) the best path follows the truth to within
  the grid's cell, the evidence finds the device's offset and moves with the
  readings; a silence longer than the gap starts a new track;
* the settings' one-line errors and the ``tracker.toml`` key; the flush hands
  the path to the arbiter as one more candidate only with the option; with a
  second core the path is found and refined on a child, with the serial
  estimates bit for bit; a handicap lets the path win only by its margin;
* end to end on tuning seed 7823 at +6 dB, σ = 3 dB: without the coarse path
  the offline filter keeps a wrong lock (111°), with it (the default) it
  leaves it (2.5°).

Tuning seeds only (7760–7879 and 7910–7969 chose the margin).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

import radiopose.filtering.coarse_track as coarse_track_module
import radiopose.filtering.forked as forked
import radiopose.filtering.offset_refit as offset_refit
import radiopose.filtering.refine2d as refine2d
import radiopose.tracker.filter as tracker_filter
from filter_support import SMALL, loud_run, require_wrong_mode, small_site, turned
from radiopose.errors import InputError
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig
from radiopose.filtering.coarse_track import (
    CoarseSettings,
    CoarseTrack,
    _kernel,
    _walk_max,
    _walk_sum,
    coarse_track,
    coarse_tracks,
    evidence_peaks,
)
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import HeardRss
from radiopose.simulate import simulate
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings


def _shifted(records: list, d_db: float) -> list:
    return [(t, HeardRss(h.receiver_index, h.rss_dbm + d_db), k) for t, h, k in records]


@settings(max_examples=25, deadline=None)
@given(
    st.integers(1, 6), st.integers(1, 6), st.integers(1, 9),
    st.floats(0.2, 1.5), st.floats(0.2, 1.5), st.integers(0, 2**31 - 1),
)  # fmt: skip
def test_walk_sum_is_the_separable_convolution(
    nx: int, ny: int, na: int, sx: float, sa: float, seed: int
) -> None:
    src = np.random.default_rng(seed).random((nx, ny, na))
    kx, ka = _kernel(sx), _kernel(sa)
    dst, tmp = np.empty_like(src), np.empty_like(src)
    _walk_sum(src, dst, tmp, kx, ka)
    want = ndimage.convolve1d(src, ka, axis=2, mode="wrap")
    want = ndimage.convolve1d(want, kx, axis=1, mode="constant", cval=0.0)
    want = ndimage.convolve1d(want, kx, axis=0, mode="constant", cval=0.0)
    if ka.size <= na:  # (scipy's wrap repeats a kernel longer than the axis differently)
        np.testing.assert_allclose(dst, want, rtol=1e-12, atol=1e-15)
    assert dst.sum() <= src.sum() + 1e-12  # mass may leave over x and y, never appear


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 7), st.integers(0, 2**31 - 1))
def test_walk_max_is_the_brute_force_max_and_its_shifts_reach_it(
    nx: int, ny: int, na: int, seed: int
) -> None:
    src = np.random.default_rng(seed).normal(size=(nx, ny, na))
    lx, la = np.log(_kernel(0.4)), np.log(_kernel(0.7))
    hx, ha = (lx.size - 1) // 2, (la.size - 1) // 2
    dst, tmp = np.empty_like(src), np.empty_like(src)
    arg = np.zeros((3, nx, ny, na), dtype=np.int8)
    _walk_max(src, dst, tmp, lx, la, arg)
    for i in range(nx):
        for j in range(ny):
            for a in range(na):
                best = -np.inf
                for dx in range(-hx, hx + 1):
                    for dy in range(-hx, hx + 1):
                        if not (0 <= i - dx < nx and 0 <= j - dy < ny):
                            continue
                        for da in range(-ha, ha + 1):
                            v = src[i - dx, j - dy, (a - da) % na] + lx[dx + hx] + lx[dy + hx]
                            best = max(best, v + la[da + ha])
                assert dst[i, j, a] == pytest.approx(best, rel=1e-12, abs=1e-12)
                # the stored shifts lead back to a source cell scoring that max
                dx = int(arg[0, i, j, a])
                dy = int(arg[1, i - dx, j, a])
                da = int(arg[2, i - dx, j - dy, a])
                v = src[i - dx, j - dy, (a - da) % na] + lx[dx + hx] + lx[dy + hx] + la[da + ha]
                assert v == pytest.approx(best, rel=1e-12, abs=1e-12)


def test_the_path_follows_the_truth_and_the_evidence_finds_the_offset() -> None:
    site = small_site()
    t = np.array([r[0] for r in site.records])
    gap = FilterConfig().reacquire_gap_s
    for d in (0.0, 6.0, -4.0):
        ct = coarse_track(site.model, _shifted(site.records, d), 0.5, gap)
        assert ct.offset_db == pytest.approx(d, abs=1.0)
        xy, az = ct.poses_at(t)
        pos_err = np.linalg.norm(xy - site.position_m[:, :2], axis=1)
        ori = np.column_stack([az, np.zeros_like(az), np.zeros_like(az)])
        # the grid's cells are 1 m and 15°: within a cell (diagonal 0.71 m, 7.5°)
        assert pos_err.mean() < 0.71
        assert orientation_error_deg(ori, site.orientation_deg).mean() < 7.5
    # louder readings move the evidence over the offsets by as much
    base = coarse_track(site.model, site.records, 0.5, gap)
    up = coarse_track(
        site.model, _shifted(site.records, 2.0), 0.5, gap,
        CoarseSettings(offsets_db=tuple(float(v) + 2.0 for v in range(-12, 13))),
    )  # fmt: skip
    np.testing.assert_allclose(up.log_evidence, base.log_evidence, rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(up.window_poses, base.window_poses)


def test_a_silence_starts_a_new_track_and_no_window_is_no_path() -> None:
    site = small_site()
    gap = FilterConfig().reacquire_gap_s
    late = [(t + 10.0 * gap, h, ("late", k)) for t, h, k in site.records]
    ct = coarse_track(site.model, site.records + late, 0.5, gap)
    assert set(ct.window_track.tolist()) == {0, 1}
    assert ct.window_times_s.size == 10  # 0.5 s in windows of 0.1 s, twice
    # each half's path is the half's own (the same readings, the same path)
    half = ct.window_track == 0
    np.testing.assert_array_equal(ct.window_poses[half], ct.window_poses[~half])
    empty = coarse_track(site.model, [], 0.5, gap)
    assert math.isnan(empty.offset_db) and empty.window_times_s.size == 0
    with pytest.raises(InputError, match="no window"):
        empty.poses_at(np.array([0.0]))
    with pytest.raises(InputError, match="sigma_db"):
        coarse_track(site.model, site.records, 0.0, gap)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window_s": 0.0}, "window_s"),
        ({"position_step_m": math.nan}, "position_step_m"),
        ({"offsets_db": ()}, "offsets"),
        ({"max_steps": 0}, "max_steps"),
    ],
)
def test_settings_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        CoarseSettings(**kwargs)


def test_tracker_toml_key(tmp_path: Path) -> None:
    assert FilterConfig().offline_coarse_track is True  # on by default since session 13
    assert FilterConfig().coarse_track_margin == 2.0
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\noffline_coarse_track = true\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides["offline_coarse_track"] is True
    p.write_text("[filter]\noffline_coarse_track = 1\n", encoding="utf-8")
    with pytest.raises(InputError, match="offline_coarse_track"):
        read_tracker_settings(p)
    p.write_text("[filter]\ncoarse_track_margin = 2.5\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides["coarse_track_margin"] == 2.5
    p.write_text('[filter]\ncoarse_track_margin = "big"\n', encoding="utf-8")
    with pytest.raises(InputError, match="coarse_track_margin"):
        read_tracker_settings(p)


def test_the_flush_adds_the_path_as_a_candidate_only_with_the_option(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen: list[tuple[int, tuple[float, ...]]] = []
    arbitrate0 = offset_refit.arbitrate

    def arbitrate(model, records, candidates, *a, **kw):  # type: ignore[no-untyped-def]
        seen.append((len(candidates), tuple(kw["handicaps_nats"])))
        return arbitrate0(model, records, candidates, *a, **kw)

    monkeypatch.setattr(offset_refit, "arbitrate", arbitrate)
    paths: list[int] = []
    coarse_tracks0 = coarse_track_module.coarse_tracks

    def counted(*a, **kw):  # type: ignore[no-untyped-def]
        out = coarse_tracks0(*a, **kw)
        paths.append(len(out))
        return out

    monkeypatch.setattr(coarse_track_module, "coarse_tracks", counted)
    sim = simulate(replace(SMALL, noise_db=3.0), 11)
    scorer = build_scorer(sim, "numba")
    for on, n in ((False, 1), (True, 1), (True, 3)):  # default: on, one path
        f = FilterConfig(
            offline_coarse_track=on,
            coarse_track_paths=n,
            coarse_track_margin=1.5,
            offline_workers=1,
        )  # (counted here, not on a child)
        run = run_methods(sim, ("filter",), TrackerConfig(filter=f), scorer)["filter"]
        assert run.summary.coverage == 1.0
    assert len(seen) == 3 and paths[0] == 1 and 1 < paths[1] <= 3
    (n0, h0), (n1, h1), (n3, h3) = seen
    assert n1 == n0 + 1 and n3 == n0 + paths[1]  # one candidate per path
    assert h1 == (*h0, 1.5) and h3 == h0 + (1.5,) * paths[1]  # each with the margin


def test_the_coarse_child_gives_the_serial_answer(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a second core the path and its refinement are computed on a child
    while the parent runs the reversed pass; the estimates are the serial ones,
    bit for bit, and the child's refinement is the one the arbiter uses."""
    # (these runs' children never enter a parallel region: the filter's
    # one-thread scorer; tests/test_filter_offline_workers.py): set before the
    # check, which an earlier test's parallel kernel would otherwise fail
    monkeypatch.setattr(forked, "numba_fork_safe", lambda: True)
    if forked.effective_workers(2) < 2:
        pytest.skip("needs fork and two cores")
    sim = simulate(replace(SMALL, duration_s=1.5, noise_db=1.0), 5)

    def cfg(workers: int) -> TrackerConfig:
        return TrackerConfig(
            filter=FilterConfig(offline_coarse_track=True, offline_workers=workers)
        )

    serial = locate(sim.site, sim.packets, "filter", cfg(1)).estimates
    started: list[bool] = []
    try_fork0 = tracker_filter.try_fork

    def try_fork(fn):  # type: ignore[no-untyped-def]
        if getattr(fn, "func", None) is tracker_filter._coarse_refined:
            started.append(fn.args[-1])  # refine=True: the child refines it too
        return try_fork0(fn)

    monkeypatch.setattr(tracker_filter, "try_fork", try_fork)
    parallel = locate(sim.site, sim.packets, "filter", cfg(2)).estimates
    assert started == [True]
    np.testing.assert_array_equal(parallel.position_m, serial.position_m)
    np.testing.assert_array_equal(parallel.orientation_deg, serial.orientation_deg)


def test_refinements_computed_ahead_spare_the_arbiter_their_work(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    site = small_site()
    cfg = FilterConfig()
    cand = turned(site.truth, site.records, 3, 30)
    ahead = refine2d.refine_for_arbiter(site.model, site.records, site.truth, [cand], 0.5, cfg, 5)
    assert len(ahead) == 1  # one track, the candidate's refinement only
    calls: list[int] = []
    refine0 = refine2d.refine_track_2d

    def counted(*a, **kw):  # type: ignore[no-untyped-def]
        calls.append(1)
        return refine0(*a, **kw)

    monkeypatch.setattr(refine2d, "refine_track_2d", counted)
    cache = dict(ahead)
    out, log = refine2d.arbitrate(site.model, site.records, [site.truth, cand], 0.5, cfg, 5,
                                  cache=cache)  # fmt: skip
    assert len(calls) == 1  # the reference's; the candidate's came from the cache
    fresh, log2 = refine2d.arbitrate(site.model, site.records, [site.truth, cand], 0.5, cfg, 5)
    assert log == log2 and out == fresh  # the same answer as computing it here


def test_a_handicap_makes_an_outsider_win_only_by_its_margin() -> None:
    site = small_site()
    cfg = FilterConfig()
    wrong = turned(site.truth, site.records, 3, 30)
    args = (site.model, site.records, [wrong, site.truth], 0.5, cfg, 5)
    _, log = refine2d.arbitrate(*args)
    gap = log[0].costs[0] - log[0].costs[1]
    assert log[0].chosen == 1 and gap > 0  # the truth wins on its objective
    _, log = refine2d.arbitrate(*args, handicaps_nats=[0.0, gap - 0.01])
    assert log[0].chosen == 1 and log[0].penalties == (0.0, gap - 0.01)
    _, log = refine2d.arbitrate(*args, handicaps_nats=[0.0, gap + 0.01])
    assert log[0].chosen == 0  # not by more than its margin: the reference stays
    with pytest.raises(InputError, match="handicaps"):
        refine2d.arbitrate(*args, handicaps_nats=[0.0])
    with pytest.raises(InputError, match="handicaps"):
        refine2d.arbitrate(*args, handicaps_nats=[0.0, math.nan])
    with pytest.raises(InputError, match="coarse_track_margin"):
        FilterConfig(coarse_track_margin=-1.0)


def test_loud_search_failure_left_only_with_the_coarse_path() -> None:
    """Tuning seed 7823 (σ = 3 dB, +6 dB; docs/filter.md "Coarse-grid HMM"): the
    offset selection's passes ran at 0 and +2.6 dB only and every candidate of
    the arbiter is a wrong lock (111°, 7.7 m); the coarse path, refined, is in
    the truth's basin by 24 objective units (2.5°, 0.22 m). The part removed
    (the option off) leaves the wrong lock."""
    pos_on, ori_on = loud_run(
        7823, 3.0, TrackerConfig(), offline_coarse_track=True, coarse_track_margin=2.0
    )
    assert ori_on < 6.0 and pos_on < 0.5  # measured 2.46°, 0.221 m
    pos_off, ori_off = loud_run(7823, 3.0, TrackerConfig(), offline_coarse_track=False)
    require_wrong_mode(ori_off, 40.0, "coarse path off")  # measured 111.3°, 7.69 m
    assert pos_off > 1.5


def test_poses_at_interpolates_within_the_nearest_windows_track() -> None:
    wt = np.array([0.05, 0.15, 0.25, 5.0, 5.1])
    poses = np.array([[0, 0, 350], [1, 0, 10], [2, 0, 20], [5, 5, 90], [6, 5, 100]], dtype=float)
    ct = CoarseTrack(np.zeros(1), np.zeros(1), 0.0, wt, poses, np.array([0, 0, 0, 1, 1]))
    xy, az = ct.poses_at(np.array([0.0, 0.1, 0.2, 2.0, 3.0, 5.05, 6.0]))
    np.testing.assert_allclose(xy[:, 0], [0.0, 0.5, 1.5, 2.0, 5.0, 5.5, 6.0])
    # the azimuth through north (350° → 10°), each time held by its nearest track's ends
    np.testing.assert_allclose(az, [350.0, 0.0, 15.0, 20.0, 90.0, 95.0, 100.0], atol=1e-9)
    one = CoarseTrack(np.zeros(1), np.zeros(1), 0.0, wt[:1], poses[:1], np.array([0]))
    np.testing.assert_allclose(one.poses_at(np.array([0.0, 9.0]))[1], [350.0, 350.0])


def test_the_chunked_backtrack_is_the_whole_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Viterbi back-pointers are kept one chunk at a time (bounded memory on
    long files); any chunk length gives the same path, gaps included."""
    site = small_site()
    gap = FilterConfig().reacquire_gap_s
    records = site.records[:40] + site.records[70:]  # a hole of several walk steps
    whole = coarse_track(site.model, records, 0.5, gap)
    for n in (1, 2, 3):
        monkeypatch.setattr(coarse_track_module, "_CHUNK_WINDOWS", n)
        chunked = coarse_track(site.model, records, 0.5, gap)
        np.testing.assert_array_equal(chunked.window_poses, whole.window_poses)
        np.testing.assert_array_equal(chunked.log_evidence, whole.log_evidence)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.integers(-5, 5).map(float), st.just(-math.inf)), min_size=1,
                max_size=12))  # fmt: skip
def test_evidence_peaks_are_the_local_maxima_largest_first(values: list[float]) -> None:
    ll = np.array(values)
    peaks = evidence_peaks(ll)
    assert peaks[0] == int(np.argmax(ll))  # the first path is the one of the largest ℓ
    assert len(set(peaks)) == len(peaks)
    if np.isfinite(ll).any():
        for i in peaks:
            assert np.isfinite(ll[i])
            assert i == 0 or ll[i] > ll[i - 1]
            assert i == ll.size - 1 or ll[i] >= ll[i + 1]
        assert [ll[i] for i in peaks] == sorted((ll[i] for i in peaks), reverse=True)
        # every strict local maximum is there
        for i in range(ll.size):
            left = i == 0 or ll[i] > ll[i - 1]
            right = i == ll.size - 1 or ll[i] > ll[i + 1]
            if np.isfinite(ll[i]) and left and right:
                assert i in peaks


def test_evidence_peaks_examples() -> None:
    assert evidence_peaks(np.array([0.0, 2.0, 1.0, 3.0, 0.0])) == [3, 1]
    assert evidence_peaks(np.array([1.0, 1.0, 0.0])) == [0]  # a plateau: its first index
    assert evidence_peaks(np.array([0.0, 1.0, 1.0, 2.0])) == [3, 1]
    assert evidence_peaks(np.array([-math.inf, -math.inf])) == [0]


def test_more_paths_start_with_the_best_and_sit_at_other_peaks() -> None:
    """``coarse_tracks(paths=3)``: the first is :func:`coarse_track`'s path; each
    further one is the Viterbi path at another local maximum of the evidence,
    which is what ``coarse_tracks`` at that single offset gives."""
    site = small_site()
    gap = FilterConfig().reacquire_gap_s
    best = coarse_track(site.model, site.records, 3.0, gap)
    cts = coarse_tracks(site.model, site.records, 3.0, gap, paths=3)
    peaks = evidence_peaks(best.log_evidence)
    assert len(cts) == min(3, len(peaks)) and len(cts) >= 2  # σ 3 dB: the ℓ has side peaks
    np.testing.assert_array_equal(cts[0].window_poses, best.window_poses)
    assert cts[0].offset_db == best.offset_db
    for ct, i in zip(cts, peaks, strict=False):
        assert ct.offset_db == best.offsets_db[i]
        one = coarse_track(site.model, site.records, 3.0, gap,
                           CoarseSettings(offsets_db=(ct.offset_db,)))  # fmt: skip
        np.testing.assert_array_equal(ct.window_poses, one.window_poses)
    with pytest.raises(InputError, match="paths"):
        coarse_tracks(site.model, site.records, 3.0, gap, paths=0)


@pytest.mark.parametrize("bad", [0, 9, 1.5, True, "2"])
def test_coarse_track_paths_setting_is_checked(bad: object, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="coarse_track_paths"):
        FilterConfig(coarse_track_paths=bad)  # type: ignore[arg-type]
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\ncoarse_track_paths = 3\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides["coarse_track_paths"] == 3


def test_a_finer_path_grid_keeps_the_evidence_and_follows_the_truth_closer() -> None:
    """``path_position_step_m`` (session 14): the evidence over the offsets is
    the 1 m grid's, bit for bit, and so is the offset of the path; the path
    lies on the finer grid and, at the device's own offset (σ = 0.5 dB, the
    small site), closer to the truth than the 1 m path (measured 0.22 m
    against 0.28 m). (This short file's evidence peaks at +1 dB, where the
    0.5 m path is the farther one, 0.53 m: the path's quality rests on the
    offset's; the arbiter's refinement frees both.)"""
    site = small_site()
    t = np.array([r[0] for r in site.records])
    gap = FilterConfig().reacquire_gap_s
    coarse = coarse_track(site.model, site.records, 0.5, gap)
    fine = coarse_track(site.model, site.records, 0.5, gap,
                        CoarseSettings(path_position_step_m=0.5))  # fmt: skip
    np.testing.assert_array_equal(fine.log_evidence, coarse.log_evidence)
    assert fine.offset_db == coarse.offset_db
    errs = []
    for step in (1.0, 0.5):
        ct = coarse_track(site.model, site.records, 0.5, gap,
                          CoarseSettings(offsets_db=(0.0,), path_position_step_m=step))  # fmt: skip
        x_lo, _, y_lo, _ = (float(v) for v in site.model.box_m)
        cells = (ct.window_poses[:, :2] - [x_lo, y_lo]) / step
        np.testing.assert_allclose(cells, np.round(cells), atol=1e-9)  # on its grid
        xy, _ = ct.poses_at(t)
        errs.append(float(np.linalg.norm(xy - site.position_m[:, :2], axis=1).mean()))
    assert errs[1] < errs[0] < 0.71  # within a 1 m cell, the finer path closer


@pytest.mark.parametrize("bad", [0.0, -1.0, 6.0, math.nan, True, "0.5"])
def test_coarse_track_path_step_setting_is_checked(bad: object, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="coarse_track_path_step_m"):
        FilterConfig(coarse_track_path_step_m=bad)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="path_position_step_m"):
        CoarseSettings(path_position_step_m=0.0)
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\ncoarse_track_path_step_m = 0.25\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides["coarse_track_path_step_m"] == 0.25


def test_loud_search_failure_left_only_with_the_finer_path() -> None:
    """Tuning seed 8028 (σ = 3 dB, +6 dB; docs/filter.md "Coarse-grid HMM: a
    finer path"): the 1 m path refines into a basin 1 m off (objective 905
    against the truth's 885) and the arbiter keeps a 167° lock (896); the
    0.5 m path at the same offset refines to the truth's optimum. The part
    removed (the 1 m path) leaves the wrong lock."""
    pos_on, ori_on = loud_run(8028, 3.0, TrackerConfig(), coarse_track_path_step_m=0.5)
    assert ori_on < 6.0 and pos_on < 0.5  # measured 1.59°, 0.172 m
    pos_off, ori_off = loud_run(8028, 3.0, TrackerConfig(), coarse_track_path_step_m=1.0)
    require_wrong_mode(ori_off, 40.0, "1 m path")  # measured 167.1°, 1.20 m
    assert pos_off > 0.8
