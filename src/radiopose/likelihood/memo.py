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
        Any scorer (``score_heard``/``score_topk``); its ``score_window``, if
        any, is exposed unchanged.
    """

    def __init__(self, inner: object) -> None:
        self.inner = inner
        self.name = f"memo({getattr(inner, 'name', '?')})"
        self.space: CandidateSpace = inner.space  # type: ignore[attr-defined]
        self._cache: dict[tuple, TopK] = {}
        window = getattr(inner, "score_window", None)
        if window is not None:
            # Bounded search (``TrackerConfig(search="bounded")``): the window depends
            # on each method's own track, so it is passed through, not remembered.
            self.score_window = window

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        key = (tuple(heard.receiver_index.tolist()), heard.rss_dbm.tobytes(), k)
        hit = self._cache.get(key)
        if hit is None:
            hit = self.inner.score_heard(heard, k)  # type: ignore[attr-defined]
            self._cache[key] = hit
        return hit

    def score_topk(self, packet: PacketObservation, k: int = 100) -> TopK:
        return self.score_heard(self.space.heard(packet), k)
