"""Offline device-level power offset: the whole track's marginal likelihood picks it.

Beyond the paper (issue 15, "unknown transmit power"; docs/filter.md,
"Accuracy round 4: device-level offset"). The device's transmit-power offset
``b`` (dB from ``devices.csv``'s ``tx_power_dbm``) is a constant of the device,
but with four receivers and a free offset one packet fits a wrong (pose,
offset) pair as well as the truth, and the filter's offset belief drifts with
whichever mode it holds. Offline, ``locate`` sees the whole file, so the
offset can be chosen once for the whole track:

1. pass 1 is the filter as it runs causally (wide offset prior,
   ``FilterConfig.offset_prior_sd_db``); it gives candidate offsets ``c``: the
   prior's centre, pass 1's final offset belief and the median of its
   per-packet beliefs (candidates within ``offset_selection_merge_db`` of one
   another merged). If none lies ``offset_selection_trigger_db`` or more
   from the prior's centre, the device sends at its enrolled power and pass
   1 is the answer (no more passes: a matched device costs nothing more);
2. each candidate is run again over the whole file with a tight offset prior
   ``N(c, offset_selection_sd_db²)`` and no offset scans (the offset is then
   nearly known, so a packet's three independent constraints pin the pose);
3. the answer is the track whose filter gives the largest marginal likelihood
   of the whole file, ``log p(y_1:T | c) = Σ_t log p(y_t | y_1:t-1, c)`` (the
   sum of the per-packet log normalisers, :attr:`FilterState.log_evidence`),
   pass 1 included (its wide prior pays its own Occam factor).

A wrong offset makes every packet misfit, so its evidence falls by
``~ h (Δb)² / 2σ²`` per packet against the truth's: over hundreds of packets
the choice is sharp at σ = 0.5 dB and still clear at σ = 3 dB.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import FilterConfig, FilterEstimate
from radiopose.filtering.forked import map_forked
from radiopose.filtering.particle import FilterState, ParticleFilter
from radiopose.likelihood import HeardRss

Record = tuple[float, HeardRss, object]
"""One packet as the passes replay it: ``(t_s, heard, key)``."""


@dataclass(frozen=True)
class OffsetPass:
    """One pass of the offline offset selection.

    Attributes
    ----------
    centre_db
        Centre of the pass's offset prior, dB (``nan`` for pass 1, whose prior
        is the configured wide one around ``devices.csv``'s power).
    log_evidence
        ``log p(y_1:T)`` of the whole file under that pass's filter, nats
        (up to a constant shared by every pass).
    from_profile
        Whether the pass runs at the offset profile's argmax (round 8).
    """

    centre_db: float
    log_evidence: float
    from_profile: bool = False


def tight_config(config: FilterConfig) -> FilterConfig:
    """The filter settings of a pass around a candidate offset: the prior's
    standard deviation ``offset_selection_sd_db``, the first packet searched at
    the centre and one standard deviation either side, and no scans of the
    prior's range (the candidate is the device's offset)."""
    sd = config.offset_selection_sd_db
    return replace(
        config,
        offset_prior_sd_db=sd,
        initial_offsets_db=(-sd, 0.0, sd),
        offset_scans_per_reentry=0,
        offline_offset_selection=False,
    )


def candidate_offsets_db(
    prior_centre_db: float, final_db: float, beliefs_db: np.ndarray, merge_db: float
) -> list[float]:
    """The candidate offsets of the tight passes, dB: the prior's centre, pass 1's
    final belief and the median of its per-packet beliefs, in that order, a
    candidate within ``merge_db`` of an earlier one dropped."""
    raw = [prior_centre_db, final_db]
    finite = beliefs_db[np.isfinite(beliefs_db)]
    if finite.size:
        raw.append(float(np.median(finite)))
    return with_offsets_apart([], raw, merge_db)


def with_offsets_apart(
    candidates: list[float], offsets_db: Iterable[float], apart_db: float
) -> list[float]:
    """``candidates`` with each finite offset of ``offsets_db`` appended, in
    order, unless it lies within ``apart_db`` of a candidate (one appended
    before it included), dB. It merges pass 1's candidates
    (:func:`candidate_offsets_db`), adds the grid's
    (``FilterConfig.offset_selection_grid_db``, apart by
    ``offset_selection_merge_db``) and round 8's profile argmax (apart by
    ``offset_profile_tolerance_db``)."""
    out = list(candidates)
    for v in offsets_db:
        if math.isfinite(v) and all(abs(v - c) > apart_db for c in out):
            out.append(float(v))
    return out


def run_pass(
    pf: ParticleFilter,
    seed: int,
    records: list[Record],
    offset_prior_db: float,
    evidence_out: dict[object, float] | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], float]:
    """Run ``pf`` (a fresh filter, smoothing or causal) over ``records`` from a new
    state seeded ``seed`` whose offset prior is centred on ``offset_prior_db``;
    return its estimates ``(key, estimate)`` and the whole file's log evidence
    (and, into ``evidence_out`` if given, each packet's share of it by key, nats)."""
    st = pf.new_state(seed)
    st.offset_prior_db = offset_prior_db
    out: list[tuple[object, FilterEstimate]] = []
    for t_s, heard, key in records:
        before = st.log_evidence
        est = pf.step(st, t_s, heard, key)
        if evidence_out is not None:
            evidence_out[key] = st.log_evidence - before
        if pf.lag_s is None:
            if est is not None:
                out.append((key, est))
        else:
            out += pf.take_smoothed()
    pf.flush(st)
    out += pf.take_smoothed()
    return out, st.log_evidence


def select_offset(
    pf: ParticleFilter,
    st: FilterState,
    seed: int,
    records: list[Record],
    first_pass: list[tuple[object, FilterEstimate]],
    beliefs_db: np.ndarray,
    evidence_out: dict[object, float] | None = None,
    tracks_out: list[dict[object, FilterEstimate]] | None = None,
    workers: int = 1,
    profile_db: Callable[[], float] | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], list[OffsetPass]]:
    """The offline selection (module docstring) after pass 1.

    Parameters
    ----------
    pf, st
        Pass 1's filter and its state after its last packet (flushed).
    seed
        The filter's seed (every pass starts from it).
    records
        Every packet of the device, in time order.
    first_pass
        Pass 1's estimates ``(key, estimate)`` not yet emitted (returned as
        they are if pass 1 is chosen).
    beliefs_db
        Pass 1's causal offset belief at each packet, dB.

    evidence_out
        If given and a further pass is chosen, filled with that pass's log
        evidence of each packet by key, nats (the reversed pass's combination
        reads it; left empty when pass 1 stands).
    tracks_out
        If given, each further pass's estimates by key are appended, in the
        order of ``passes[1:]`` (round 6's arbiter refines them too).
    workers
        Processes the further passes may use, this one included
        (:func:`radiopose.filtering.forked.map_forked`); the result does not
        depend on it.
    profile_db
        If given (round 8, ``FilterConfig.offline_offset_profile``), called once
        when the selection runs: the device's offset by the data alone, dB
        (:func:`radiopose.filtering.offset_profile.data_offset_db`); a tight
        pass runs there too, last, unless a candidate lies within
        ``offset_profile_tolerance_db`` of it.

    Returns
    -------
    The chosen pass's estimates and every pass's evidence (pass 1 first).
    """
    cfg = pf.config
    passes = [OffsetPass(math.nan, st.log_evidence)]
    best, best_ll = first_pass, st.log_evidence
    final_db = math.nan
    if st.particles is not None and st.log_weights is not None:
        w = np.exp(st.log_weights - np.max(st.log_weights))
        final_db = float(np.sum(w * st.particles[:, K.OFFSET_DB]) / np.sum(w))
    tight = tight_config(cfg)
    centre0 = 0.0  # pass 1's prior centre: devices.csv's power
    candidates = candidate_offsets_db(centre0, final_db, beliefs_db, cfg.offset_selection_merge_db)
    if all(abs(c - centre0) < cfg.offset_selection_trigger_db for c in candidates):
        return best, passes  # the device sends at its enrolled power: pass 1 stands
    candidates = with_offsets_apart(
        candidates, cfg.offset_selection_grid_db, cfg.offset_selection_merge_db
    )
    n_own = len(candidates)
    if profile_db is not None:  # round 8: the offset by the data alone
        candidates = with_offsets_apart(candidates, [profile_db()], cfg.offset_profile_tolerance_db)

    def tight_pass(
        c: float,
    ) -> tuple[list[tuple[object, FilterEstimate]], float, dict[object, float] | None]:
        per_packet: dict[object, float] | None = None if evidence_out is None else {}
        est, ll = run_pass(ParticleFilter(pf.model, tight, pf.lag_s), seed, records, c, per_packet)
        return est, ll, per_packet

    # the passes are independent (each a fresh filter from the same seed): on
    # ``workers`` processes they give what they give one after another
    runs = map_forked([partial(tight_pass, c) for c in candidates], workers)
    for i, (c, (est, ll, per_packet)) in enumerate(zip(candidates, runs, strict=True)):
        passes.append(OffsetPass(c, ll, from_profile=i >= n_own))
        if tracks_out is not None:
            tracks_out.append(dict(est))
        if ll > best_ll:
            best, best_ll = est, ll
            if evidence_out is not None and per_packet is not None:
                evidence_out.clear()
                evidence_out.update(per_packet)
    return best, passes


__all__ = [
    "OffsetPass",
    "Record",
    "candidate_offsets_db",
    "run_pass",
    "select_offset",
    "tight_config",
    "with_offsets_apart",
]
