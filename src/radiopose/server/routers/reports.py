"""Receiver reports in: ``POST /api/v1/reports``, ``GET /api/v1/transmitters``."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Response

from radiopose.capture.records import (
    PLAUSIBLE_RSS_DBM,
    canonical_transmitter,
    transmitter_id_problem,
)
from radiopose.server.db import Database
from radiopose.server.deps import API, DB, AnyRole, ReceiverRole, Worker
from radiopose.server.schemas import ReportAck, ReportBatch


def add_routes(router: APIRouter) -> None:
    """Add this module's routes to ``router`` (the app's own, so they stay flat)."""
    router.add_api_route(
        f"{API}/reports",
        post_reports,
        methods=["POST"],
        status_code=201,
        response_model=ReportAck,
        responses={200: {"model": ReportAck, "description": "batch already stored"}},
    )
    router.add_api_route(
        f"{API}/transmitters", transmitters, methods=["GET"], response_model=list[str]
    )


def post_reports(
    batch: ReportBatch, who: ReceiverRole, response: Response, db: DB, worker: Worker
) -> ReportAck:
    """Store a batch of one receiver's frame reports (answered once durably stored).
    Frames of transmitters that are not enrolled, or with an implausible RSS, are
    skipped and counted in the answer; the rest of the batch is stored."""
    if who.receiver_id != batch.receiver_id:
        raise HTTPException(403, f"this token may post only as receiver {who.receiver_id!r}")
    receivers, transmitters = known_ids(db)
    if batch.receiver_id not in receivers:
        raise HTTPException(422, f"unknown receiver {batch.receiver_id!r}")
    rows = []
    not_enrolled = implausible = 0
    lo, hi = PLAUSIBLE_RSS_DBM
    for i, f in enumerate(batch.frames):
        problem = transmitter_id_problem(f.transmitter)
        if problem:
            raise HTTPException(422, f"frames[{i}]: {problem}")
        mac = canonical_transmitter(f.transmitter)
        if mac not in transmitters:  # another device the sniffer heard: skipped, counted
            not_enrolled += 1
            continue
        if not lo <= f.rss_dbm <= hi:  # a radio's glitch: skipped and counted, as sync does
            implausible += 1
            continue
        rows.append((round(f.timestamp_s * 1e9), f.frame_sha256.lower(), mac, round(f.rss_dbm, 3)))
    rows.sort(key=lambda r: r[0])
    new, _ = db.store_batch(batch.receiver_id, batch.batch_id, rows)
    if new:
        if worker is not None:
            worker.wake()
    else:
        response.status_code = 200
    return ReportAck(
        batch_id=batch.batch_id,
        frames_stored=len(rows) if new else 0,
        duplicate=not new,
        frames_not_enrolled=not_enrolled,
        frames_implausible_rss=implausible,
    )


def transmitters(who: AnyRole, db: DB) -> list[str]:
    """Enrolled transmitter addresses (receivers send only these)."""
    return sorted(known_ids(db)[1])


def known_ids(db: Database) -> tuple[set[str], set[str]]:
    """Receiver ids and canonical transmitter ids of the stored site."""
    receivers, transmitters = db.known_ids()
    return set(receivers), {canonical_transmitter(t) for t in transmitters}
