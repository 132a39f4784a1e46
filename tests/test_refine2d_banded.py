"""The offline arbiter's cheaper arithmetic (docs/performance.md, "Ninth pass"):
the 2-D refinement's normal equations in band form, the offset profile a few
offsets at a time, the residuals of a track in one model call.

Exact equivalences on small inputs: the band form's matrix and gradient equal
the dense ``JᵀWJ`` and ``JᵀWf`` of the same Jacobian; its solve (banded
Cholesky and the offset's Schur complement, or the sparse fallback) equals a
dense solve; the chunked profile and the one-call residuals equal the
computations they replace bit for bit. Seeds 8101–8104 (random matrices) and
the small site's seed 11 (tests/filter_support.py) only.
"""

from __future__ import annotations

import numpy as np
import pytest

from filter_support import small_site
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.refine2d import (
    _BAND,
    _POSE,
    _banded_step,
    _BandedNormal,
    _sparse_step,
    refine_track_2d,
)
from radiopose.filtering.reverse import (
    OFFSET_GRID_DB,
    mixture_loglik,
    pose_residuals_db,
    profile_offset,
)
from radiopose.units import angle_diff_deg


def _prior_coef(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random motion-prior coefficients ``(3, n − 2, 3)`` as refine_track_2d's."""
    d1, d2 = rng.uniform(0.002, 0.02, n - 2), rng.uniform(0.002, 0.02, n - 2)
    coef = np.empty((3, n - 2, 3))
    for comp, q in enumerate((0.7, 0.7, 2.0)):
        w = 1.0 / (q * np.sqrt((d1 + d2) / 3.0))
        coef[comp] = np.column_stack([w / d2, -w / d2 - w / d1, w / d1])
    return coef


def _dense_jacobian(
    n: int, pkt: np.ndarray, d: np.ndarray, coef: np.ndarray, sig: float, sd_b: float
) -> np.ndarray:
    """The whole Jacobian ``(m + 3k + 1, 3n + 1)`` written out row by row."""
    m, k = pkt.size, coef.shape[1]
    J = np.zeros((m + 3 * k + 1, _POSE * n + 1))
    for r in range(m):
        J[r, _POSE * pkt[r] : _POSE * pkt[r] + _POSE] = d[r]
        J[r, -1] = -1.0 / sig
    for comp in range(_POSE):
        for row in range(k):
            i = row + 1
            for a, j in enumerate((i + 1, i, i - 1)):
                J[m + comp * k + row, _POSE * j + comp] = coef[comp, row, a]
    J[-1, -1] = 1.0 / sd_b
    return J


def _full(ab: np.ndarray, c: np.ndarray, d_bb: float) -> np.ndarray:
    """The symmetric matrix ``[[P, c], [cᵀ, d_bb]]`` of an upper band ``ab``."""
    nv = ab.shape[1]
    P = np.zeros((nv, nv))
    for o in range(_BAND + 1):
        idx = np.arange(o, nv)
        P[idx - o, idx] = ab[_BAND - o, o:]
        P[idx, idx - o] = ab[_BAND - o, o:]
    return np.block([[P, c[:, None]], [c[None, :], np.array([[d_bb]])]])


@pytest.mark.parametrize("seed", [8101, 8102])
def test_band_form_is_the_dense_normal_equations(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, sig, sd_b = 9, 1.3, 6.0
    heard = rng.integers(1, 4, n)  # 1–3 readings per packet
    pkt = np.repeat(np.arange(n), heard)
    m = pkt.size
    d = rng.normal(0.0, 2.0, (m, _POSE))
    coef = _prior_coef(rng, n)
    f = rng.normal(0.0, 1.0, m + 3 * (n - 2) + 1)
    w = np.concatenate([rng.uniform(0.2, 1.0, m), np.ones(3 * (n - 2) + 1)])
    normal = _BandedNormal(n, pkt, coef, sig, sd_b)
    ab, c, d_bb, g, g_b = normal.build(d, w, f)
    J = _dense_jacobian(n, pkt, d, coef, sig, sd_b)
    A = J.T @ (w[:, None] * J)
    np.testing.assert_allclose(_full(ab, c, d_bb), A, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.append(g, g_b), J.T @ (w * f), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("seed", [8103, 8104])
def test_banded_step_solves_the_system(seed: int, monkeypatch) -> None:
    rng = np.random.default_rng(seed)
    n = 12
    nv = _POSE * n
    ab = rng.normal(0.0, 0.3, (_BAND + 1, nv))
    ab[_BAND] = rng.uniform(20.0, 30.0, nv)  # diagonally dominant: positive definite
    c = rng.normal(0.0, 0.5, nv)
    d_bb = 40.0
    g, g_b = rng.normal(0.0, 1.0, nv), 0.7
    want = -np.linalg.solve(_full(ab, c, d_bb), np.append(g, g_b))
    np.testing.assert_allclose(_banded_step(ab, c, d_bb, g, g_b), want, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(_sparse_step(ab, c, d_bb, g, g_b), want, rtol=1e-10, atol=1e-12)

    # a band that is not numerically positive definite goes to the sparse LU
    import scipy.linalg

    def refuse(*_a: object, **_k: object) -> None:
        raise scipy.linalg.LinAlgError("not positive definite")

    monkeypatch.setattr(scipy.linalg, "cholesky_banded", refuse)
    np.testing.assert_allclose(_banded_step(ab, c, d_bb, g, g_b), want, rtol=1e-10, atol=1e-12)


def test_profile_offset_in_chunks_is_the_whole_grid_argmax() -> None:
    rng = np.random.default_rng(8101)
    for sigma, centre in ((0.5, 0.0), (1.0, 4.3), (3.0, -6.1)):
        r = rng.normal(centre, sigma, 1203)
        r[::50] += 15.0  # outliers
        ll = mixture_loglik(r[None, :], OFFSET_GRID_DB[:, None], sigma, 0.02, 60.0).sum(axis=1)
        assert profile_offset(r, sigma, 0.02, 60.0) == float(OFFSET_GRID_DB[int(np.argmax(ll))])
        assert abs(profile_offset(r, sigma, 0.02, 60.0) - centre) < 0.5


def test_track_residuals_in_one_call_equal_one_call_per_packet() -> None:
    site = small_site()
    heards = [r[1] for r in site.records]
    rng = np.random.default_rng(8102)
    pos = site.position_m + np.column_stack([rng.normal(0.0, 0.5, (len(heards), 2)),
                                             np.zeros(len(heards))])  # fmt: skip
    ori = site.orientation_deg.copy()
    ori[:, 0] = (ori[:, 0] + rng.normal(0.0, 40.0, len(heards))) % 360.0
    res, idx = pose_residuals_db(site.model, heards, pos, ori)
    want, want_idx = [], []
    S = np.zeros((1, K.N_COLUMNS))
    rad = np.deg2rad(ori)
    for i, h in enumerate(heards):
        S[0, K.X_M : K.Z_M + 1] = pos[i]
        S[0, K.AZIMUTH_RAD], S[0, K.PITCH_RAD], S[0, K.ROLL_RAD] = rad[i]
        want.append(h.rss_dbm - site.model.expected(S, h.receiver_index)[0])
        want_idx.append(np.full(h.n_heard, i))
    assert res.tobytes() == np.concatenate(want).tobytes()
    np.testing.assert_array_equal(idx, np.concatenate(want_idx))
    empty = pose_residuals_db(site.model, [], pos[:0], ori[:0])
    assert empty[0].size == 0 and empty[1].size == 0


def test_banded_refinement_reaches_the_sparse_ones_optimum() -> None:
    """``FilterConfig.refine_banded`` solves the same iteration's equations: on
    the small site's jittered track the two refinements agree far below the
    estimates' precision (the banded solve is the default since 2026-11-27)."""
    site = small_site()
    rng = np.random.default_rng(8103)
    n = len(site.records)
    pos = site.position_m.copy()
    pos[:, :2] += rng.normal(0.0, 0.3, (n, 2))
    ori = site.orientation_deg.copy()
    ori[:, 0] = (ori[:, 0] + rng.normal(0.0, 10.0, n)) % 360.0
    t = np.array([r[0] for r in site.records])
    h = [r[1] for r in site.records]
    assert FilterConfig().refine_banded is True
    runs = [
        refine_track_2d(site.model, t, h, pos, ori, 0.5, FilterConfig(refine_banded=b))
        for b in (False, True)
    ]
    sparse, banded = runs
    assert sparse.nfev == banded.nfev
    assert banded.cost == pytest.approx(sparse.cost, rel=1e-9)
    assert banded.initial_cost == sparse.initial_cost
    assert np.abs(banded.position_m - sparse.position_m).max() < 1e-7
    assert (
        np.abs(angle_diff_deg(banded.orientation_deg[:, 0], sparse.orientation_deg[:, 0])).max()
        < 1e-6
    )
    assert banded.offset_db == pytest.approx(sparse.offset_db, abs=1e-8)
    assert banded.cost < 0.5 * banded.initial_cost
