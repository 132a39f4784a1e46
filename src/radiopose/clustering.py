"""Clustering of top-k candidates: wrap-aware DBSCAN on angles, DBSCAN on positions.

Paper, "Enhanced Localisation Pipeline", steps 3, 5 and 6.

* Weights: every top-k candidate gets the normalised, inverted MSE
  ``w = (MSE_max − MSE) / (MSE_max − MSE_min)`` (best → 1, worst → 0; all 1 if
  every MSE is equal), :func:`inverted_weights`.
* Orientation (step 3): DBSCAN (scikit-learn) on each rotation axis separately,
  ``ε = 2°``, ``minPts = 10``. On a periodic axis the values are duplicated at
  −360° and +360° so a cluster can form across the wrap (358°, 359°, 0°, 1°);
  only clusters whose centroid lies in the canonical range ``[0, 360)``
  are kept, so each
  cluster is counted once. Pitch (``[−90, 90]``) is not periodic and is not
  duplicated. The centroid is the weighted mean of the (unwrapped) members.
* Position (step 5): DBSCAN on candidate positions, ``ε = 0.5 m``,
  ``minPts = 10``; the centroid is the weighted mean of the core points.
* Cluster score (step 6): ``Σ w²`` over the cluster's members.

DBSCAN itself: :func:`dbscan` reproduces scikit-learn's ``DBSCAN`` labels
exactly (same neighbourhoods ``d ≤ ε``, same cluster numbering, same
assignment of border points reachable from two clusters — tested against
scikit-learn on random data) for the small top-k sets of the hot path, where
scikit-learn's per-call validation and tree building cost ~2 ms per call, i.e.
most of a packet's budget. Larger inputs go to scikit-learn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from radiopose.units import FloatArray, circular_mean_deg, wrap_deg

IntArray = NDArray[np.int64]

SMALL_DBSCAN_MAX_POINTS = 2000
"""Inputs up to this size use the dense implementation; larger go to scikit-learn."""


def dbscan(points: FloatArray, eps: float, min_samples: int) -> tuple[IntArray, NDArray]:
    """DBSCAN labels (``-1`` = noise) and the core-point mask, as scikit-learn gives them.

    Parameters
    ----------
    points
        ``(n, d)`` points (Euclidean metric).
    eps
        Neighbourhood radius; ``q`` is a neighbour of ``p`` if ``|p − q| ≤ eps``.
    min_samples
        A core point has at least this many neighbours, itself included.

    Notes
    -----
    scikit-learn numbers clusters in the order of their first core point and
    expands them in that order, so a border point within reach of several
    clusters takes the lowest-numbered one; the same rule is applied here.
    """
    x = np.asarray(points, dtype=np.float64)
    x = x.reshape(x.shape[0], -1)
    n = x.shape[0]
    if n > SMALL_DBSCAN_MAX_POINTS:
        from sklearn.cluster import DBSCAN  # imported here: ~1 s of start-up otherwise

        db = DBSCAN(eps=eps, min_samples=min_samples).fit(x)
        core = np.zeros(n, dtype=bool)
        core[db.core_sample_indices_] = True
        return db.labels_.astype(np.int64), core
    if x.shape[1] == 1:
        return _dbscan_1d(x[:, 0], eps, min_samples)
    near = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1) <= eps * eps
    core = near.sum(axis=1) >= min_samples
    labels = np.full(n, -1, dtype=np.int64)
    if not core.any():
        return labels, core
    ci = np.flatnonzero(core)
    # components come numbered by their lowest index, and ``ci`` increases: that is
    # scikit-learn's numbering by each cluster's first core point
    labels[ci] = _components(near[np.ix_(ci, ci)])
    border = ~core & near[:, ci].any(axis=1)
    if border.any():
        reach = np.where(near[np.ix_(border, ci)], labels[ci][None, :], np.iinfo(np.int64).max)
        labels[border] = reach.min(axis=1)
    return labels, core


DENSE_COMPONENTS_MAX_POINTS = 256
"""Core sets up to this size use dense label propagation; larger go to scipy."""


def _components(adj: NDArray) -> IntArray:
    """Connected components of a symmetric boolean adjacency matrix with a true
    diagonal, numbered in the order of their lowest index.

    Small inputs: min-label propagation with pointer jumping (every label is the
    index of a node in the same component and never increases, so the fixed
    point labels each component by its lowest index); larger ones: scipy.
    """
    m = adj.shape[0]
    if m > DENSE_COMPONENTS_MAX_POINTS:
        _, comp = connected_components(csr_matrix(adj), directed=False)
        return _number_by_first(comp, np.arange(m))
    lab = np.arange(m)
    while True:
        nxt = np.where(adj, lab[None, :], m).min(axis=1)
        nxt = nxt[nxt]
        if np.array_equal(nxt, lab):
            break
        lab = nxt
    roots = np.unique(lab)
    return np.searchsorted(roots, lab)


def _number_by_first(comp: IntArray, index: IntArray) -> IntArray:
    """Renumber groups ``comp`` (``0 … g−1``) in the order of their lowest ``index``."""
    first = np.full(int(comp.max()) + 1, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first, comp, index)
    rank = np.empty_like(first)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return rank[comp]


@dataclass(frozen=True, eq=False)
class AxisCluster:
    """A cluster of candidate angles on one rotation axis.

    Attributes
    ----------
    centroid_deg
        Weighted centroid, degrees, in the axis's canonical range.
    members
        ``(m,)`` indices into the clustered candidates, increasing.
    """

    centroid_deg: float
    members: IntArray


@dataclass(frozen=True, eq=False)
class PositionCluster:
    """A cluster of candidate positions.

    Attributes
    ----------
    centroid_m
        ``(3,)`` weighted mean of the core points, metres.
    members
        ``(m,)`` indices into the clustered candidates (core and border), increasing.
    """

    centroid_m: FloatArray
    members: IntArray


def _dbscan_1d(v: FloatArray, eps: float, min_samples: int) -> tuple[IntArray, NDArray]:
    """:func:`dbscan` on a line in ``O(n log n)``.

    Sorted, a point's neighbours are a contiguous run; two core points are
    connected exactly when every gap between consecutive core points from one
    to the other is at most ``eps`` (no ``eps``-edge can jump a larger gap), and
    a border point can only be reached from the nearest core point on each side.
    """
    n = v.size
    order = np.argsort(v, kind="stable")
    sv = v[order]
    # |a − b| ≤ eps evaluated as scikit-learn does it (on the difference, not shifted bounds)
    lo = np.searchsorted(sv, sv - eps, side="left")
    hi = np.searchsorted(sv, sv + eps, side="right")
    lo = np.where((lo > 0) & (np.abs(sv - sv[np.maximum(lo - 1, 0)]) <= eps), lo - 1, lo)
    hi = np.where((hi < n) & (np.abs(sv[np.minimum(hi, n - 1)] - sv) <= eps), hi + 1, hi)
    while True:  # settle rounding at the run ends in either direction
        lo2 = np.where((lo < n) & (np.abs(sv - sv[np.minimum(lo, n - 1)]) > eps), lo + 1, lo)
        lo2 = np.where((lo2 > 0) & (np.abs(sv - sv[np.maximum(lo2 - 1, 0)]) <= eps), lo2 - 1, lo2)
        hi2 = np.where((hi > 0) & (np.abs(sv[np.maximum(hi - 1, 0)] - sv) > eps), hi - 1, hi)
        hi2 = np.where((hi2 < n) & (np.abs(sv[np.minimum(hi2, n - 1)] - sv) <= eps), hi2 + 1, hi2)
        if np.array_equal(lo2, lo) and np.array_equal(hi2, hi):
            break
        lo, hi = lo2, hi2
    core_s = (hi - lo) >= min_samples
    labels_s = np.full(n, -1, dtype=np.int64)
    ci = np.flatnonzero(core_s)
    if ci.size:
        cv = sv[ci]
        comp = np.concatenate([[0], np.cumsum(np.abs(np.diff(cv)) > eps)])
        labels_s[ci] = _number_by_first(comp, order[ci])
        b = np.flatnonzero(~core_s)
        if b.size:
            k = np.searchsorted(cv, sv[b], side="right")  # first core point above
            below = np.clip(k - 1, 0, ci.size - 1)
            above = np.clip(k, 0, ci.size - 1)
            big = np.iinfo(np.int64).max
            lab_b = np.where(np.abs(sv[b] - cv[below]) <= eps, labels_s[ci[below]], big)
            lab_a = np.where(np.abs(cv[above] - sv[b]) <= eps, labels_s[ci[above]], big)
            lab = np.minimum(lab_b, lab_a)
            labels_s[b] = np.where(lab == big, -1, lab)
    labels = np.empty(n, dtype=np.int64)
    labels[order] = labels_s
    core = np.empty(n, dtype=bool)
    core[order] = core_s
    return labels, core


def inverted_weights(mse_db2: FloatArray) -> FloatArray:
    """Normalised, inverted MSE ``(n,)``: best → 1, worst → 0 (all 1 if all equal)."""
    mse = np.asarray(mse_db2, dtype=np.float64)
    if mse.size == 0:
        return mse.copy()
    lo, hi = float(mse.min()), float(mse.max())
    if hi <= lo:
        return np.ones_like(mse)
    return (hi - mse) / (hi - lo)


def cluster_score(weights: FloatArray, members: IntArray) -> float:
    """Score of a cluster: ``Σ w²`` over its members (paper, step 6)."""
    w = np.asarray(weights, dtype=np.float64)[members]
    return float(np.sum(w * w))


def _weighted_mean(values: FloatArray, weights: FloatArray) -> FloatArray:
    """``Σ w v / Σ w`` along the first axis (all weights 1 if they sum to ≤ 0);
    the arithmetic of ``np.average`` without its overhead."""
    w = np.asarray(weights, dtype=np.float64)
    scl = float(w.sum())
    if scl <= 0.0:
        w = np.ones_like(w)
        scl = float(w.size)
    v = np.asarray(values, dtype=np.float64)
    wb = w.reshape((-1,) + (1,) * (v.ndim - 1))
    return np.multiply(v, wb).sum(axis=0) / scl


def cluster_axis_deg(
    values_deg: FloatArray,
    weights: FloatArray,
    *,
    eps_deg: float = 2.0,
    min_samples: int = 10,
    periodic: bool = True,
    low_deg: float = 0.0,
    wrap_duplication: bool = True,
) -> tuple[AxisCluster, ...]:
    """DBSCAN clusters of angles on one rotation axis.

    Parameters
    ----------
    values_deg
        ``(n,)`` candidate angles on this axis, degrees.
    weights
        ``(n,)`` candidate weights (:func:`inverted_weights`).
    eps_deg, min_samples
        DBSCAN radius (degrees) and minimum points (paper: 2°, 10).
    periodic
        True for azimuth and roll, False for pitch.
    low_deg
        Start of the canonical range ``[low, low + 360)`` of a periodic axis.
    wrap_duplication
        Duplicate values at ±360° (the paper's method). False only for ablation:
        angles are then clustered as plain numbers in the canonical range.

    Returns
    -------
    Clusters in order of increasing centroid.
    """
    v = np.asarray(values_deg, dtype=np.float64).reshape(-1)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    n = v.size
    if n == 0:
        return ()
    if periodic:
        v = wrap_deg(v - low_deg) + low_deg
    if periodic and wrap_duplication:
        ext = np.concatenate([v - 360.0, v, v + 360.0])
        src = np.tile(np.arange(n), 3)
    else:
        ext, src = v, np.arange(n)
    labels, _ = dbscan(ext.reshape(-1, 1), eps_deg, min_samples)
    out = []
    for lab in np.unique(labels):
        if lab < 0:
            continue
        sel = labels == lab
        centroid = float(_weighted_mean(ext[sel], w[src[sel]]))
        if periodic and wrap_duplication:
            # The copies of one cluster have centroids 360° apart: keep the copy in
            # [low, low + 360). Rounding to 1e-9° first makes a centroid at the wrap
            # (−1e−14 in one copy, 360 − 1e−14 in the next) land in exactly one copy.
            c = round(centroid, 9) + 0.0
            if not (low_deg <= c < low_deg + 360.0):
                continue
        if periodic:
            centroid = float(wrap_deg(centroid - low_deg)) + low_deg
        out.append(AxisCluster(centroid, np.unique(src[sel]).astype(np.int64)))
    return tuple(sorted(out, key=lambda c: c.centroid_deg))


def cluster_positions_m(
    positions_m: FloatArray,
    weights: FloatArray,
    *,
    eps_m: float = 0.5,
    min_samples: int = 10,
) -> tuple[PositionCluster, ...]:
    """DBSCAN clusters of candidate positions.

    Parameters
    ----------
    positions_m
        ``(n, 3)`` candidate positions, metres.
    weights
        ``(n,)`` candidate weights.
    eps_m, min_samples
        DBSCAN radius (metres) and minimum points (paper: 0.5 m, 10).
    """
    p = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if p.shape[0] == 0:
        return ()
    labels, core = dbscan(p, eps_m, min_samples)
    out = []
    for lab in np.unique(labels):
        if lab < 0:
            continue
        sel = labels == lab
        cs = sel & core
        out.append(
            PositionCluster(_weighted_mean(p[cs], w[cs]), np.flatnonzero(sel).astype(np.int64))
        )
    return tuple(out)


def weighted_orientation_deg(
    orientations_deg: FloatArray, weights: FloatArray, periodic: tuple[bool, bool, bool]
) -> FloatArray:
    """Weighted mean orientation ``(3,)``: circular on periodic axes, arithmetic otherwise."""
    o = np.asarray(orientations_deg, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64)
    if float(w.sum()) <= 0.0:
        w = np.ones_like(w)
    out = np.empty(3)
    for axis in range(3):
        if periodic[axis]:
            out[axis] = circular_mean_deg(o[:, axis], w)
        else:
            out[axis] = float(np.average(o[:, axis], weights=w))
    return out
