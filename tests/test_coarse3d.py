"""The whole-file coarse HMM in 3-D as a refinement start (radiopose.filtering.coarse3d;
docs/pose3d.md, "A coarse-path start, 2026-11-28"): the compiled profile against
numpy, the nearest window, the path on a noise-free scene, the offset's
evidence, the refinement's use of the start, settings."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from filter_support import scene_3d
from radiopose.errors import InputError
from radiopose.filtering.coarse3d import (
    CoarseScorer,
    CoarseWindow,
    _axes,
    coarse_path3d,
    coarse_paths3d,
    nearest,
    offset_evidence,
    viterbi_nd,
    window_index,
)
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import HeardRss


@pytest.fixture(scope="module")
def scene():
    sim, space, _, model, obs = scene_3d()
    heard = [space.heard(o) for o in obs]
    t = np.array([o.timestamp_s for o in obs])
    return sim, model, t, heard


@given(
    st.lists(st.floats(-100, 100), min_size=1, max_size=20),
    st.lists(st.floats(-120, 120), min_size=1, max_size=20),
)
def test_nearest_is_the_closest(ref, t):
    ref_a, t_a = np.sort(np.array(ref)), np.array(t)
    got = nearest(ref_a, t_a)
    d = np.abs(t_a[:, None] - ref_a[None, :])
    assert np.array_equal(d[np.arange(t_a.size), got], d.min(axis=1))


def test_nearest_takes_the_earlier_on_a_tie():
    ref = np.array([0.0, 1.0, 2.0, 4.0])
    assert nearest(ref, np.array([-1.0, 0.5, 1.5, 3.0, 9.0])).tolist() == [0, 0, 1, 2, 3]
    assert nearest(np.array([7.0]), np.array([1.0, 9.0])).tolist() == [0, 0]


def test_window_index_and_its_error():
    assert window_index(np.array([5.0, 5.05, 5.25, 5.35]), 0.1).tolist() == [0, 0, 2, 3]
    with pytest.raises(InputError, match="window_s") as exc:
        window_index(np.array([0.0]), 0.0)
    assert "\n" not in str(exc.value)


def test_the_compiled_profile_is_numpys(scene):
    """:func:`_profile` equals the cost of every grid row minimised over height
    by numpy, per (x, y, azimuth, pitch, roll) cell, at several offsets, for a
    window of four receivers (and over the tilts too without them); the best
    rows at a cell are that minimum's."""
    _, model, _, _ = scene
    grid = model.coarse
    _, shape = _axes(grid)
    rng = np.random.default_rng(5)
    rx = np.array([0, 2, 3, 6])
    med = rng.uniform(-80, -40, rx.size)
    w = rng.uniform(0.2, 1.0, rx.size)
    offs = np.array([-3.0, 0.0, 2.5])
    sc = CoarseScorer(grid)
    win = CoarseWindow(0, rx, med, w, 0.0)
    got = sc.cost(win, offs)
    e = med[None, :] - grid.table_dbm[:, rx].astype(float)
    for j, b in enumerate(offs):
        row = (0.5 * ((e - b) ** 2) @ w).reshape(shape)  # (pitch, roll, az, x, y, z)
        want = row.transpose(3, 4, 2, 0, 1, 5).min(axis=5)
        np.testing.assert_allclose(got[..., j], want, rtol=1e-5, atol=1e-6)
    cell = (2, 3, 5, 1, 2)
    rows = (0.5 * (e**2) @ w).reshape(shape).transpose(3, 4, 2, 0, 1, 5)
    ip, ir, k = sc.best_rows(win, 0.0, cell)
    assert (ip, ir) == cell[3:] and rows[cell][k] == pytest.approx(got[(*cell, 1)])
    # over every tilt too: the cost minimised over pitch, roll and height there
    flat = sc.cost(win, offs, tilts=False)
    np.testing.assert_allclose(flat, got.min(axis=(3, 4)), rtol=1e-12)
    ip, ir, k = sc.best_rows(win, 0.0, cell[:3])
    assert rows[(*cell[:3], ip, ir)][k] == pytest.approx(flat[(*cell[:3], 1)])


