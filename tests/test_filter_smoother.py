"""The backward smoother's kernels on hand-made particle sets (radiopose.filtering.smoother)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812
from radiopose.filtering.smoother import (
    N_MOMENTS,
    N_STATE,
    BackwardSettings,
    BackwardStore,
    backward_moments,
    log_kernel,
)

DT_S = 0.005


def _row(x_m: float, y_m: float, azimuth_deg: float = 0.0, vx_mps: float = 0.0,
         rate_dps: float = 0.0) -> np.ndarray:  # fmt: skip
    r = np.zeros(N_STATE)
    r[K.X_M], r[K.Y_M], r[K.VX_MPS] = x_m, y_m, vx_mps
    r[K.AZIMUTH_RAD] = math.radians(azimuth_deg) % (2 * math.pi)
    r[K.RATE_RAD_S] = math.radians(rate_dps)
    return r


def test_log_kernel_is_the_motion_models_mean_with_a_gaussian_width() -> None:
    a = _row(1.0, 2.0, 350.0, vx_mps=2.0, rate_dps=200.0)
    # b exactly where a's constant velocity and turn rate put it after dt: peak
    b = _row(1.0 + 2.0 * 0.1, 2.0, 350.0 + 20.0)
    assert log_kernel(a, b, 0.1, 0.25, math.radians(8.0)) == pytest.approx(0.0, abs=1e-12)
    # 0.25 m off in y and 8° off in azimuth (across 0/360): one bandwidth each, d² = 2
    c = _row(1.2, 2.25, 10.0 + 8.0)
    assert log_kernel(a, c, 0.1, 0.25, math.radians(8.0)) == pytest.approx(-1.0, rel=1e-9)
    # the wrap knows 359° − 1° is 2°
    d, e = _row(0.0, 0.0, 359.0), _row(0.0, 0.0, 1.0)
    assert log_kernel(d, e, 0.0, 1.0, math.radians(2.0)) == pytest.approx(-0.5, rel=1e-9)


def _case(reentered_xy: tuple[float, float]) -> tuple[np.ndarray, ...]:
    """Three packets of two particles: A near the origin heading 0°, B at (5, 0)
    heading 180°; at the last packet particle 1 is a re-entered hypothesis."""
    X = np.zeros((3, 2, N_STATE))
    for t in range(3):
        X[t, 0] = _row(0.0, 0.0, 0.0)
        X[t, 1] = _row(5.0, 0.0, 180.0)
    X[2, 1] = _row(*reentered_xy, 180.0)
    logw = np.log(np.array([[0.9, 0.1], [0.5, 0.5], [0.2, 0.8]]))
    anc = np.array([[-1, -1], [0, 1], [0, -1]], dtype=np.int32)
    times = np.array([0.0, DT_S, 2 * DT_S])
    return X, logw, anc, times


def _smooth(case: tuple[np.ndarray, ...], ghost_s: float) -> np.ndarray:
    out = np.empty((3, N_MOMENTS))
    backward_moments(*case, BackwardSettings(ghost_s=ghost_s).kernel(), ghost_s, out)
    return out


def test_a_reentered_hypothesis_takes_the_past_of_the_particles_within_reach() -> None:
    # the newcomer at (5.05, 0) lies within reach of B only: its 0.8 goes to B,
    # whose genealogy then carries it back (the filter said 0.5 and 0.1 there)
    out = _smooth(_case((5.05, 0.0)), ghost_s=0.1)
    np.testing.assert_allclose(out[2, 0], 0.2 * 0.0 + 0.8 * 5.05)
    np.testing.assert_allclose(out[1, 0], 0.8 * 5.0)
    np.testing.assert_allclose(out[0, 0], 0.8 * 5.0)
    # azimuth sums: 0.2 at 0°, 0.8 at 180°
    np.testing.assert_allclose(out[0, 3:5], [0.2 - 0.8, 0.0], atol=1e-12)


def test_an_unmatched_hypothesis_travels_back_then_takes_the_filters_past() -> None:
    case = _case((15.0, 15.0))  # far from both: a jump
    # no ghost time: its 0.8 is handed back by the filter's weights at packet 1
    out = _smooth(case, ghost_s=0.0)
    w1 = np.array([0.2 + 0.8 * 0.5, 0.8 * 0.5])
    np.testing.assert_allclose(out[1, 0], w1[1] * 5.0)
    np.testing.assert_allclose(out[0, 0], w1[1] * 5.0)
    # one packet of ghost time: at packet 1 it is its own (static) pose, then
    # the filter's weights at packet 0 (0.9, 0.1)
    out = _smooth(case, ghost_s=DT_S)
    np.testing.assert_allclose(out[1, 0:2], [0.8 * 15.0, 0.8 * 15.0])
    w0 = np.array([0.2 + 0.8 * 0.9, 0.8 * 0.1])
    np.testing.assert_allclose(out[0, 0], w0[1] * 5.0)


def test_a_ghost_moves_back_on_its_own_motion() -> None:
    X, logw, anc, times = _case((15.0, 15.0))
    X[2, 1, K.VX_MPS] = 2.0
    X[2, 1, K.RATE_RAD_S] = math.radians(100.0)
    out = np.empty((3, N_MOMENTS))
    backward_moments(X, logw, anc, times, BackwardSettings().kernel(), 1.0, out)
    # at packet 0 (two packets back) the ghost is at x = 15 − 2 · 0.01, azimuth 180° − 1°
    ghost_x = 15.0 - 2.0 * 2 * DT_S
    np.testing.assert_allclose(out[0, 0], 0.8 * ghost_x)
    np.testing.assert_allclose(out[0, 3], 0.2 + 0.8 * math.cos(math.radians(179.0)))


def test_the_store_records_ancestors_through_reentry_and_resampling() -> None:
    st = BackwardStore(BackwardSettings(), n_particles=3, capacity=1)
    S = np.zeros((3, K.N_COLUMNS))
    w = np.full(3, 1 / 3)
    st.push(0.0, S, w)
    st.reentered(np.array([2]))
    st.remap(np.array([2, 0, 0]))  # particle 0 copies the newcomer
    st.push(0.01, S, w)  # grows past its capacity
    st.push(0.02, S, w)
    assert st.size == 3 and st.x.shape[0] >= 3
    np.testing.assert_array_equal(st.anc[1], [-1, 0, 0])
    np.testing.assert_array_equal(st.anc[2], [0, 1, 2])
    st.drop(2)
    assert st.size == 1 and st.oldest_time_s() == 0.02


def test_the_smoother_setting_is_checked() -> None:
    with pytest.raises(InputError, match="smoother"):
        FilterConfig(smoother="magic")
    with pytest.raises(InputError, match="smoother_ghost_s"):
        FilterConfig(smoother_ghost_s=-1.0)


def test_estimates_are_due_once_the_kept_packets_span_twice_the_lag() -> None:
    from collections import deque

    st = BackwardStore(BackwardSettings(), n_particles=4)
    pending: deque = deque()
    S = np.zeros((4, K.N_COLUMNS))
    S[:, K.X_M] = [0.0, 1.0, 2.0, 3.0]
    due = []
    for k in range(5):
        t = 0.1 * k
        st.push(t, S, np.full(4, 0.25))
        pending.append((t, f"p{k}", None))
        due.append([key for key, _, _ in st.due(pending, 0.2, final=False)])
    # nothing until the span reaches 0.4 s; then the packets at least 0.2 s old
    assert due == [[], [], [], [], ["p0", "p1", "p2"]]
    rest = st.due(pending, 0.2, final=True)
    assert [key for key, _, _ in rest] == ["p3", "p4"] and st.size == 0 and not pending
    np.testing.assert_allclose(rest[0][2][0], 1.5)  # the mean x of equal weights


def test_the_store_survives_a_checkpoint() -> None:
    import pickle
    from collections import deque

    st = BackwardStore(BackwardSettings(), n_particles=2)
    S = np.zeros((2, K.N_COLUMNS))
    for k in range(3):
        S[:, K.X_M] = [k, k + 1.0]
        st.push(0.1 * k, S, np.array([0.25, 0.75]))
    back = pickle.loads(pickle.dumps(st))
    a = st.due(deque((0.1 * k, k, None) for k in range(3)), 1.0, final=True)
    b = back.due(deque((0.1 * k, k, None) for k in range(3)), 1.0, final=True)
    np.testing.assert_array_equal(np.array([m for _, _, m in a]), np.array([m for _, _, m in b]))


def test_tracker_toml_chooses_the_smoother(tmp_path) -> None:
    from radiopose.tracker_settings import read_tracker_toml

    p = tmp_path / "tracker.toml"
    p.write_text('[filter]\nsmoother = "backward"\nsmoother_ghost_s = 1.0\n')
    overrides, _ = read_tracker_toml(p)
    assert FilterConfig(**overrides).smoother == "backward"
    p.write_text('[filter]\nsmoother = "magic"\n')
    with pytest.raises(InputError, match=r"tracker\.toml") as err:
        read_tracker_toml(p)
    assert "\n" not in str(err.value)


def test_the_lineage_ring_grows_only_to_what_the_lag_holds():
    """A ring holds the packets within the lag and no more slots (every slot of
    a ring is written in turn: a 256-slot ring cost a live device 37 MB at any
    packet rate); its moments equal a large ring's, through doublings."""
    from radiopose.filtering.lineage import INITIAL_CAPACITY, Lineage

    rng = np.random.default_rng(3)
    n = 50
    small, big = Lineage(n), Lineage(n, capacity=256)
    for i in range(200):
        rows = rng.normal(size=(n, K.POSE_ROW))
        idx = rng.integers(0, n, n)
        hold = 3 if i < 150 else 20  # the lag's packets: few, then more (a doubling)
        for lin in (small, big):
            lin.push(0.1 * i, rows)
            lin.remap(idx)
        while small.size > hold:
            w = rng.dirichlet(np.ones(n))
            m1, m2 = np.zeros(11), np.zeros(11)
            small.pop_moments(w, m1)
            big.pop_moments(w, m2)
            np.testing.assert_array_equal(m1, m2)
        if i == 149:
            assert small.capacity == INITIAL_CAPACITY
    assert small.capacity == 32 and big.capacity == 256
