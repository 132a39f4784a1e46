"""Likelihood maps: one packet's MSE per candidate position, minimised over orientations.

What :func:`radiopose.plots.plot_mse_map` draws. A scorer that declares
``supports_position_mse`` (:mod:`radiopose.likelihood.capabilities`: the
compiled scorer) gives the map from its own tables; the numpy
:class:`~radiopose.likelihood.TableScorer` (which declares no such method) is
read here from its float32 tables; without a scorer the map is computed
exactly in float64.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from radiopose.likelihood.candidates import CandidateSpace, HeardRss, expected_rss_dbm
from radiopose.likelihood.numpy_kernel import TableScorer
from radiopose.units import FloatArray

__all__ = ["position_mse_db2"]


def position_mse_db2(space: CandidateSpace, heard: HeardRss, scorer: Any = None) -> FloatArray:
    """Per position, the packet's MSE minimised over orientations ``(n_pos,)``, dB².

    Parameters
    ----------
    space
        The candidate space.
    heard
        The receivers (site indices) that heard the packet and their RSS, dBm.
    scorer
        A scorer of ``space``: used when it declares ``supports_position_mse``
        or is a :class:`~radiopose.likelihood.TableScorer`.
    """
    if scorer is not None and scorer.supports_position_mse:
        return np.asarray(scorer.position_mse_db2(heard), np.float64)
    if isinstance(scorer, TableScorer):
        return _table_position_mse_db2(scorer, heard)
    n_pos, n_o = space.n_positions, space.n_orientations
    best = np.full(n_pos, np.inf)
    chunk = max(1, 1_000_000 // max(n_o * space.n_receivers, 1))
    for start in range(0, n_pos, chunk):
        stop = min(start + chunk, n_pos)
        pos = np.repeat(np.arange(start, stop), n_o)
        ori = np.tile(np.arange(n_o), stop - start)
        exp = expected_rss_dbm(space, pos, ori)
        acc = np.zeros(pos.size)
        for r, rss in zip(heard.receiver_index, heard.rss_dbm, strict=True):
            acc += (rss - exp[:, r]) ** 2
        best[start:stop] = (acc / heard.n_heard).reshape(-1, n_o).min(axis=1)
    return best


def _table_position_mse_db2(scorer: TableScorer, heard: HeardRss) -> FloatArray:
    """:func:`position_mse_db2` from a numpy scorer's float32 tables (``inf``: invalid)."""
    s = scorer.space
    acc = np.zeros(s.n_candidates, dtype=np.float32)
    for r, rss in zip(heard.receiver_index, heard.rss_dbm, strict=True):
        d = np.float32(rss - scorer.centre_db[r]) - scorer.table[:, r]
        acc += d * d
    per_pos = (acc / heard.n_heard).reshape(s.n_positions, -1).min(axis=1).astype(np.float64)
    per_pos[~np.all(scorer.valid[:, heard.receiver_index], axis=1)] = np.inf
    return per_pos
