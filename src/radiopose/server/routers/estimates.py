"""Estimates out: ``GET /api/v1/estimates``, ``/alarms`` and the ``/stream`` of events."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from radiopose.server.alarms import Alarm, FlaggedEstimate, flag_estimates
from radiopose.server.deps import API, DB, Viewer
from radiopose.server.routers.site import health_of
from radiopose.server.schemas import Estimate, TransmitterId

_Transmitter = Annotated[TransmitterId | None, Query()]
"""A transmitter id in a query, checked as every reader checks one (:data:`TransmitterId`)."""


def add_routes(router: APIRouter) -> None:
    """Add this module's routes to ``router`` (the app's own, so they stay flat)."""
    router.add_api_route(
        f"{API}/estimates",
        estimates,
        methods=["GET"],
        response_model=list[FlaggedEstimate],
        response_model_exclude_none=True,
    )
    router.add_api_route(f"{API}/alarms", alarms, methods=["GET"], response_model=list[Alarm])
    router.add_api_route(f"{API}/stream", stream, methods=["GET"])


def estimates(
    who: Viewer,
    db: DB,
    transmitter: _Transmitter = None,
    since_s: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
) -> list[dict[str, Any]]:
    """Estimates (columns of ``estimates.csv``) in time order; the optional
    uncertainty columns (``position_std_m``, ``azimuth_std_deg``) where the
    method gives them, and ``spoof_alarm_flag`` (1 inside a raised spoofing
    alarm, :mod:`radiopose.server.alarms`)."""
    transmitter = _canonical(transmitter)
    rows = db.estimates(transmitter, since_s, limit=limit)
    return flag_estimates(rows, db.alarms(transmitter, limit=100_000)) if rows else rows


def alarms(
    who: Viewer,
    db: DB,
    transmitter: _Transmitter = None,
    since_s: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 1_000,
) -> list[dict[str, Any]]:
    """Spoofing alarm events (``raised``/``cleared``) in time order."""
    return db.alarms(_canonical(transmitter), since_s, limit=limit)


def _canonical(transmitter: str | None) -> str | None:
    """A queried id in the form reports are matched in (a MAC ``AA-BB-…`` as
    ``aa:bb:…``; the database compares ids case-insensitively), so a query
    finds what the reports in either spelling made (helper-64: the dash form
    that reports accept found nothing)."""
    from radiopose.capture.records import canonical_transmitter

    return None if transmitter is None else canonical_transmitter(transmitter)


async def stream(
    request: Request,
    who: Viewer,
    db: DB,
    after_id: Annotated[int | None, Query(ge=0, le=2**63 - 1)] = None,
) -> StreamingResponse:
    """Server-sent events: ``estimates`` (JSON list) as stored, ``health`` every 2 s."""
    state = request.app.state

    async def events() -> AsyncIterator[str]:
        last = after_id
        if last is None:  # start with the most recent trail
            last = max(0, await run_in_threadpool(db.last_estimate_id) - 200)
        next_health = 0.0
        while not state.stopping and not await request.is_disconnected():
            rows = await run_in_threadpool(db.estimates, None, None, last, 1_000)
            if rows:
                last = rows[-1]["id"]
                yield _sse("estimates", [_public(r) for r in rows])
            if time.monotonic() >= next_health:
                next_health = time.monotonic() + 2.0
                yield _sse("health", (await run_in_threadpool(health_of, db)).model_dump())
            await asyncio.sleep(0.1)

    return StreamingResponse(
        events(),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )


def _public(row: dict[str, Any]) -> dict[str, Any]:
    """An estimate's JSON object: the contract columns, and the optional ones when set."""
    return {k: row[k] for k in Estimate.model_fields if row.get(k) is not None}


def _sse(event: str, data: Any) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"
