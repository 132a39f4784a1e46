"""Spoofing alarms on the live server (issue 19, ``docs/security.md``).

The live pipeline hands every ``filter`` estimate to an :class:`AlarmMonitor`,
which keeps one :class:`~radiopose.security.detection.ConsistencyDetector` per
transmitter (fed the packet's RSS, or with ``signal = "residual"`` its residuals
at the estimate's pose) and returns an
event when a transmitter's alarm switches on (``raised``) or off
(``cleared``). Events are stored in the ``alarms`` table
(:meth:`radiopose.server.db.Database.add_alarms`) and served by:

=======  ==================================  ===========================
method   path                                role
=======  ==================================  ===========================
GET      /api/v1/alarms                      viewer, admin
=======  ==================================  ===========================

``GET /api/v1/estimates`` marks each estimate that falls inside a raised alarm
with ``spoof_alarm_flag = 1`` (:func:`flag_estimates`).

The detectors' state is part of the pipeline checkpoint
(``PipelineState.alarm_detectors`` in :mod:`radiopose.server.live`, the same
dictionary the monitor updates): after a restart each transmitter's detector
resumes with its reference variance, CUSUM and alarm state instead of warming
up again (``warmup_s``), and an alarm raised before the restart is not raised
twice.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import BaseModel

from radiopose.packets import PacketObservation
from radiopose.security.detection import (
    ConsistencyDetector,
    DetectorConfig,
    pose_residuals_db,
)
from radiopose.server.schemas import Estimate
from radiopose.site import Site


class Alarm(BaseModel):
    """One alarm event: a transmitter's spoofing alarm ``raised`` or ``cleared``."""

    id: int
    transmitter: str
    packet_id: str
    timestamp_s: float
    state: str
    score_nats: float
    x_m: float
    y_m: float
    raised_s: float


class FlaggedEstimate(Estimate):
    """An estimate of ``GET /api/v1/estimates`` with its alarm flag."""

    spoof_alarm_flag: int = 0
    """1 inside a raised spoofing alarm of the transmitter, else 0."""


class AlarmMonitor:
    """Per-transmitter consistency detectors over the live ``filter`` estimates.

    Parameters
    ----------
    site
        The site (its survey map and devices give the expected RSS).
    config
        Detector parameters.
    detectors
        The per-transmitter detectors (lower-case address), updated in place: pass
        the dictionary that is checkpointed (the live pipeline's state) so a restart
        resumes them; a new one if ``None``.
    """

    def __init__(
        self,
        site: Site,
        config: DetectorConfig | None = None,
        detectors: dict[str, ConsistencyDetector] | None = None,
    ) -> None:
        self.site = site
        self.config = config or DetectorConfig()
        self._models: dict[str, Any] = {}
        self._detectors: dict[str, ConsistencyDetector] = {} if detectors is None else detectors
        self._rx = {r: i for i, r in enumerate(site.receiver_ids)}

    def _model(self, transmitter: str) -> Any:
        key = transmitter.lower()
        if key not in self._models:
            from radiopose.filtering import FilterModel
            from radiopose.likelihood import candidate_space, make_scorer

            space = candidate_space(self.site, transmitter)
            # only FilterModel.expected is used: the scorer that costs nothing to build
            scorer = make_scorer("reference", space)
            self._models[key] = FilterModel.build(self.site, space, scorer)
        return self._models[key]

    def observe(
        self,
        obs: PacketObservation,
        position_m: Sequence[float],
        orientation_deg: Sequence[float],
    ) -> dict[str, Any] | None:
        """One estimated packet; an alarm event row (without ``id``) if the alarm changed."""
        key = obs.transmitter.lower()
        rss = np.full(len(self._rx), np.nan)
        for r, v in zip(obs.receiver_ids, obs.rss_dbm, strict=True):
            if r in self._rx:
                rss[self._rx[r]] = v
        if self.config.signal == "rss":
            values = rss
        else:
            model = self._model(obs.transmitter)
            pose = np.asarray(position_m, np.float64), np.asarray(orientation_deg, np.float64)
            values = pose_residuals_db(model, *pose, rss)[0]
        det = self._detectors.get(key)
        if det is None:
            det = self._detectors[key] = ConsistencyDetector(self.config)
        else:
            det.config = self.config  # a checkpointed detector takes today's settings
            if det.last_s is not None and obs.timestamp_s - det.last_s > 1.0:
                det.reset()  # the tracker re-acquires after a silence
        before = det.alarm
        score, alarm = det.update(obs.timestamp_s, values)
        if alarm == before:
            return None
        return {
            "transmitter": obs.transmitter,
            "packet_id": str(obs.packet_id),
            "timestamp_s": float(obs.timestamp_s),
            "state": "raised" if alarm else "cleared",
            "score_nats": float(score),
            "x_m": float(position_m[0]),
            "y_m": float(position_m[1]),
        }


def flag_estimates(
    rows: list[dict[str, Any]], events: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Add ``spoof_alarm_flag`` (1 inside a raised alarm of its transmitter, else 0)."""
    spans: dict[str, list[tuple[float, float]]] = {}
    open_at: dict[str, float] = {}
    for e in sorted(events, key=lambda e: (e["timestamp_s"], e["id"])):
        tx = e["transmitter"].lower()
        if e["state"] == "raised":
            open_at.setdefault(tx, e["timestamp_s"])
        elif tx in open_at:
            spans.setdefault(tx, []).append((open_at.pop(tx), e["timestamp_s"]))
    for tx, t0 in open_at.items():
        spans.setdefault(tx, []).append((t0, float("inf")))
    out = []
    for r in rows:
        t = r["timestamp_s"]
        flag = any(a <= t < b for a, b in spans.get(r["transmitter"].lower(), ()))
        out.append({**r, "spoof_alarm_flag": int(flag)})
    return out
