"""Offline: mid-track restarts of the 3-D filter as more refinement starts.

Beyond the paper (issue 18; docs/pose3d.md, "Mid-track restarts, 2026-11-27").
The 3-D batch refinement (:func:`radiopose.filtering.refine3d.refine_smoothed`)
keeps the refined track of the lowest objective among its starts: the forward
filter's smoothed track, its offset-bank members' tracks, the reversed pass's
track (:func:`radiopose.filtering.reverse.reversed_tracks3d`) and a hybrid
spliced from those. Its remaining failures are **search** failures: no start
lies in the truth's basin, and the wrong modes often cover only part of the
track. Both passes acquire at an end of the track; a pass that acquires *inside*
it enters the data from another place.

A restart at packet ``i`` runs two fresh filters (the same model, settings
and lag; seeds of their own): one forward over the packets ``i …`` (to the
end) and one over the time-reversed packets ``… i − 1`` (back to the start).
Each acquires afresh from the coarse grid at the restart point. Their smoothed
tracks, spliced at ``i``, cover every packet of the track once: one more start.
With ``n`` restarts the points are at ``1/(n+1), …, n/(n+1)`` of the track's
time span. The forward half keeps the optional heading prior; the reversed
half runs without it (it ties the azimuth to the velocity, which the time
reversal negates: :func:`~radiopose.filtering.reverse.reversed_tracks3d`).

Offline only: the passes need the whole file (the causal filter and the live
server never run them).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from radiopose.errors import InputError
from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.reverse import Record, pass_tracks3d, reversed_records

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import ParticleFilter3d

Track = list[tuple[object, FilterEstimate]]
"""A smoothed track: ``(key, estimate)`` per packet."""


def restart_indices(times_s: list[float] | np.ndarray, n_restarts: int) -> list[int]:
    """The packets at which ``n_restarts`` restarts begin: the first packet at or
    after each of ``1/(n+1), …, n/(n+1)`` of the time span ``times_s[0] …
    times_s[-1]`` (seconds, non-decreasing); points that would leave either side
    empty, and repeats, are dropped (a track of fewer than two packets has none)."""
    if n_restarts < 0:
        raise InputError(f"mid-track restarts: n_restarts = {n_restarts!r} must be >= 0")
    t = np.asarray(times_s, dtype=float)
    if t.size < 2 or n_restarts == 0:
        return []
    t0, t1 = float(t[0]), float(t[-1])
    out: list[int] = []
    for j in range(1, n_restarts + 1):
        i = int(np.searchsorted(t, t0 + (t1 - t0) * j / (n_restarts + 1), side="left"))
        if 0 < i < t.size and i not in out:
            out.append(i)
    return out


def _spliced(before: Track, after: Track) -> Track:
    """``before``'s estimates, then ``after``'s (by key; ``after`` wins a shared key)."""
    d = dict(before)
    d.update(after)
    return list(d.items())


def midtrack_tracks3d(
    pf: ParticleFilter3d, records: list[Record], seed: int, n_restarts: int, members: bool = False
) -> list[Track]:
    """The 3-D filter restarted inside the track (see the module docstring):
    for each restart point (:func:`restart_indices` over ``records``' times), a
    forward pass from it to the end and a pass over the time-reversed packets
    from just before it back to the start, spliced into one track of every
    packet. With ``members`` and the offset bank on, also member ``k`` of the
    reversed half spliced with member ``k`` of the forward half, per member.
    Each pass has its own seed drawn from ``seed``. Returns the spliced tracks,
    restart by restart."""
    idx = restart_indices([r[0] for r in records], n_restarts)
    if not idx:
        return []
    seeds = np.random.SeedSequence(seed).spawn(2 * len(idx))
    no_heading = replace(pf.pose3d, heading_prior_deg=0.0)
    out: list[Track] = []
    for j, i in enumerate(idx):
        s_fwd, s_rev = (int(s.generate_state(1, np.uint64)[0] >> np.uint64(1))
                        for s in seeds[2 * j : 2 * j + 2])  # fmt: skip
        fwd = pass_tracks3d(pf, records[i:], s_fwd, members)
        rev = pass_tracks3d(pf, reversed_records(records[:i]), s_rev, members, no_heading)
        out += [_spliced(r, f) for r, f in zip(rev, fwd, strict=True)]
    return out


__all__ = ["Track", "midtrack_tracks3d", "pass_tracks3d", "restart_indices"]
