"""The filter's compiled per-packet mechanics against plain numpy definitions:
the σ median, the posterior moments, in-place resampling and the smoother's
genealogy ring (growth, resampling, re-entered hypotheses, pickling), and the
motion noise's counter-based draws.

Seeds 4301-4310 are used here only.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from radiopose.filtering import kernels as K  # noqa: N812
from radiopose.filtering.lineage import Lineage

POSE = [K.X_M, K.Y_M, K.Z_M, K.AZIMUTH_RAD, K.PITCH_RAD, K.ROLL_RAD]


def _particles(rng: np.random.Generator, n: int) -> np.ndarray:
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M] = rng.uniform(0, 20, n)
    S[:, K.Y_M] = rng.uniform(0, 20, n)
    S[:, K.Z_M] = 1.0
    S[:, K.VX_MPS] = rng.normal(0, 1, n)
    S[:, K.VY_MPS] = rng.normal(0, 1, n)
    S[:, K.AZIMUTH_RAD] = rng.uniform(0, 2 * np.pi, n)
    S[:, K.RATE_RAD_S] = rng.normal(0, 1, n)
    S[:, K.PITCH_RAD] = rng.choice([0.0, 0.3], n)
    S[:, K.ROLL_RAD] = rng.choice([0.0, -0.2], n)
    S[:, K.OFFSET_DB] = rng.normal(0, 2, n)
    return S


def _weights(rng: np.random.Generator, n: int) -> np.ndarray:
    w = rng.exponential(1.0, n) ** 3
    return w / w.sum()


def _summary_numpy(rows: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The moments as the filter computed them before they were compiled."""
    x, y, z = (float(np.sum(w * rows[:, c])) for c in range(3))
    return np.array(
        [
            x,
            y,
            z,
            np.sum(w * np.cos(rows[:, 3])),
            np.sum(w * np.sin(rows[:, 3])),
            np.sum(w * rows[:, 4]),
            np.sum(w * np.cos(rows[:, 5])),
            np.sum(w * np.sin(rows[:, 5])),
            np.sum(w * ((rows[:, 0] - x) ** 2 + (rows[:, 1] - y) ** 2)),
        ]
    )


@pytest.mark.parametrize("seed", [4301, 4302, 4303])
def test_sampled_median_lies_at_the_weighted_median(seed):
    """The σ update's median of 256 systematic draws sits at cumulative weight
    ½ of the exact weighted distribution, to the draws' resolution."""
    rng = np.random.default_rng(seed)
    n, h = 501, 3
    S = _particles(rng, n)
    pred = rng.normal(-60, 3, (n, h))
    pred[rng.integers(0, n, 5), 1] = np.nan  # outside the survey
    rss = np.array([-58.0, -61.0, -63.0])
    w = _weights(rng, n)
    w[rng.integers(0, n, 50)] = 0.0
    w /= w.sum()
    lim2 = 25.0
    r2 = np.minimum((rss[None, :] - pred - S[:, K.OFFSET_DB, None]) ** 2, lim2)
    r2 = np.nan_to_num(r2.mean(axis=1), nan=lim2)
    got = K.median_squared_residual(S, pred, rss, w, lim2, float(rng.uniform()))
    below = float(np.sum(w[r2 < got]))
    at_or_below = float(np.sum(w[r2 <= got]))
    assert below <= 0.5 + 2 / 256 and at_or_below >= 0.5 - 2 / 256


def test_sampled_median_of_one_heavy_particle_is_its_value():
    rng = np.random.default_rng(4304)
    S = _particles(rng, 100)
    pred = rng.normal(-60, 3, (100, 2))
    rss = np.array([-60.0, -60.0])
    w = np.full(100, 1e-6)
    w[37] = 1.0
    w /= w.sum()
    e = rss - pred[37] - S[37, K.OFFSET_DB]
    got = K.median_squared_residual(S, pred, rss, w, 1e9, 0.5)
    assert got == pytest.approx(np.mean(e**2))


