"""Likelihood estimation: score every candidate pose of a packet, keep the top k.

Paper, "Enhanced Localisation Pipeline", steps 1–2. A candidate is a grid
position × grid orientation (:mod:`~radiopose.likelihood.candidates`); its score
is the MSE between the packet's RSS and ``M_r(p) + P_tx + D_t`` over the
receivers that heard it. Scorers are pluggable: each takes a
:class:`~radiopose.likelihood.candidates.CandidateSpace` and offers
``score_topk(packet, k) -> TopK`` (and ``score_heard(heard, k)``).

Registry (:data:`SCORERS`):

* ``"reference"`` — exhaustive float64 (:mod:`~radiopose.likelihood.reference`);
* ``"numpy"`` — float32 table screen + exact rescoring
  (:mod:`~radiopose.likelihood.numpy_kernel`), same output as the reference;
* ``"numba"`` — compiled circular-shift kernel with fused, pruned top-k and
  exact rescoring (:mod:`~radiopose.likelihood.compiled`), same output as the
  reference at a few ms per packet (falls back to ``"numpy"`` for candidate
  sets without the azimuth-sweep structure).

Example
-------
>>> from radiopose.likelihood import candidate_space, make_scorer
>>> # scorer = make_scorer("numpy", candidate_space(site, "02:00:00:00:00:01"))
>>> # top = scorer.score_topk(packet, k=100)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from radiopose.likelihood.candidates import (
    CandidateSpace,
    HeardRss,
    candidate_mse_db2,
    candidate_space,
    exact_mse_db2,
    expected_rss_dbm,
)
from radiopose.likelihood.capabilities import ScorerBase
from radiopose.likelihood.memo import MemoScorer
from radiopose.likelihood.numpy_kernel import TableScorer
from radiopose.likelihood.power import best_power_mse_db2, profile_offset_db
from radiopose.likelihood.reference import ReferenceScorer
from radiopose.likelihood.topk import TopK, select_topk


class Scorer(Protocol):
    """What the tracker needs from a scorer.

    Every scorer offers ``score_heard`` (and, for interactive use, ``score_topk``
    from :class:`~radiopose.likelihood.capabilities.ScorerBase`). The optional features
    are declared, not probed (:mod:`~radiopose.likelihood.capabilities`):
    ``supports_window`` says whether :meth:`score_window` works (the compiled
    scorer; the tracker's bounded search needs it), ``supports_position_mse``
    whether :meth:`position_mse_db2` does (MSE maps). A scorer without them
    inherits :class:`~radiopose.likelihood.capabilities.ScorerBase`: both
    ``False``, the methods raise ``NotImplementedError``.
    """

    # read-only members (properties): class constants and instance attributes both satisfy them
    @property
    def name(self) -> str: ...

    @property
    def space(self) -> CandidateSpace: ...

    @property
    def supports_window(self) -> bool: ...

    @property
    def supports_position_mse(self) -> bool: ...

    def score_heard(self, heard: HeardRss, k: int) -> TopK: ...

    def score_window(
        self,
        heard: HeardRss,
        k: int,
        positions: np.ndarray,
        azimuth_lo_deg: float,
        azimuth_span_deg: float,
    ) -> TopK: ...

    def position_mse_db2(self, heard: HeardRss) -> np.ndarray: ...


def _compiled(space: CandidateSpace) -> Scorer:
    """The compiled shift kernel; the numpy scorer where the space lacks its structure."""
    from radiopose.likelihood.compiled import ShiftScorer, UnsupportedSpaceError

    try:
        return ShiftScorer(space)
    except UnsupportedSpaceError:
        return TableScorer(space)


SCORERS: dict[str, Callable[[CandidateSpace], Scorer]] = {
    "reference": ReferenceScorer,
    "numpy": TableScorer,
    "numba": _compiled,
}
"""Scorer name → constructor taking a :class:`CandidateSpace`."""


def make_scorer(name: str, space: CandidateSpace) -> Scorer:
    """Build the scorer registered under ``name`` for a candidate space."""
    try:
        factory = SCORERS[name]
    except KeyError:
        raise ValueError(f"unknown scorer {name!r} (known: {', '.join(sorted(SCORERS))})") from None
    return factory(space)


__all__ = [
    "SCORERS",
    "CandidateSpace",
    "HeardRss",
    "MemoScorer",
    "ReferenceScorer",
    "Scorer",
    "ScorerBase",
    "TableScorer",
    "TopK",
    "best_power_mse_db2",
    "candidate_mse_db2",
    "candidate_space",
    "exact_mse_db2",
    "expected_rss_dbm",
    "make_scorer",
    "profile_offset_db",
    "select_topk",
]
