"""What a scorer offers beyond the top-k of a packet, declared, not probed.

Every scorer has ``score_heard`` (the tracker's call). :meth:`ScorerBase.score_topk`
(a packet in, its top-k out) is a convenience for interactive use and the
tests; nothing in the pipeline calls it. Two further features exist
only in some; a scorer declares them with a class attribute and callers read
the attribute (never ``hasattr``):

* ``supports_window`` — :meth:`ScorerBase.score_window`: the top-k among a list
  of positions × an azimuth window (the tracker's bounded search);
* ``supports_position_mse`` — :meth:`ScorerBase.position_mse_db2`: the MSE per
  position minimised over orientations (MSE maps).

:class:`ScorerBase` gives both as ``False`` with methods that say so.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from radiopose.likelihood.candidates import CandidateSpace, HeardRss
from radiopose.likelihood.topk import TopK
from radiopose.packets import PacketObservation


class ScorerBase:
    """Defaults of the optional scorer features: not supported."""

    name: str = "?"
    supports_window: ClassVar[bool] = False
    """Whether :meth:`score_window` is offered."""
    supports_position_mse: ClassVar[bool] = False
    """Whether :meth:`position_mse_db2` is offered."""

    space: CandidateSpace

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        """Top-k candidates of the receivers that heard one packet (best first)."""
        raise NotImplementedError(f"scorer {self.name!r} has no score_heard")

    def score_topk(self, packet: PacketObservation, k: int = 100) -> TopK:
        """Top-k candidates of one packet (best first); not used by the pipeline."""
        return self.score_heard(self.space.heard(packet), k)

    def score_window(
        self,
        heard: HeardRss,
        k: int,
        positions: np.ndarray,
        azimuth_lo_deg: float,
        azimuth_span_deg: float,
    ) -> TopK:
        """Top-k among ``positions`` × azimuths in ``[lo, lo + span]`` (wrapping), degrees."""
        raise NotImplementedError(f"scorer {self.name!r} has no window search")

    def position_mse_db2(self, heard: HeardRss) -> np.ndarray:
        """Per position, the MSE minimised over orientations ``(n_pos,)``, dB²."""
        raise NotImplementedError(f"scorer {self.name!r} has no per-position MSE")
