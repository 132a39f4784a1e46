"""Clustering of top-k candidates: wrap-aware DBSCAN on angles, DBSCAN on positions.

Paper, "Enhanced Localisation Pipeline", steps 3, 5 and 6.

* Weights: every top-k candidate gets the normalised, inverted MSE
  ``w = (MSE_max − MSE) / (MSE_max − MSE_min)`` (best → 1, worst → 0; all 1 if
  every MSE is equal), :func:`inverted_weights`.
* Orientation (step 3): DBSCAN (:func:`dbscan`, below) on each rotation axis separately,
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
most of a packet's budget. Two compiled (numba) routines do it: a sorted
two-pointer scan on a line (the orientation axes, any size) and a brute-force
``O(n²)`` pass otherwise (positions, up to 5,000 points; more go to scikit-learn).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from radiopose.units import FloatArray, circular_mean_deg, wrap_deg

IntArray = NDArray[np.int64]

SMALL_DBSCAN_MAX_POINTS = 5000
"""Points of more than one dimension up to this many use the compiled brute-force
pass (an ``n × n`` boolean matrix: 25 MB at the limit); more go to scikit-learn.
Points on a line always use the sorted scan. A pooled acquisition clusters up to
≈ 2,100 positions (21 packets × top-100)."""


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
    if x.shape[1] == 1:  # O(n log n) at any size
        return _dbscan_sorted_1d(np.ascontiguousarray(x[:, 0]), float(eps), int(min_samples))
    if n > SMALL_DBSCAN_MAX_POINTS:
        from sklearn.cluster import DBSCAN  # imported here: ~1 s of start-up otherwise

        db = DBSCAN(eps=eps, min_samples=min_samples).fit(x)
        core = np.zeros(n, dtype=bool)
        core[db.core_sample_indices_] = True
        return db.labels_.astype(np.int64), core
    return _dbscan_dense(np.ascontiguousarray(x), float(eps), int(min_samples))


@numba.njit(cache=True)
def _dbscan_dense(x: FloatArray, eps: float, min_samples: int) -> tuple[IntArray, NDArray]:
    """:func:`dbscan` by brute force in ``O(n²)``: neighbours ``Σ (p − q)² ≤ eps²``;
    clusters grown breadth-first from each not yet labelled core point in index
    order (scikit-learn's numbering); a border point takes the lowest label of
    the core points within reach."""
    n, d = x.shape
    eps2 = eps * eps
    near = np.zeros((n, n), dtype=np.bool_)
    count = np.zeros(n, dtype=np.int64)
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for c in range(d):
                t = x[i, c] - x[j, c]
                s += t * t
            if s <= eps2:
                near[i, j] = True
                near[j, i] = True
                count[i] += 1
                if j != i:
                    count[j] += 1
    core = count >= min_samples
    labels = np.full(n, -1, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)
    n_clusters = 0
    for i in range(n):
        if not core[i] or labels[i] >= 0:
            continue
        labels[i] = n_clusters
        queue[0] = i
        head, tail = 0, 1
        while head < tail:
            a = queue[head]
            head += 1
            for b in range(n):
                if near[a, b] and core[b] and labels[b] < 0:
                    labels[b] = n_clusters
                    queue[tail] = b
                    tail += 1
        n_clusters += 1
    for i in range(n):
        if core[i]:
            continue
        for b in range(n):
            if near[i, b] and core[b] and (labels[i] < 0 or labels[b] < labels[i]):
                labels[i] = labels[b]
    return labels, core


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


@numba.njit(cache=True)
def _dbscan_sorted_1d(v: FloatArray, eps: float, min_samples: int) -> tuple[IntArray, NDArray]:
    """:func:`dbscan` on a line in ``O(n log n)``.

    Sorted, a point's neighbours (``|a − b| ≤ eps``, as scikit-learn evaluates
    it on the difference) are a contiguous run, found with two pointers (the
    rounded difference is monotone along the sorted values). Two core points are
    connected exactly when every gap between consecutive core points from one to
    the other is at most ``eps`` (no ``eps``-edge can jump a larger gap); clusters
    are numbered by their lowest original index; a border point can only be
    reached from the nearest core point on each side and takes the lower label.
    """
    n = v.size
    order = np.argsort(v, kind="mergesort")
    sv = v[order]
    core_s = np.zeros(n, dtype=np.bool_)
    lo = 0
    hi = 0
    for i in range(n):
        while abs(sv[i] - sv[lo]) > eps:
            lo += 1
        if hi < i + 1:
            hi = i + 1
        while hi < n and abs(sv[hi] - sv[i]) <= eps:
            hi += 1
        core_s[i] = hi - lo >= min_samples
    # components of consecutive core points, in sorted order
    comp_s = np.full(n, -1, dtype=np.int64)
    first = np.empty(n, dtype=np.int64)  # lowest original index per component
    g = -1
    last = -1
    for i in range(n):
        if not core_s[i]:
            continue
        if last < 0 or abs(sv[i] - sv[last]) > eps:
            g += 1
            first[g] = order[i]
        elif order[i] < first[g]:
            first[g] = order[i]
        comp_s[i] = g
        last = i
    rank = np.empty(g + 1, dtype=np.int64)
    rank[np.argsort(first[: g + 1], kind="mergesort")] = np.arange(g + 1)
    labels = np.full(n, -1, dtype=np.int64)
    core = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if core_s[i]:
            labels[order[i]] = rank[comp_s[i]]
            core[order[i]] = True
    above = -1  # nearest core point above
    for i in range(n - 1, -1, -1):
        if core_s[i]:
            above = i
            continue
        lab = -1
        if above >= 0 and abs(sv[above] - sv[i]) <= eps:
            lab = rank[comp_s[above]]
        labels[order[i]] = lab
    below = -1
    for i in range(n):
        if core_s[i]:
            below = i
        elif below >= 0 and abs(sv[i] - sv[below]) <= eps:
            lab = rank[comp_s[below]]
            if labels[order[i]] < 0 or lab < labels[order[i]]:
                labels[order[i]] = lab
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
        src = np.arange(3 * n) % n
    else:
        ext, src = v, np.arange(n)
    labels, _ = dbscan(ext.reshape(-1, 1), eps_deg, min_samples)
    good = labels >= 0
    if not good.any():
        return ()
    lab, e, we = labels[good], ext[good], w[src[good]]
    n_lab = int(lab.max()) + 1
    # weighted mean per cluster (plain mean where the weights sum to 0, as _weighted_mean)
    wsum = np.bincount(lab, we, n_lab)
    wx = np.bincount(lab, we * e, n_lab)
    plain = np.bincount(lab, e, n_lab) / np.bincount(lab, minlength=n_lab)
    centroids = np.where(wsum > 0.0, wx / np.where(wsum > 0.0, wsum, 1.0), plain)
    out = []
    for label in range(n_lab):
        centroid = float(centroids[label])
        if periodic and wrap_duplication:
            # The copies of one cluster have centroids 360° apart: keep the copy in
            # [low, low + 360). Rounding to 1e-9° first makes a centroid at the wrap
            # (−1e−14 in one copy, 360 − 1e−14 in the next) land in exactly one copy.
            c = round(centroid, 9) + 0.0
            if not (low_deg <= c < low_deg + 360.0):
                continue
        if periodic:
            centroid = float(wrap_deg(centroid - low_deg)) + low_deg
        member = np.zeros(n, dtype=bool)
        member[src[labels == label]] = True
        out.append(AxisCluster(centroid, np.flatnonzero(member)))
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