def test_posterior_moments_match_numpy():
    rng = np.random.default_rng(4305)
    S = _particles(rng, 777)
    w = _weights(rng, 777)
    rows = np.empty((777, K.POSE_ROW))
    m = np.empty(11)
    K.posterior_moments(S, w, rows, m)
    np.testing.assert_allclose(m[:9], _summary_numpy(S[:, POSE], w), rtol=1e-12, atol=1e-12)
    assert m[9] == pytest.approx(np.sum(w * S[:, K.OFFSET_DB]))
    assert m[10] == pytest.approx(np.sum(w * w))
    np.testing.assert_allclose(rows[:, 3], np.cos(S[:, K.AZIMUTH_RAD]))
    np.testing.assert_allclose(rows[:, 7], np.sin(S[:, K.ROLL_RAD]), atol=1e-15)


def test_resample_in_place_is_systematic_resampling():
    rng = np.random.default_rng(4306)
    S = _particles(rng, 300)
    w = _weights(rng, 300)
    idx_ref = K.systematic_resample(w, 0.37)
    want = S[idx_ref]
    idx = np.empty(300, np.int64)
    K.resample_in_place(S, w, 0.37, np.empty_like(S), idx)
    np.testing.assert_array_equal(idx, idx_ref)
    np.testing.assert_array_equal(S, want)


