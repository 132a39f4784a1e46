"""Offline: the arbiter's device offset judged by the passes' evidence, and a pass at it.

Beyond the paper (issue 15, unknown transmit power; docs/filter.md, "Accuracy
round 7"). Round 6's batch MAP arbiter (:mod:`radiopose.filtering.refine2d`)
takes every candidate track to its own optimum of one objective (data, motion
prior, one device offset ``b`` with the wide prior around ``devices.csv``'s
power) and keeps the lowest. With the device 6 dB above its enrolled power at
σ = 3 dB two things were left (tuning seeds 7060–7079):

* **no candidate in the truth's basin** (a search failure): the offset
  selection (:mod:`radiopose.filtering.offset`) ran its tight passes only at
  pass 1's beliefs, none near the device's offset, while the arbiter's chosen
  candidate refined to an offset near it. :func:`arbitrate_offline` then runs
  one more tight pass at that refined offset (``offline_offset_refit``), when
  no tight pass ran within ``offset_refit_tolerance_db`` of it and it lies
  ``offset_selection_trigger_db`` or more from the enrolled power, and lets its
  track compete;
* **a tie of the objective** between the truth's basin and a mirror track at
  another offset: the refined objectives differ by under a nat, while the
  tight passes' marginal likelihoods of the whole file (which integrate over
  the poses) differ by several nats in the truth's favour. With
  ``arbiter_offset_evidence`` each candidate's refined objective gets a
  penalty from its refined offset ``b``:
  ``ℓ_max − log Σ_j exp(ℓ_j − (b − c_j)² / 2 s²)``, nats, over the tight passes
  ``j`` (centre ``c_j``, evidence ``ℓ_j``; ``s`` the passes' prior sd,
  ``offset_selection_sd_db``): near the best pass's centre it is ~0, near a
  pass that lost by ``Δ`` nats it is ~``Δ``.

Both are off by default (``FilterConfig``); with both off
:func:`arbitrate_offline` is :func:`radiopose.filtering.refine2d.arbitrate`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.offset import OffsetPass, Record, run_pass, tight_config
from radiopose.filtering.particle import ParticleFilter
from radiopose.filtering.refine2d import Arbitration, Refined2d, arbitrate
from radiopose.filtering.reverse import reversed_records


def evidence_penalty(passes: Sequence[OffsetPass], sd_db: float) -> Callable[[float], float] | None:
    """The offset penalty of the arbiter (module docstring) from the tight passes
    of ``passes`` (those with a finite ``centre_db``), nats as a function of an
    offset in dB; ``None`` with fewer than two tight passes (nothing to compare).

    Raises
    ------
    ValueError
        ``sd_db`` not positive.
    """
    if not (math.isfinite(sd_db) and sd_db > 0):
        raise ValueError(f"evidence_penalty: sd_db {sd_db!r} must be positive")
    tight = [p for p in passes if math.isfinite(p.centre_db) and math.isfinite(p.log_evidence)]
    if len(tight) < 2:
        return None
    c = np.array([p.centre_db for p in tight])
    ll = np.array([p.log_evidence for p in tight])
    top = float(ll.max())

    def penalty(offset_db: float) -> float:
        if not math.isfinite(offset_db):
            return math.inf
        z = ll - top - 0.5 * ((offset_db - c) / sd_db) ** 2
        m = float(z.max())
        return -(m + math.log(float(np.exp(z - m).sum())))

    return penalty


def needs_refit(
    offset_db: float, passes: Sequence[OffsetPass], tolerance_db: float, trigger_db: float
) -> bool:
    """Whether a tight pass at ``offset_db`` (the arbiter's chosen refined offset)
    should run: it lies ``trigger_db`` or more from the enrolled power (0 dB) and
    no tight pass of ``passes`` ran within ``tolerance_db`` of it."""
    if not math.isfinite(offset_db) or abs(offset_db) < trigger_db:
        return False
    return all(
        not math.isfinite(p.centre_db) or abs(p.centre_db - offset_db) > tolerance_db
        for p in passes
    )


def _chosen_offset_db(log: Sequence[Arbitration]) -> float:
    """The refined offset of the candidate chosen on the longest track, dB."""
    if not log:
        return math.nan
    a = max(log, key=lambda a: a.stop - a.start)
    return a.offsets_db[a.chosen] if a.offsets_db else math.nan


def arbitrate_offline(
    pf: ParticleFilter,
    records: list[Record],
    candidates: list[dict[object, FilterEstimate]],
    sigma_db: float,
    passes: list[OffsetPass],
    seed: int,
    workers: int = 1,
    cache: dict[tuple[object, ...], Refined2d] | None = None,
    handicaps_nats: list[float] | None = None,
) -> tuple[list[tuple[object, FilterEstimate]], list[Arbitration], list[OffsetPass]]:
    """Round 6's arbiter with round 7's offset evidence and refit (module docstring).

    Parameters
    ----------
    pf
        The forward pass's filter (model, settings, lag).
    records
        Every packet of the device, in time order.
    candidates
        The arbiter's candidate tracks by key, the reference first
        (:func:`radiopose.filtering.refine2d.arbitrate`).
    sigma_db
        The forward filter's σ estimate, dB.
    passes
        The offset selection's passes (pass 1 first, centre ``nan``).
    seed
        The filter's seed (a refit pass starts from it, as the selection's do).
    workers, cache
        As :func:`radiopose.filtering.refine2d.arbitrate` (the cache serves the
        first arbitration only: a refit's contenders have another reference).
    handicaps_nats
        Per candidate, nats added to its refined objective in the first
        arbitration (:func:`radiopose.filtering.refine2d.arbitrate`).

    Returns
    -------
    Every packet's estimate, the arbitration log (of the last arbitration) and
    the passes, a refit pass appended if one ran.
    """
    cfg = pf.config
    sd = cfg.offset_selection_sd_db
    passes = list(passes)
    penalty = evidence_penalty(passes, sd) if cfg.arbiter_offset_evidence else None
    out, log = arbitrate(
        pf.model, records, candidates, sigma_db, cfg, cfg.refine_max_nfev,
        workers=workers, cache=cache, offset_penalty=penalty, handicaps_nats=handicaps_nats,
    )  # fmt: skip
    if not cfg.offline_offset_refit:
        return out, log, passes
    b = _chosen_offset_db(log)
    if not needs_refit(b, passes, cfg.offset_refit_tolerance_db, cfg.offset_selection_trigger_db):
        return out, log, passes
    tight = ParticleFilter(pf.model, tight_config(cfg), pf.lag_s)
    # the first arbitration's output (already at its optimum) against the new pass(es)
    contenders = [dict(out)]
    if cfg.offset_refit_passes in ("forward", "both"):
        track, ll = run_pass(tight, seed, records, b)
        passes.append(OffsetPass(b, ll))
        contenders.append(dict(track))
    if cfg.offset_refit_passes in ("reversed", "both"):
        # the reversed pass's own stream, as radiopose.filtering.reverse.reverse_pass's
        track, ll = run_pass(tight, (seed + 1) % 2**63, reversed_records(records), b)
        if cfg.offset_refit_passes == "reversed":  # its evidence: p(y) factored backwards
            passes.append(OffsetPass(b, ll))
        contenders.append(dict(track))
    penalty = evidence_penalty(passes, sd) if cfg.arbiter_offset_evidence else None
    out, log = arbitrate(
        pf.model, records, contenders, sigma_db, cfg, cfg.refine_max_nfev,
        workers=workers, offset_penalty=penalty,
    )  # fmt: skip
    return out, log, passes


__all__ = ["arbitrate_offline", "evidence_penalty", "needs_refit"]