def _brute_force(cost, steps_before, log_k, wraps):
    """The best path of a tiny 2-axis HMM by enumerating every path."""
    import itertools

    n_w, shape = cost.shape[0], cost.shape[1:]
    cells = list(itertools.product(*(range(n) for n in shape)))
    h = [(k.size - 1) // 2 for k in log_k]

    def move(a, b):  # log probability of one step a -> b
        s = 0.0
        for ax in range(2):
            d = b[ax] - a[ax]
            if wraps[ax]:
                d = (d + shape[ax] // 2) % shape[ax] - shape[ax] // 2
            if abs(d) > h[ax]:
                return -np.inf
            s += log_k[ax][d + h[ax]]
        return s

    best, arg = -np.inf, None
    for path in itertools.product(cells, repeat=n_w):
        v = -sum(cost[q][path[q]] for q in range(n_w))
        for q in range(1, n_w):
            v += move(path[q - 1], path[q])
        if v > best:
            best, arg = v, path
    return [tuple(c) for c in arg]


def test_viterbi_nd_is_the_best_path():
    """On a tiny HMM (3 × 4 cells, the second axis wrapping, 4 windows) the
    N-D Viterbi's path is the one of the largest score over all 12⁴ paths; on
    a 3-axis grid it equals the 2-D filter's own Viterbi
    (:func:`radiopose.filtering.coarse_track._viterbi_path`)."""
    from radiopose.filtering.coarse_track import _kernel, _viterbi_path

    rng = np.random.default_rng(11)
    cost = rng.uniform(0, 4, (4, 3, 4))
    lk = [np.log(np.array([0.2, 0.6, 0.2])), np.log(np.array([0.3, 0.45, 0.25]))]
    got = viterbi_nd([0, 1, 1, 1], lambda q: cost[q], (3, 4), lk, [False, True])
    assert got == _brute_force(cost, [0, 1, 1, 1], lk, [False, True])

    cost3 = rng.uniform(0, 6, (70, 5, 4, 6))  # more windows than a chunk
    steps = [0] + [int(v) for v in rng.integers(1, 3, 69)]
    kx, ka = _kernel(0.7), _kernel(1.2)
    want = _viterbi_path([(s, None, None) for s in steps], np.zeros(70, dtype=np.int64),
                         lambda q: (cost3[q], np.zeros((5, 4, 6)), 0.0), 0.0, (5, 4, 6),
                         np.log(kx), np.log(ka))  # fmt: skip
    got3 = viterbi_nd(steps, lambda q: cost3[q], (5, 4, 6),
                      [np.log(kx), np.log(kx), np.log(ka)], [False, False, True])  # fmt: skip
    assert got3 == [tuple(c) for c in want]
    with pytest.raises(InputError, match="one kernel"):
        viterbi_nd([0], lambda q: cost3[0], (5, 4, 6), [np.log(kx)], [False])


def test_the_path_follows_the_walk_noise_free(scene):
    """On the noise-free scene the coarse path is within the grid's cells of
    the truth: positions within a metre (a 1 m grid), azimuths within a 15°
    step on average, every packet a pose; the evidence peaks at the device's
    own offset (0 dB)."""
    sim, model, t, heard = scene
    got = coarse_path3d(model.coarse, t, heard, 1.0)
    assert got is not None
    pos, ori, off = got
    assert pos.shape == ori.shape == (t.size, 3)
    tp, to = sim.truth.position_m, sim.truth.orientation_deg
    assert np.linalg.norm(pos[:, :2] - tp[:, :2], axis=1).mean() < 1.0
    az = np.abs((ori[:, 0] - to[:, 0] + 180.0) % 360.0 - 180.0)
    assert az.mean() < 15.0
    assert off == 0.0
    ll = offset_evidence(model.coarse, t, heard, 1.0, offsets_db=(-4.0, 0.0, 4.0))
    assert int(np.argmax(ll)) == 1 and ll[1] - max(ll[0], ll[2]) > 5.0
    # a path held at a wrong offset is further from the truth
    far = coarse_path3d(model.coarse, t, heard, 1.0, offset_db=-6.0)
    assert far is not None and far[2] == -6.0
    near_rot = orientation_error_deg(ori, to).mean()
    far_rot = orientation_error_deg(far[1], to).mean()
    assert far_rot > near_rot


def test_more_paths_are_at_other_offsets_and_tilts_can_walk(scene, monkeypatch):
    """``paths = 3``: the paths at the evidence's three largest local maxima
    (a three-peaked evidence: 0, −4 and +3 dB), the best first and equal to
    the single path; with the tilts as walking states the noise-free path is
    as close as without."""
    import radiopose.filtering.coarse3d as c3

    sim, model, t, heard = scene
    offs = np.array(c3.OFFSETS_DB)
    ll = -np.abs(offs) * 3.0
    ll[offs == -4.0], ll[offs == 3.0] = -1.0, -2.0
    monkeypatch.setattr(c3, "_evidence", lambda *a, **k: ll)
    one = coarse_path3d(model.coarse, t, heard, 1.0)
    three = coarse_paths3d(model.coarse, t, heard, 1.0, paths=3)
    assert [p[2] for p in three] == [0.0, -4.0, 3.0]
    assert one is not None and np.array_equal(three[0][0], one[0]) and three[0][2] == one[2]
    assert len(coarse_paths3d(model.coarse, t, heard, 1.0, paths=2)) == 2
    walked = coarse_path3d(model.coarse, t, heard, 1.0, tilt_walk_deg=9.0)
    assert walked is not None
    to = sim.truth.orientation_deg
    az = np.abs((walked[1][:, 0] - to[:, 0] + 180.0) % 360.0 - 180.0)
    assert az.mean() < 15.0


def test_a_shifted_power_moves_the_evidence(scene):
    """Readings 3 dB above the enrolled power: the evidence's offset follows (+3 dB)."""
    _, model, t, heard = scene
    loud = [HeardRss(h.receiver_index, np.asarray(h.rss_dbm) + 3.0) for h in heard]
    got = coarse_path3d(model.coarse, t, loud, 1.0)
    assert got is not None and got[2] == 3.0


def test_too_few_receivers_give_no_path_and_bad_settings_are_errors(scene):
    _, model, t, heard = scene
    two = [HeardRss(h.receiver_index[:2], np.asarray(h.rss_dbm)[:2]) for h in heard]
    assert coarse_path3d(model.coarse, t, two, 1.0) is None
    assert coarse_paths3d(model.coarse, t, two, 1.0, paths=3) == []
    assert np.all(offset_evidence(model.coarse, t, two, 1.0) == -np.inf)
    assert coarse_path3d(model.coarse, t[:0], heard[:0], 1.0) is None
    for kw in ({"sigma_db": 0.0}, {"sigma_db": 1.0, "walk_m": 0.0},
               {"sigma_db": 1.0, "walk_deg": math.nan}):  # fmt: skip
        with pytest.raises(InputError, match="3-D coarse path") as exc:
            coarse_path3d(model.coarse, t, heard, **kw)
        assert "\n" not in str(exc.value)
    for name in ("refine_coarse_walk_m", "refine_coarse_walk_deg"):
        with pytest.raises(InputError, match=name):
            Pose3dConfig(**{name: 0.0})
    for n in (0, 9):
        with pytest.raises(InputError, match="refine_coarse_paths"):
            Pose3dConfig(refine_coarse_paths=n)
    with pytest.raises(InputError, match="paths"):
        coarse_paths3d(model.coarse, t, heard, 1.0, paths=0)
    with pytest.raises(InputError, match="tilt_walk_deg"):
        coarse_paths3d(model.coarse, t, heard, 1.0, tilt_walk_deg=-1.0)
    assert Pose3dConfig().refine_coarse_path  # the default since 2026-11-28


def test_the_refinement_takes_the_coarse_start_when_the_filters_are_wrong(scene):
    """Every filter start 1.5 m and 120° off: refined alone they stay there; with
    the coarse path as one more start the refinement reaches the truth."""
    from radiopose.filtering import FilterConfig, FilterEstimate
    from radiopose.filtering.refine3d import refine_smoothed

    sim, model, t, heard = scene
    tp, to = sim.truth.position_m, sim.truth.orientation_deg
    bad = [((i,), FilterEstimate(tuple(tp[i] + [1.5, -1.5, 0.0]),
                                 tuple(to[i] + [120.0, 0.0, 0.0]), 0.1, 1.0, 0.0, 0.5))
           for i in range(t.size)]  # fmt: skip
    records = [(t[i], heard[i], (i,)) for i in range(t.size)]
    p3 = Pose3dConfig()

    def run(coarse):
        out = refine_smoothed(
            model, records, bad, FilterConfig(), p3.height_noise_mps, p3.tilt_noise_dps, 100,
            coarse_start=coarse,
        )  # fmt: skip
        ori = np.array([e.orientation_deg for _, e in out])
        return float(orientation_error_deg(ori, to).mean())

    from functools import partial

    assert run(None) > 30.0
    assert run(partial(coarse_paths3d, model.coarse)) < 3.0


def test_locate_reads_the_setting(monkeypatch):
    """``refine_coarse_path`` on: ``locate`` hands the refinement a coarse start
    (off: none), with the settings' walk."""
    import radiopose.filtering.refine3d as r3
    from radiopose.tracker import TrackerConfig, locate

    sim, *_ = scene_3d()
    seen: list[object] = []

    def spy(model, records, smoothed, *args, **kw):
        seen.append(kw.get("coarse_start"))
        return list(smoothed)  # (the refinement itself is not this test's)

    monkeypatch.setattr(r3, "refine_smoothed", spy)
    base = TrackerConfig()
    for on in (False, True):
        # (no escalation: the spy's unrefined track would be refined a second time)
        p3 = replace(base.pose3d, refine_coarse_path=on, refine_coarse_walk_m=0.5,
                     refine_reverse_pass=False, refine_escalate_ratio=0.0)  # fmt: skip
        cfg = replace(base, pose3d=p3)
        locate(sim.site, sim.packets, "filter", cfg)
    assert seen[0] is None
    assert seen[1] is not None and seen[1].keywords["walk_m"] == 0.5
