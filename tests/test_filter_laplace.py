"""Issue 15, σ = 3 dB ties: the arbiter's Laplace term
(``FilterConfig.arbiter_laplace``; docs/filter.md, "Laplace arbiter").

* ``_half_log_det`` of the banded normal matrix with the offset's row and
  column equals ½ log det of the same matrix built dense (hypothesis);
* the term is computed only with the option (with either solve, banded or
  sparse), and computing it changes neither the refined track nor its
  objective;
* with the option the arbiter keeps the lowest ``cost + penalty +
  log_volume``, without it the lowest ``cost + penalty``;
* the ``tracker.toml`` key reads, a non-boolean is a one-line error;
* end to end, σ = 3 dB, device +6 dB, tuning seed 7784: the default arbiter
  keeps a wrong lock (43°), with the Laplace term the truth's mode wins.

Tuning seeds only (7760–7819 chose it).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from filter_support import loud_run, small_site, turned
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.refine2d import _BAND, _half_log_det, arbitrate, refine_track_2d
from radiopose.tracker import TrackerConfig
from radiopose.tracker_settings import read_tracker_settings


def _dense(ab: np.ndarray, c: np.ndarray, d_bb: float) -> np.ndarray:
    """The symmetric matrix ``[[P, c], [cᵀ, d_bb]]`` of ``P`` in upper band form."""
    u, nv = ab.shape[0] - 1, ab.shape[1]
    P = np.zeros((nv, nv))
    for o in range(u + 1):
        idx = np.arange(o, nv)
        P[idx - o, idx] = ab[u - o, o:]
        P[idx, idx - o] = ab[u - o, o:]
    M = np.zeros((nv + 1, nv + 1))
    M[:nv, :nv], M[:nv, nv], M[nv, :nv], M[nv, nv] = P, c, c, d_bb
    return M


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 12), seed=st.integers(0, 2**31 - 1), scale=st.floats(1e-3, 1e3))
def test_half_log_det_equals_the_dense_one(n: int, seed: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    nv = 3 * n
    B = rng.normal(size=(nv + 5, nv + 1)) * scale
    M = B.T @ B + np.eye(nv + 1) * scale**2  # SPD
    # keep only the band of the pose block (the normal equations' structure)
    i, j = np.indices((nv, nv))
    M[:nv, :nv][np.abs(i - j) > _BAND] = 0.0
    M[:nv, :nv] += np.eye(nv) * np.abs(M[:nv, :nv]).sum(axis=1).max()  # still SPD
    ab = np.zeros((_BAND + 1, nv))
    for o in range(_BAND + 1):
        idx = np.arange(o, nv)
        ab[_BAND - o, o:] = M[idx - o, idx]
    M = _dense(ab, M[:nv, nv], float(M[nv, nv]))
    sign, logdet = np.linalg.slogdet(M)
    got = _half_log_det(ab, M[:nv, nv], float(M[nv, nv]))
    if sign > 0:
        assert got == pytest.approx(0.5 * logdet, rel=1e-9, abs=1e-9)
    else:  # the offset's Schur complement not positive
        assert math.isnan(got)


def test_not_positive_definite_is_nan() -> None:
    ab = np.zeros((_BAND + 1, 3))
    ab[_BAND] = 1.0
    assert math.isnan(_half_log_det(ab, np.ones(3), 1.0))  # Schur complement 1 − 3 < 0
    ab[_BAND, 0] = -1.0
    assert math.isnan(_half_log_det(ab, np.zeros(3), 1.0))  # P itself indefinite


def test_log_volume_only_with_the_option_and_nothing_else_changes() -> None:
    s = small_site()
    cfg = FilterConfig()
    t = np.array([r[0] for r in s.records])
    h = [r[1] for r in s.records]
    args = (s.model, t, h, s.position_m, s.orientation_deg, 0.5)
    off = refine_track_2d(*args, cfg)
    on = refine_track_2d(*args, replace(cfg, arbiter_laplace=True))
    assert math.isnan(off.log_volume) and math.isfinite(on.log_volume)
    assert on.cost == off.cost and on.offset_db == off.offset_db
    np.testing.assert_array_equal(on.position_m, off.position_m)
    np.testing.assert_array_equal(on.orientation_deg, off.orientation_deg)
    # the sparse solve (refine_banded = false) gets the term too, from the same matrix
    sparse = refine_track_2d(*args, replace(cfg, arbiter_laplace=True, refine_banded=False))
    assert sparse.log_volume == pytest.approx(on.log_volume, rel=1e-6)


def test_arbiter_adds_the_term_only_with_the_option() -> None:
    s = small_site()
    n = len(s.records)
    cands = [s.truth, turned(s.truth, s.records, n // 4, 3 * n // 4)]
    for laplace in (False, True):
        cfg = replace(FilterConfig(), arbiter_laplace=laplace)
        _, log = arbitrate(s.model, s.records, cands, 0.5, cfg, 30)
        for a in log:
            assert len(a.log_volumes) == 2
            assert all(math.isfinite(v) for v in a.log_volumes) == laplace
            key = np.array(a.costs) + np.array(a.penalties)
            if laplace:
                key = key + np.array(a.log_volumes)
            assert a.chosen == int(np.argmin(key))


def test_tracker_toml_key(tmp_path: Path) -> None:
    assert FilterConfig().arbiter_laplace is False  # off by default
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\narbiter_laplace = true\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides["arbiter_laplace"] is True
    p.write_text("[filter]\narbiter_laplace = 1\n", encoding="utf-8")
    with pytest.raises(InputError, match="arbiter_laplace"):
        read_tracker_settings(p)


# ------------------------------------------------------- end to end: tuning seed 7784
@pytest.mark.slow  # an option off by default (arbiter_laplace = false): session 14's cut
def test_loud_laplace_leaves_the_wrong_lock() -> None:
    """Tuning seed 7784 (σ = 3 dB, device +6 dB): measured 0.44 m / 43.2° by
    default, 0.08 m / 2.0° with the Laplace term."""
    pos_m, ori_deg = loud_run(7784, 3.0, TrackerConfig())
    assert ori_deg > 25.0  # the part removed: the wrong lock stays
    pos_m, ori_deg = loud_run(7784, 3.0, TrackerConfig(), arbiter_laplace=True)
    assert ori_deg < 6.0 and pos_m < 0.3
