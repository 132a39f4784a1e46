"""The reference scorer: every candidate, exactly, in float64.

Paper, "Enhanced Localisation Pipeline", step 1. For one packet, every
candidate position × orientation gets the MSE between the measured RSS and
``M_r(p) + P_tx + D_t`` over the receivers that heard it
(:func:`~radiopose.likelihood.candidates.exact_mse_db2`). Positions are taken in
chunks so that memory stays bounded (about ``chunk_terms`` float64 terms at a
time), and a running top-k is kept. Slow — seconds per packet on the paper's
grid — and obviously correct: faster scorers are tested against it.
"""

from __future__ import annotations

import numpy as np

from radiopose.likelihood.candidates import CandidateSpace, HeardRss, exact_mse_db2
from radiopose.likelihood.capabilities import ScorerBase
from radiopose.likelihood.topk import TopK, merge_topk, select_topk


class ReferenceScorer(ScorerBase):
    """Exhaustive float64 scorer (see module docstring).

    Parameters
    ----------
    space
        The device's candidate space at the site.
    chunk_terms
        Upper bound on ``positions × orientations × receivers`` per chunk.
    """

    name = "reference"

    def __init__(self, space: CandidateSpace, chunk_terms: int = 2_000_000) -> None:
        self.space = space
        per_pos = space.n_orientations * space.n_receivers
        self.chunk_positions = max(1, chunk_terms // max(per_pos, 1))

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        """Top-k candidates for one packet given as site receiver indices."""
        s = self.space
        n_o = s.n_orientations
        best = TopK(np.empty(0, np.int64), np.empty(0))
        for start in range(0, s.n_positions, self.chunk_positions):
            stop = min(start + self.chunk_positions, s.n_positions)
            cand = np.arange(start * n_o, stop * n_o, dtype=np.int64)
            mse = exact_mse_db2(s, heard, cand)
            best = merge_topk(best, select_topk(cand, mse, k), k)
        return best
