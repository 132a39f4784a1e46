"""The filter's selectable parts for the real BLE site (issue 16):
``FilterConfig.likelihood = "huber"`` (the previous design's Huber-weighted
Gaussian) against plain numpy definitions, the ``jump_own_past`` switch, and
both as ``tracker.toml`` keys.

Seeds 4401-4409 are used here only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from radiopose.errors import InputError
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812
from radiopose.filtering.lineage import Lineage
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import TrackerConfig
from radiopose.tracker_settings import read_tracker_toml, write_tracker_toml


def _particles(rng: np.random.Generator, n: int, offset_var_db2: float) -> np.ndarray:
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M] = rng.uniform(0, 20, n)
    S[:, K.Y_M] = rng.uniform(0, 20, n)
    S[:, K.OFFSET_DB] = rng.normal(0, 2, n)
    S[:, K.OFFSET_VAR_DB2] = offset_var_db2
    return S


@pytest.mark.parametrize("seed", [4401, 4402])
def test_huber_update_with_inliers_is_the_gaussian_marginal(seed):
    """All residuals within c σ: the log-likelihood is log N(e; 0, σ²I + P 11ᵀ) up
    to the constant (h/2) log 2π + h log σ, and the offset update is the Kalman one."""
    rng = np.random.default_rng(seed)
    n, h, sigma, p = 50, 6, 5.0, 1.5
    S = _particles(rng, n, p)
    pred = rng.normal(-70, 5, (n, h))
    rss_rows = (pred + S[:, K.OFFSET_DB, None]) + rng.normal(0, 1.0, (n, h))
    logw = np.zeros(n)
    S0 = S.copy()
    for i in range(n):  # each particle its own packet, all residuals small
        row = S[i : i + 1]
        K.measurement_update_huber(row, pred[i : i + 1], rss_rows[i], sigma, 100.0, logw[i : i + 1])
        e = rss_rows[i] - pred[i] - S0[i, K.OFFSET_DB]
        cov = sigma**2 * np.eye(h) + p * np.ones((h, h))
        ref = (
            multivariate_normal(np.zeros(h), cov).logpdf(e)
            + 0.5 * h * math.log(2 * math.pi)
            + h * math.log(sigma)
        )
        assert logw[i] == pytest.approx(ref, abs=1e-9)
        gain = p / (sigma**2 + h * p)
        assert S[i, K.OFFSET_DB] == pytest.approx(S0[i, K.OFFSET_DB] + gain * e.sum(), abs=1e-9)
        assert S[i, K.OFFSET_VAR_DB2] == pytest.approx(p * sigma**2 / (sigma**2 + h * p))


def test_huber_update_without_offset_uncertainty_is_half_linear_past_c():
    """P = 0: log L = −½ Σ min(u², c |u|) (the Huber weight c/|u| beyond c)."""
    rng = np.random.default_rng(4403)
    n, h, sigma, c = 40, 8, 4.0, 1.0
    S = _particles(rng, n, 0.0)
    pred = rng.normal(-70, 5, (n, h))
    rss = rng.normal(-70, 8, h)
    logw = np.zeros(n)
    b = S[:, K.OFFSET_DB].copy()
    K.measurement_update_huber(S, pred, rss, sigma, c, logw)
    u = np.abs(rss[None, :] - pred - b[:, None]) / sigma
    np.testing.assert_allclose(logw, -0.5 * np.minimum(u * u, c * u).sum(axis=1), rtol=1e-12)
    np.testing.assert_array_equal(S[:, K.OFFSET_DB], b)  # P = 0: the offset does not move


def test_huber_window_loglik_is_the_huber_cost_and_nan_is_impossible():
    rng = np.random.default_rng(4404)
    n, h, sigma, c = 30, 5, 5.0, 1.0
    pred = rng.normal(-70, 5, (n, h))
    pred[3, 2] = np.nan
    rss = rng.normal(-70, 8, h)
    off = rng.normal(0, 2, n)
    out = np.full(n, 1.5)
    K.fixed_offset_loglik_huber(pred, rss, off, sigma, c, out)
    u = np.abs(rss[None, :] - pred - off[:, None]) / sigma
    cost = np.where(u <= c, 0.5 * u * u, c * u - 0.5 * c * c).sum(axis=1)
    ok = np.arange(n) != 3
    np.testing.assert_allclose(out[ok], 1.5 - cost[ok], rtol=1e-12)
    assert out[3] == -np.inf


def test_huber_packet_update_is_predict_expected_and_update():
    """The fused call gives what its three parts give in turn."""
    rng = np.random.default_rng(4405)
    n = 64
    S = _particles(rng, n, 2.0)
    S[:, K.Z_M] = 1.0
    S[:, K.VX_MPS] = rng.normal(0, 1, n)
    S[:, K.VY_MPS] = rng.normal(0, 1, n)
    rx = np.array([[0.0, 0.0, 2.0], [20.0, 0.0, 2.0], [10.0, 20.0, 2.0]])
    chan = rng.normal(-60, 5, (3, 21, 21))
    grid = np.array([0.0, 1.0, 21, 0.0, 1.0, 21])
    d = np.zeros((36, 1))
    pat = np.array([0.0, 10.0, 1.0])
    heard = np.array([0, 2], np.int64)
    rss = np.array([-61.0, -58.0])
    noise = np.empty((n, K.N_NOISE))
    motion = np.array([0.5, 0.5, 0.0, 10.0, 10.0])
    box = np.array([0.0, 20.0, 0.0, 20.0])
    tilt = np.zeros(4)
    logw = rng.normal(0, 1, n)
    S1, lw1 = S.copy(), logw.copy()
    pred, w = np.empty((n, 2)), np.empty(n)
    lse0, lse1 = K.packet_update_huber(
        S1, lw1, noise, 4405, 0, 0.3, motion, box, tilt, heard, rx, chan, grid, 0.0, d, pat,
        rss, 5.0, 1.0, pred, w,
    )  # fmt: skip
    S2, lw2 = S.copy(), logw.copy()
    noise2 = np.empty((n, K.N_NOISE))
    K.motion_noise_into(noise2, 4405, 0, tilt)
    K.predict(S2, noise2, 0.3, *motion, box, tilt)
    pred2 = K.expected_rss_dbm(S2, heard, rx, chan, grid, 0.0, d, pat)
    K.measurement_update_huber(S2, pred2, rss, 5.0, 1.0, lw2)
    np.testing.assert_allclose(S1, S2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lw1, lw2, rtol=0, atol=1e-12)
    assert lse0 == pytest.approx(float(np.logaddexp.reduce(logw)))
    assert lse1 == pytest.approx(float(np.logaddexp.reduce(lw2)))
    np.testing.assert_allclose(w, np.exp(lw2 - lse1), atol=1e-12)


@pytest.fixture(scope="module")
def sim():
    return simulate(ScenarioConfig(noise_db=0.5, duration_s=2.0), 4406)


def test_huber_filter_tracks_and_differs_from_the_mixture(sim):
    scorer = build_scorer(sim, "numba")
    runs = {
        lik: run_methods(
            sim, ("filter",), TrackerConfig(filter=FilterConfig(likelihood=lik)), scorer
        )["filter"]
        for lik in ("mixture", "huber")
    }
    for run in runs.values():
        assert run.summary.coverage == 1.0
        assert run.position_error_m.mean() < 0.5
    assert not np.array_equal(
        runs["huber"].estimates.position_m, runs["mixture"].estimates.position_m
    )


def test_jump_own_past_false_lets_every_hypothesis_inherit(sim, monkeypatch):
    seen: list[np.ndarray] = []
    real = Lineage.inject

    def spy(self, *args, inherit=None, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(np.asarray(inherit).copy())
        return real(self, *args, inherit=inherit, **kwargs)

    monkeypatch.setattr(Lineage, "inject", spy)
    scorer = build_scorer(sim, "numba")
    for own in (True, False):
        seen.clear()
        cfg = TrackerConfig(filter=FilterConfig(jump_own_past=own))
        run_methods(sim, ("filter",), cfg, scorer)
        masks = np.concatenate(seen)
        assert masks.size > 0
        if own:
            assert not masks.all()  # some re-entered hypotheses are jumps here
        else:
            assert masks.all()


def test_bad_likelihood_is_a_one_line_error():
    with pytest.raises(InputError, match="likelihood"):
        FilterConfig(likelihood="gauss")


def test_tracker_toml_reads_and_writes_the_switches(tmp_path):
    p = tmp_path / "tracker.toml"
    write_tracker_toml(p, {"likelihood": "huber", "jump_own_past": False, "huber_c": 1.0}, 10.0)
    assert read_tracker_toml(p) == (
        {"likelihood": "huber", "jump_own_past": False, "huber_c": 1.0},
        10.0,
    )
    p.write_text('[filter]\nhuber_c = 1.0\nlikelihood = "cauchy"\n')
    with pytest.raises(InputError, match=r"tracker.toml:3.*likelihood.*cauchy"):
        read_tracker_toml(p)
    p.write_text("[filter]\njump_own_past = 1\n")
    with pytest.raises(InputError, match=r"tracker.toml:2.*jump_own_past"):
        read_tracker_toml(p)
