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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import DBSCAN

from radiopose.units import FloatArray, circular_mean_deg, wrap_deg

IntArray = NDArray[np.int64]


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
    w = np.asarray(weights, dtype=np.float64)
    if float(w.sum()) <= 0.0:
        w = np.ones_like(w)
    return np.average(values, axis=0, weights=w)


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
    labels = DBSCAN(eps=eps_deg, min_samples=min_samples).fit(ext.reshape(-1, 1)).labels_
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
    db = DBSCAN(eps=eps_m, min_samples=min_samples).fit(p)
    labels = db.labels_
    core = np.zeros(p.shape[0], dtype=bool)
    core[db.core_sample_indices_] = True
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
