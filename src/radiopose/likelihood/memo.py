"""A scorer wrapper that remembers each packet's top-k.

Running several methods over the same packets (the accuracy script, the demo)
scores each packet once: the wrapped scorer is called on the first request
and the result is reused for later requests of the same packet.
"""

from __future__ import annotations

from radiopose.likelihood.candidates import CandidateSpace, HeardRss
from radiopose.likelihood.topk import TopK
from radiopose.packets import PacketObservation


class MemoScorer:
    """Wrap a scorer; results are keyed by (receivers heard, their RSS, k).

    Parameters
    ----------
    inner
        Any scorer (:class:`~radiopose.likelihood.Scorer`); its declared
        features (``supports_window``, ``supports_position_mse``) and their
        methods are passed through unchanged; a feature it lacks is absent.
    """

    def __init__(self, inner: object) -> None:
        self.inner = inner
        self.name = f"memo({inner.name})"  # type: ignore[attr-defined]
        self.space: CandidateSpace = inner.space  # type: ignore[attr-defined]
        self.supports_window: bool = bool(inner.supports_window)  # type: ignore[attr-defined]
        self.supports_position_mse: bool = bool(inner.supports_position_mse)  # type: ignore[attr-defined]
        self._cache: dict[tuple, TopK] = {}
        # The optional features are the inner scorer's own methods, present only
        # where declared (a bounded search's window depends on each method's
        # own track, so it is passed through, not remembered).
        if self.supports_window:
            self.score_window = inner.score_window  # type: ignore[attr-defined]
        if self.supports_position_mse:
            self.position_mse_db2 = inner.position_mse_db2  # type: ignore[attr-defined]
        # The one-thread twin (``with_parallel``) is the inner scorer's own: a
        # method that asks for it (the filter's re-entry, whose searches at
        # its own offsets other methods never repeat) gets the same scorer as
        # in a plain ``locate``, unremembered (results do not depend on it).
        if hasattr(inner, "with_parallel"):
            self.with_parallel = inner.with_parallel

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        key = (tuple(heard.receiver_index.tolist()), heard.rss_dbm.tobytes(), k)
        hit = self._cache.get(key)
        if hit is None:
            hit = self.inner.score_heard(heard, k)  # type: ignore[attr-defined]
            self._cache[key] = hit
        return hit

    def score_topk(self, packet: PacketObservation, k: int = 100) -> TopK:
        return self.score_heard(self.space.heard(packet), k)
