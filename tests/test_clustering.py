"""Clustering: weights, wrap-aware DBSCAN on angles, position DBSCAN, cluster scores."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from radiopose.clustering import (
    cluster_axis_deg,
    cluster_positions_m,
    cluster_score,
    dbscan,
    inverted_weights,
    weighted_orientation_deg,
)
from radiopose.units import angle_diff_deg, wrap_deg


def test_inverted_weights_best_one_worst_zero():
    w = inverted_weights(np.array([1.0, 3.0, 2.0, 5.0]))
    np.testing.assert_allclose(w, [1.0, 0.5, 0.75, 0.0])
    np.testing.assert_array_equal(inverted_weights(np.full(4, 2.0)), np.ones(4))


def test_cluster_score_is_sum_of_squared_weights():
    assert cluster_score(np.array([1.0, 0.5, 0.25]), np.array([0, 1])) == pytest.approx(1.25)


def _around(centre: float, n: int = 25) -> np.ndarray:
    return wrap_deg(centre + np.linspace(-2.5, 2.5, n))


def test_cluster_across_the_wrap_is_one_cluster_counted_once():
    v = _around(0.0)  # 357.5 … 2.5
    clusters = cluster_axis_deg(v, np.ones(v.size))
    assert len(clusters) == 1
    assert abs(angle_diff_deg(clusters[0].centroid_deg, 0.0)) < 1e-9
    assert 0.0 <= clusters[0].centroid_deg < 360.0
    np.testing.assert_array_equal(clusters[0].members, np.arange(v.size))


def test_without_wrap_duplication_the_wrap_cluster_breaks():
    # Ablation: the paper's duplication at ±360° is what joins 359° and 1°.
    v = _around(0.0)
    clusters = cluster_axis_deg(v, np.ones(v.size), wrap_duplication=False)
    assert len(clusters) != 1 or abs(angle_diff_deg(clusters[0].centroid_deg, 0.0)) > 1.0


def test_centroid_is_weighted_and_noise_is_dropped():
    v = np.concatenate([np.full(10, 100.0), np.full(10, 102.0), [250.0]])
    w = np.concatenate([np.ones(10), np.zeros(10), [1.0]])
    (c,) = cluster_axis_deg(v, w)
    assert c.centroid_deg == pytest.approx(100.0)
    assert 20 not in c.members  # the lone 250° is noise
    # too few points for minPts = 10: no cluster
    assert cluster_axis_deg(np.full(9, 5.0), np.ones(9)) == ()


def test_two_separate_clusters():
    v = np.concatenate([_around(90.0), _around(270.0)])
    clusters = cluster_axis_deg(v, np.ones(v.size))
    assert [round(c.centroid_deg) for c in clusters] == [90, 270]


@settings(max_examples=40, deadline=None)
@given(shift=st.floats(0.0, 360.0, allow_nan=False), seed=st.integers(0, 2**16))
def test_rotating_all_angles_rotates_the_centroid(shift, seed):
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1.0, 1.0, 15)  # dense: one cluster
    w = rng.uniform(0.0, 1.0, 15)
    (a,) = cluster_axis_deg(wrap_deg(base + 30.0), w)
    (b,) = cluster_axis_deg(wrap_deg(base + 30.0 + shift), w)
    assert abs(angle_diff_deg(b.centroid_deg, a.centroid_deg + shift)) < 1e-6


def test_non_periodic_axis_is_not_duplicated():
    v = np.concatenate([np.full(10, -30.0), np.full(10, 30.0)])
    clusters = cluster_axis_deg(v, np.ones(20), periodic=False)
    assert [c.centroid_deg for c in clusters] == [-30.0, 30.0]


def test_position_clusters_centroid_from_core_points():
    rng = np.random.default_rng(0)
    a = np.array([[2.0, 3.0, 1.0]] * 10 + [[2.0, 3.3, 1.0]] * 5)
    b = np.column_stack([rng.normal(8.0, 0.05, 12), rng.normal(1.0, 0.05, 12), np.ones(12)])
    border = np.array([[2.0, 3.75, 1.0]])  # 6 neighbours within ε: a border point, not core
    p = np.vstack([a, b, border])
    w = np.ones(p.shape[0])
    clusters = cluster_positions_m(p, w)
    assert len(clusters) == 2
    ca = min(clusters, key=lambda c: np.linalg.norm(c.centroid_m[:2] - [2, 3]))
    assert 27 in ca.members  # the border point belongs to the cluster …
    np.testing.assert_allclose(ca.centroid_m, a.mean(axis=0), atol=1e-12)  # … not its centroid
    assert cluster_positions_m(p[:5], w[:5]) == ()


def test_weighted_orientation_is_circular_on_periodic_axes():
    o = np.array([[350.0, 10.0, 350.0], [10.0, 20.0, 10.0]])
    m = weighted_orientation_deg(o, np.array([1.0, 1.0]), (True, False, True))
    assert abs(angle_diff_deg(m[0], 0.0)) < 1e-9
    assert m[1] == pytest.approx(15.0)
    assert abs(angle_diff_deg(m[2], 0.0)) < 1e-9


# ------------------------------------------------------------ dbscan vs scikit-learn


def _sk(points, eps, min_samples):
    # the reference is scikit-learn with exact distances (k-d tree: Σ (p − q)²);
    # its "auto" choice for small inputs is brute force, whose dot-product
    # expansion (p² − 2pq + q²) misjudges pairs exactly eps apart, e.g. −1.0 and
    # −0.8 with eps = 2 × 0.1 (hypothesis found it: seed 95, n 11, step 0.1)
    db = DBSCAN(eps=eps, min_samples=min_samples, algorithm="kd_tree").fit(points)
    core = np.zeros(len(points), bool)
    core[db.core_sample_indices_] = True
    return db.labels_, core


@settings(max_examples=150, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 3),
    st.integers(1, 160),
    st.floats(0.05, 2.0),
    st.integers(1, 15),
)
def test_dbscan_labels_equal_scikit_learn(seed, dim, n, eps, min_samples):
    rng = np.random.default_rng(seed)
    # clumps on a coarse lattice: many exact ties at distance eps and shared borders
    pts = np.round(rng.normal(0, 2.0, (n, dim)) * 4) / 4
    labels, core = dbscan(pts, eps, min_samples)
    sk_labels, sk_core = _sk(pts, eps, min_samples)
    np.testing.assert_array_equal(core, sk_core)
    np.testing.assert_array_equal(labels, sk_labels)


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 400), st.sampled_from([0.1, 0.3, 1.0, 2.0]))
@example(seed=95, n=11, step=0.1)
def test_dbscan_on_a_line_equals_scikit_learn_at_rounding_edges(seed, n, step):
    # angles on a decimal grid (not binary fractions), shifted by ±360 like the
    # wrap duplication: differences land within rounding of eps = 2 steps
    rng = np.random.default_rng(seed)
    v = rng.integers(-40, 40, n) * step + rng.choice([-360.0, 0.0, 360.0], n)
    pts = v.reshape(-1, 1)
    ms = int(rng.integers(1, 12))
    labels, core = dbscan(pts, 2 * step, ms)
    sk_labels, sk_core = _sk(pts, 2 * step, ms)
    np.testing.assert_array_equal(core, sk_core)
    np.testing.assert_array_equal(labels, sk_labels)


def test_dbscan_large_inputs_equal_scikit_learn():
    # a pooled acquisition clusters thousands of angles (sorted scan at any size)
    # and ~2,100 positions (brute force up to 5,000 points; more: scikit-learn)
    rng = np.random.default_rng(7)
    line = (rng.integers(0, 720, (6000, 1)) * 0.5).astype(float)
    near = np.round(rng.normal(0, 3, (2500, 2)) * 4) / 4
    wide = np.round(rng.normal(0, 40, (5200, 2)) * 4) / 4
    for pts, eps in ((line, 2.0), (near, 0.5), (wide, 0.5)):
        labels, core = dbscan(pts, eps, 10)
        sk_labels, sk_core = _sk(pts, eps, 10)
        np.testing.assert_array_equal(core, sk_core)
        np.testing.assert_array_equal(labels, sk_labels)


def test_dbscan_border_point_takes_first_cluster():
    # two clusters of 4 points and a border point exactly eps from both (binary fractions)
    pts = np.array([[0.0], [0.25], [0.5], [0.75], [1.75], [2.75], [3.0], [3.25], [3.5]])
    labels, core = dbscan(pts, 1.0, 4)
    np.testing.assert_array_equal(labels, _sk(pts, 1.0, 4)[0])
    assert labels[4] == 0 and not core[4]
    assert set(labels[5:]) == {1}
