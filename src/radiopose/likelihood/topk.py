"""Top-k selection of candidates by MSE, ties broken by candidate index.

Paper, "Enhanced Localisation Pipeline", step 2: the ``k`` candidates with the
lowest MSE (``k = 100``) go on to clustering. Every scorer selects through
:func:`select_topk`, so equal MSEs always resolve the same way (lower candidate
index first) and non-finite MSEs (excluded candidates) are never selected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from radiopose.units import FloatArray

IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class TopK:
    """The best candidates of one packet, best first.

    Attributes
    ----------
    candidate_idx
        ``(m,)`` candidate indices (``m <= k``; fewer only if fewer are scorable).
    mse_db2
        ``(m,)`` their MSE, dB², increasing (ties by increasing index).
    """

    candidate_idx: IntArray
    mse_db2: FloatArray

    def __len__(self) -> int:
        return int(self.candidate_idx.size)


def select_topk(candidate_idx: IntArray, mse_db2: FloatArray, k: int) -> TopK:
    """The ``k`` lowest finite MSEs, ordered by (MSE, candidate index).

    Parameters
    ----------
    candidate_idx
        ``(n,)`` candidate indices (unique).
    mse_db2
        ``(n,)`` their MSE, dB²; NaN/inf are never selected.
    k
        How many to keep (``k >= 1``).
    """
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    idx = np.asarray(candidate_idx, dtype=np.int64)
    mse = np.asarray(mse_db2, dtype=np.float64)
    ok = np.isfinite(mse)
    idx, mse = idx[ok], mse[ok]
    if mse.size > k:
        kth = np.partition(mse, k - 1)[k - 1]
        keep = mse <= kth  # keeps every tie of the k-th value
        idx, mse = idx[keep], mse[keep]
    order = np.lexsort((idx, mse))[:k]
    return TopK(idx[order], mse[order])


def merge_topk(a: TopK, b: TopK, k: int) -> TopK:
    """Top-k of the union of two disjoint top-k lists."""
    return select_topk(
        np.concatenate([a.candidate_idx, b.candidate_idx]),
        np.concatenate([a.mse_db2, b.mse_db2]),
        k,
    )