class _ListLineage:
    """The genealogy as the filter kept it before the ring buffer: lists of arrays."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.history: list[np.ndarray] = []
        self.ancestors: list[np.ndarray] = []

    def push(self, t: float, S: np.ndarray) -> None:
        self.times.append(t)
        self.history.append(S[:, POSE].copy())
        self.ancestors.append(np.arange(S.shape[0]))

    def remap(self, idx: np.ndarray) -> None:
        self.ancestors = [a[idx] for a in self.ancestors]

    def inject(self, t_s, window_s, new, slots, donors, inherit=None, box=None) -> None:
        m = new.shape[0]
        same = np.ones(m, bool) if inherit is None else inherit
        for j in range(len(self.history)):
            lag = t_s - self.times[j]
            own = np.ones(m, dtype=bool) if lag <= window_s else ~same
            if not own.all():
                self.ancestors[j][slots[~own]] = self.ancestors[j][donors[~own]]
            if not own.any():
                continue
            mine = new[own]
            rows = mine[:, POSE].copy()
            rows[:, 0] -= mine[:, K.VX_MPS] * lag
            rows[:, 1] -= mine[:, K.VY_MPS] * lag
            rows[:, 3] -= mine[:, K.RATE_RAD_S] * lag
            if box is not None:
                rows[:, 0] = np.clip(rows[:, 0], box[0], box[1])
                rows[:, 1] = np.clip(rows[:, 1], box[2], box[3])
            base = self.history[j].shape[0]
            self.history[j] = np.vstack([self.history[j], rows])
            self.ancestors[j][slots[own]] = base + np.arange(rows.shape[0])

    def pop(self, w: np.ndarray) -> np.ndarray:
        self.times.pop(0)
        return _summary_numpy(self.history.pop(0)[self.ancestors.pop(0)], w)


@pytest.mark.parametrize(("seed", "own_past"), [(4307, False), (4308, False), (4308, True)])
def test_lineage_ring_equals_the_list_genealogy(seed, own_past):
    """Pushes past the capacity, resamplings, re-entered hypotheses (more rows
    than the ring holds; with ``own_past`` some keep their own moved-back,
    clipped pose before the window instead of their donor's past) and a pickle
    round trip give the moments of the list-of-arrays genealogy."""
    rng = np.random.default_rng(seed)
    n, lag_packets = 64, 11
    ring, ref = Lineage(n, capacity=4), _ListLineage()
    S = _particles(rng, n)
    rows, mom = np.empty((n, K.POSE_ROW)), np.empty(11)
    got, want = [], []
    for step in range(60):
        t = 0.005 * step
        S[:, K.X_M] += 0.01 * S[:, K.VX_MPS]
        S[:, K.AZIMUTH_RAD] = (S[:, K.AZIMUTH_RAD] + 0.01) % (2 * np.pi)
        w = _weights(rng, n)
        K.posterior_moments(S, w, rows, mom)
        ring.push(t, rows)
        ref.push(t, S)
        if step % 7 == 3:  # a re-entry of 20 hypotheses
            new = _particles(rng, 20)
            new[:, K.VX_MPS] *= 100.0  # moved back out of the box: clipped
            slots = rng.choice(n, 20, replace=False)
            donors = rng.integers(0, n, 20)
            S[slots] = new
            extra = {}
            if own_past:
                extra = {"inherit": rng.random(20) < 0.5, "box": np.array([0.0, 20.0, 0.0, 20.0])}
            ring.inject(t, 0.02, new, slots, donors, extra.get("inherit"), extra.get("box"))
            ref.inject(t, 0.02, new, slots, donors, **extra)
        if step == 30:
            ring = pickle.loads(pickle.dumps(ring))
        if ring.size > lag_packets:
            m9 = np.empty(9)
            ring.pop_moments(w, m9)
            got.append(m9)
            want.append(ref.pop(w))
        if step % 3 == 0:
            idx = K.systematic_resample(w, float(rng.uniform()))
            S = S[idx]
            ring.remap(idx)
            ref.remap(idx)
    assert ring.capacity > 4 and len(got) == 60 - lag_packets
    np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-10, atol=1e-10)


def test_lineage_pickle_keeps_only_the_live_packets():
    ring = Lineage(1000)
    rows = np.zeros((1000, K.POSE_ROW))
    for k in range(3):
        ring.push(float(k), rows)
    m = np.empty(9)
    ring.pop_moments(np.full(1000, 1e-3), m)
    assert len(pickle.dumps(ring)) < 2 * (2 * 1000 * K.POSE_ROW * 8 + 2 * 1000 * 4)
    back = pickle.loads(pickle.dumps(ring))
    assert back.size == 2 and back.oldest_time_s() == 1.0 and not math.isnan(m[0])


def test_filter_model_scores_on_one_thread_with_the_same_answers():
    from dataclasses import replace

    from radiopose.filtering import FilterModel
    from radiopose.likelihood import candidate_space
    from radiopose.likelihood.compiled import ShiftScorer
    from radiopose.packets import group_packets
    from radiopose.simulate import ScenarioConfig, simulate

    sim = simulate(
        replace(ScenarioConfig(), size_m=6.0, duration_s=0.05, min_receiver_spacing_m=1.5), 4309
    )
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    scorer = ShiftScorer(space, parallel=True)
    model = FilterModel.build(sim.site, space, scorer)
    assert model.scorer is not scorer and not model.scorer.parallel and scorer.parallel
    assert model.scorer.posf is scorer.posf  # tables shared, not copied
    for packet in group_packets(sim.packets)[:3]:
        heard = space.heard(packet)
        a, b = scorer.score_heard(heard, 50), model.scorer.score_heard(heard, 50)
        np.testing.assert_array_equal(a.candidate_idx, b.candidate_idx)
        np.testing.assert_array_equal(a.mse_db2, b.mse_db2)


# ----------------------------------------------------------------------------- motion noise
def _noise(seed: int, n: int, tilt: np.ndarray, row0: int = 0) -> np.ndarray:
    out = np.full((n, K.N_NOISE), 7.0)
    K.motion_noise_into(out, seed, row0, tilt)
    return out


FROZEN = np.zeros(4)
FREE = np.array([-1.0, 1.0, -1.0, 1.0])


def test_motion_noise_is_standard_normal_and_independent():
    """Counter-based draws: mean 0, variance 1, normal tails, no correlation
    between columns, between neighbouring particles or between packets."""
    from scipy import stats

    a = _noise(4307, 100_000, FREE)
    b = _noise(4308, 100_000, FREE)
    assert np.all(np.abs(a.mean(axis=0)) < 0.02)  # sd of the mean 0.003
    assert np.all(np.abs(a.std(axis=0) - 1.0) < 0.015)
    for c in range(K.N_NOISE):
        assert stats.kstest(a[:, c], "norm").pvalue > 1e-4
    corr = np.corrcoef(np.hstack([a, b, np.roll(a, 1, axis=0)]).T)
    off = corr[~np.eye(corr.shape[0], dtype=bool)]
    assert np.max(np.abs(off)) < 0.02
    # the tails: P(|z| > 3) = 0.0027
    assert abs(np.mean(np.abs(a) > 3.0) - 0.0027) < 0.0008


def test_motion_noise_depends_on_the_particle_index_only():
    """Two blocks (the two threads of ParticleFilter's split update) give the
    rows of one call; another seed gives other numbers; a frozen roll column is
    not written (predict never reads it) and the other columns do not change."""
    whole = _noise(4309, 1000, FREE)
    first = _noise(4309, 400, FREE, row0=0)
    rest = _noise(4309, 600, FREE, row0=400)
    np.testing.assert_array_equal(np.vstack([first, rest]), whole)
    assert not np.any(_noise(4310, 1000, FREE) == whole)
    frozen = _noise(4309, 1000, FROZEN)
    np.testing.assert_array_equal(frozen[:, 4], 7.0)
    # the other draws are the particle's own whether roll is free or not
    np.testing.assert_array_equal(frozen[:, :4], whole[:, :4])


def test_split_packet_update_gives_the_numbers_of_one_call(monkeypatch):
    """ParticleFilter's update on two threads (each half's noise drawn from its
    own rows' particle indices) gives exactly what one call gives."""
    from radiopose.filtering import particle

    rng = np.random.default_rng(4310)
    n = 2000
    S = _particles(rng, n)
    logw = rng.normal(0, 1, n)
    rx = np.array([[0.0, 0.0, 2.0], [20.0, 0.0, 2.0], [10.0, 20.0, 2.0]])
    chan = rng.normal(-60, 5, (3, 21, 21))
    grid = np.array([0.0, 1.0, 21, 0.0, 1.0, 21])
    d = rng.normal(0, 3, (36, 1))
    args = (
        0.005, np.array([0.5, 0.5, 0.1, 10.0, 10.0]), np.array([0.0, 20.0, 0.0, 20.0]),
        np.array([0.0, 0.4, -0.3, 0.0]), np.array([0, 2], np.int64), rx, chan, grid, 0.0, d,
        np.array([0.0, 10.0, 1.0]), np.array([-61.0, -58.0]), 3.0, -4.0,
    )  # fmt: skip
    out = []
    for spare in (False, True):
        monkeypatch.setattr(particle, "spare_core", lambda s=spare: s)
        S1, lw1 = S.copy(), logw.copy()
        pred, w = np.empty((n, 2)), np.empty(n)
        lse = particle._packet_update(
            K.packet_update, S1, lw1, np.empty((n, K.N_NOISE)), 99, *args, pred, w
        )
        out.append((S1, lw1, pred, w, lse))
    for a, b in zip(*out, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(out[0][0], S)  # the particles moved


def test_predict_without_noise_is_constant_velocity_and_turn_rate():
    """With zero noise ``predict`` moves each particle by ``v dt`` and turns it by
    ``ω dt`` (trapezoid of equal end points), leaves pitch and roll where a
    frozen ``tilt_box`` holds them, and reflects a position that leaves the box
    (helper-65's mutant F12, which dropped ``v dt``, passed test_filter.py)."""
    import math

    S = np.zeros((2, K.N_COLUMNS))
    S[:, K.X_M], S[:, K.Y_M] = [1.0, 9.9], [2.0, 5.0]
    S[:, K.VX_MPS], S[:, K.VY_MPS] = [1.5, 1.0], [-0.5, 0.0]
    S[:, K.AZIMUTH_RAD], S[:, K.RATE_RAD_S] = [0.1, 6.2], [0.4, 1.0]
    noise = np.zeros((2, 5))
    box = np.array([0.0, 10.0, 0.0, 10.0])
    K.predict(S, noise, 0.2, 1.0, 1.0, 0.0, 10.0, 10.0, box, np.zeros(4))
    assert S[0, K.X_M] == pytest.approx(1.3) and S[0, K.Y_M] == pytest.approx(1.9)
    assert S[0, K.AZIMUTH_RAD] == pytest.approx(0.18)
    assert S[1, K.AZIMUTH_RAD] == pytest.approx((6.2 + 0.2) % (2 * math.pi))
    # 9.9 + 0.2 = 10.1 is reflected at 10: x = 9.9, heading back
    assert S[1, K.X_M] == pytest.approx(9.9) and S[1, K.VX_MPS] == pytest.approx(-1.0)
    assert (S[:, K.PITCH_RAD] == 0).all() and (S[:, K.ROLL_RAD] == 0).all()
