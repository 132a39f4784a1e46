"""The central server: a FastAPI app over the database and the live pipeline.

:func:`create_app` builds one app around one :class:`~radiopose.server.db.Database`;
everything the app needs lives on ``app.state`` (no module-level state), so
several apps — or several processes on one database — never share memory.

API (version 1, OpenAPI at ``/docs`` and ``/openapi.json``); every endpoint
but the dashboard's static files needs ``Authorization: Bearer TOKEN``
(missing or unknown token: 401; wrong role: 403):

=======  ==================================  ===========================
method   path                                role
=======  ==================================  ===========================
POST     /api/v1/reports                     receiver (own id only)
GET      /api/v1/transmitters                receiver, viewer, admin
GET      /api/v1/estimates                   viewer, admin
GET      /api/v1/alarms                      viewer, admin
GET      /api/v1/stream                      viewer, admin (SSE)
GET      /api/v1/site                        viewer, admin
GET      /api/v1/patterns/{name}             viewer, admin
GET      /health                             viewer, admin
PUT/DEL  /api/v1/admin/receivers/{id}        admin
PUT/DEL  /api/v1/admin/devices/{address}     admin
PUT/DEL  /api/v1/admin/patterns/{name}       admin
PUT      /api/v1/admin/survey                admin
=======  ==================================  ===========================

Every 4xx answer is ``{"detail": "<one line>"}``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from fastapi import Depends, FastAPI, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from radiopose.capture.records import canonical_transmitter, transmitter_id_problem
from radiopose.errors import InputError
from radiopose.server import sitestore
from radiopose.server.alarms import FlaggedEstimate, add_routes, flag_estimates
from radiopose.server.auth import READ_ROLES, Principal, hash_token
from radiopose.server.db import Database
from radiopose.server.live import LiveConfig, LiveWorker
from radiopose.server.schemas import (
    MAX_BODY_BYTES,
    MAX_CSV_BYTES,
    Area,
    CsvIn,
    DeviceIn,
    DeviceOut,
    Estimate,
    Health,
    ReceiverHealth,
    ReceiverIn,
    ReceiverOut,
    ReportAck,
    ReportBatch,
    SiteOut,
)

log = logging.getLogger("radiopose.server")
STATIC_DIR = Path(__file__).with_name("static")
API = "/api/v1"


# ----------------------------------------------------------------------------- site import
def import_site_dir(db: Database, directory: str | Path) -> str:
    """Import a site directory into the database on start.

    The directory is read and validated. If it is the one imported last time
    (same content hash) the stored site — including admin edits made since —
    is kept; otherwise the directory replaces the stored site.

    Returns
    -------
    ``"imported"`` or ``"kept"``.
    """
    parts, digest = sitestore.read_site_parts(directory)
    if db.meta("source_hash") == digest and db.site_version() > 0:
        return "kept"
    db.replace_site(parts, source_hash=digest)
    return "imported"


# ----------------------------------------------------------------------------- body limit
class BodyLimit:
    """Pure ASGI middleware: answer 413 once a request body passes its limit."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = (
            MAX_CSV_BYTES + 65_536 if scope["path"].startswith(f"{API}/admin") else MAX_BODY_BYTES
        )
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await _drain(receive, 0)
            await _too_large(send, limit)
            return
        # Read the whole body first (it is small: at most `limit` bytes), so an
        # oversized one is refused before the app sees any of it. Raising from
        # inside the app's receive() would not do: FastAPI turns any error while
        # reading a body into a 400.
        parts: list[bytes] = []
        seen = 0
        more = True
        while more:
            msg = await receive()
            if msg["type"] != "http.request":
                return  # the client went away
            parts.append(msg.get("body", b""))
            seen += len(parts[-1])
            more = bool(msg.get("more_body", False))
            if seen > limit:
                if more:
                    await _drain(receive, seen)
                await _too_large(send, limit)
                return
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(parts), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


#: How much of an oversized body is read and discarded before the 413 goes out.
#: Answering while the client is still sending makes the server close a socket
#: with unread data, and the client then sees a connection reset instead of the
#: 413 (a real race: a local test run failed on it); past this cap the server
#: answers anyway.
DRAIN_CAP_BYTES = 16_000_000


async def _drain(receive: Receive, seen: int) -> None:
    """Read and discard the rest of a request body, up to :data:`DRAIN_CAP_BYTES`."""
    more = True
    while more and seen <= DRAIN_CAP_BYTES:
        msg = await receive()
        if msg["type"] != "http.request":
            return
        seen += len(msg.get("body", b""))
        more = bool(msg.get("more_body", False))


async def _too_large(send: Send, limit: int) -> None:
    body = json.dumps({"detail": f"request body larger than {limit} bytes"}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 413,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


# ----------------------------------------------------------------------------- auth
_bearer = HTTPBearer(auto_error=False, description="radiopose token (`radiopose token create`)")


def _principal(
    request: Request,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    if creds is None or not creds.credentials:
        raise HTTPException(401, "missing bearer token", headers={"WWW-Authenticate": "Bearer"})
    found = request.app.state.db.find_token(hash_token(creds.credentials))
    if found is None:
        raise HTTPException(401, "unknown token", headers={"WWW-Authenticate": "Bearer"})
    return Principal(*found)


def require(*roles: str) -> Callable[..., Principal]:
    """A dependency admitting only ``roles`` (401 without a valid token, 403 otherwise)."""

    def dep(who: Annotated[Principal, Depends(_principal)]) -> Principal:
        if who.role not in roles:
            raise HTTPException(
                403, f"a {who.role} token may not do this (needs {' or '.join(roles)})"
            )
        return who

    return dep


Viewer = Annotated[Principal, Depends(require(*sorted(READ_ROLES)))]
Admin = Annotated[Principal, Depends(require("admin"))]
ReceiverRole = Annotated[Principal, Depends(require("receiver"))]
AnyRole = Annotated[Principal, Depends(require("receiver", "viewer", "admin"))]


# ----------------------------------------------------------------------------- app
def create_app(
    db: Database,
    live: LiveConfig | None = None,
    *,
    run_pipeline: bool = True,
    pipeline_mode: str = "thread",
) -> FastAPI:
    """Build the server app.

    Parameters
    ----------
    db
        The database (the site must already be imported, see :func:`import_site_dir`).
    live
        Live pipeline settings (this process's partition among them).
    run_pipeline
        Start the live pipeline with the app (off: API only, e.g. extra API processes).
    pipeline_mode
        ``"thread"`` or ``"process"`` (see :class:`~radiopose.server.live.LiveWorker`).
    """

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        worker = app.state.worker
        if worker is not None:
            worker.start()
        log.info(
            "server started",
            extra={"db": db.dialect, "partition": (live or LiveConfig()).partition_key},
        )
        try:
            yield
        finally:
            app.state.stopping = True
            if worker is not None:
                await run_in_threadpool(worker.stop)
            log.info("server stopped")

    app = FastAPI(
        title="radiopose live server",
        version="1",
        summary="Receiver reports in, live position and orientation estimates out.",
        lifespan=lifespan,
    )
    app.state.db = db
    app.state.worker = LiveWorker(db, live, pipeline_mode) if run_pipeline else None
    app.state.stopping = False
    app.add_middleware(BodyLimit)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _reject(request, 422, _one_line(exc.errors()))

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> JSONResponse:
        detail = " ".join(str(exc.detail).split())
        resp = _reject(request, exc.status_code, detail)
        for k, v in (exc.headers or {}).items():
            resp.headers[k] = v
        return resp

    @app.exception_handler(InputError)
    async def _input(request: Request, exc: InputError) -> JSONResponse:
        return _reject(request, 422, str(exc))

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        """The dashboard page (static; it asks for a token and reads the API)."""
        return FileResponse(STATIC_DIR / "index.html")

    # ------------------------------------------------------------------ reports
    @app.post(
        f"{API}/reports",
        status_code=201,
        response_model=ReportAck,
        responses={200: {"model": ReportAck, "description": "batch already stored"}},
    )
    def post_reports(batch: ReportBatch, who: ReceiverRole, response: Response) -> ReportAck:
        """Store a batch of one receiver's frame reports (answered once durably stored)."""
        if who.receiver_id != batch.receiver_id:
            raise HTTPException(403, f"this token may post only as receiver {who.receiver_id!r}")
        receivers, transmitters = _known(db)
        if batch.receiver_id not in receivers:
            raise HTTPException(422, f"unknown receiver {batch.receiver_id!r}")
        rows = []
        for i, f in enumerate(batch.frames):
            problem = transmitter_id_problem(f.transmitter)
            if problem:
                raise HTTPException(422, f"frames[{i}]: {problem}")
            mac = canonical_transmitter(f.transmitter)
            if mac not in transmitters:
                raise HTTPException(422, f"frames[{i}]: transmitter {mac} is not enrolled")
            rows.append(
                (round(f.timestamp_s * 1e9), f.frame_sha256.lower(), mac, round(f.rss_dbm, 3))
            )
        rows.sort(key=lambda r: r[0])
        new, _ = db.store_batch(batch.receiver_id, batch.batch_id, rows)
        if new:
            worker = app.state.worker
            if worker is not None:
                worker.wake()
        else:
            response.status_code = 200
        return ReportAck(
            batch_id=batch.batch_id, frames_stored=len(rows) if new else 0, duplicate=not new
        )

    @app.get(f"{API}/transmitters", response_model=list[str])
    def transmitters(who: AnyRole) -> list[str]:
        """Enrolled transmitter addresses (receivers send only these)."""
        return sorted(_known(db)[1])

    # ------------------------------------------------------------------ estimates
    @app.get(
        f"{API}/estimates", response_model=list[FlaggedEstimate], response_model_exclude_none=True
    )
    def estimates(
        who: Viewer,
        transmitter: Annotated[str | None, Query(max_length=64)] = None,
        since_s: Annotated[float | None, Query(allow_inf_nan=False)] = None,
        limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    ) -> list[dict[str, Any]]:
        """Estimates (columns of ``estimates.csv``) in time order; the optional
        uncertainty columns (``position_std_m``, ``azimuth_std_deg``) where the
        method gives them, and ``spoof_alarm_flag`` (1 inside a raised spoofing
        alarm, :mod:`radiopose.server.alarms`)."""
        rows = db.estimates(transmitter, since_s, limit=limit)
        return flag_estimates(rows, db.alarms(transmitter, limit=100_000)) if rows else rows

    add_routes(app, db, require(*sorted(READ_ROLES)))

    @app.get(f"{API}/stream")
    async def stream(
        request: Request, who: Viewer, after_id: Annotated[int | None, Query(ge=0)] = None
    ) -> StreamingResponse:
        """Server-sent events: ``estimates`` (JSON list) as stored, ``health`` every 2 s."""

        async def events() -> AsyncIterator[str]:
            last = after_id
            if last is None:  # start with the most recent trail
                last = max(0, await run_in_threadpool(db.last_estimate_id) - 200)
            next_health = 0.0
            while not app.state.stopping and not await request.is_disconnected():
                rows = await run_in_threadpool(db.estimates, None, None, last, 1_000)
                if rows:
                    last = rows[-1]["id"]
                    yield _sse("estimates", [_public(r) for r in rows])
                if time.monotonic() >= next_health:
                    next_health = time.monotonic() + 2.0
                    yield _sse("health", (await run_in_threadpool(_health, db)).model_dump())
                await asyncio.sleep(0.1)

        return StreamingResponse(
            events(),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
        )

    # ------------------------------------------------------------------ site
    @app.get(f"{API}/site", response_model=SiteOut)
    def site(who: Viewer) -> SiteOut:
        """The site: area, receivers with their orientation, devices, pattern names."""
        return _site_out(db)

    @app.get(f"{API}/patterns/{{name}}", response_class=PlainTextResponse)
    def pattern(name: str, who: Viewer) -> str:
        """A pattern's CSV."""
        csv = db.site_rows()["patterns"].get(name)
        if csv is None:
            raise HTTPException(404, f"unknown pattern {name!r}")
        return csv

    @app.get("/health", response_model=Health)
    def health(who: Viewer) -> Health:
        """Per receiver: last report, frames/s, clock offset and drift; pipeline backlog."""
        return _health(db)

    # ------------------------------------------------------------------ admin
    def _apply(change: Callable[[dict[str, Any]], dict[str, Any]]) -> SiteOut:
        parts = db.site_rows()
        new = change(parts)
        sitestore.build_site(new)  # validates; raises InputError -> 422, nothing changes
        db.replace_site(new)
        log.info("site changed", extra={"version": db.site_version()})
        return _site_out(db)

    @app.put(f"{API}/admin/receivers/{{receiver_id}}", response_model=SiteOut)
    def put_receiver(receiver_id: str, body: ReceiverIn, who: Admin) -> SiteOut:
        """Add or replace a receiver (its survey rows must exist)."""
        _check_id(receiver_id)

        def change(p: dict[str, Any]) -> dict[str, Any]:
            rx = [r for r in p["receivers"] if r["receiver_id"] != receiver_id]
            rx.append({"receiver_id": receiver_id, **body.model_dump()})
            order = (
                p["order"]
                if receiver_id in p["order"].split(",")
                else (f"{p['order']},{receiver_id}".strip(","))
            )
            return sitestore.edited(p, receivers=rx, order=order)

        return _apply(change)

    @app.delete(f"{API}/admin/receivers/{{receiver_id}}", response_model=SiteOut)
    def delete_receiver(receiver_id: str, who: Admin) -> SiteOut:
        """Remove a receiver (and its survey rows)."""

        def change(p: dict[str, Any]) -> dict[str, Any]:
            if all(r["receiver_id"] != receiver_id for r in p["receivers"]):
                raise HTTPException(404, f"unknown receiver {receiver_id!r}")
            rx = [r for r in p["receivers"] if r["receiver_id"] != receiver_id]
            files = dict(p["files"])
            files["survey.csv"] = _drop_survey_rows(files["survey.csv"], receiver_id)
            return sitestore.edited(p, receivers=rx, files=files)

        return _apply(change)

    @app.put(f"{API}/admin/devices/{{transmitter}}", response_model=SiteOut)
    def put_device(transmitter: str, body: DeviceIn, who: Admin) -> SiteOut:
        """Enrol or update a device."""
        problem = transmitter_id_problem(transmitter)
        if problem:
            raise HTTPException(422, problem)
        tx = canonical_transmitter(transmitter)

        def change(p: dict[str, Any]) -> dict[str, Any]:
            dev = [d for d in p["devices"] if d["transmitter"].lower() != tx]
            dev.append({"transmitter": tx, **body.model_dump()})
            return sitestore.edited(p, devices=dev)

        return _apply(change)

    @app.delete(f"{API}/admin/devices/{{transmitter}}", response_model=SiteOut)
    def delete_device(transmitter: str, who: Admin) -> SiteOut:
        """Remove an enrolled device."""
        tx = canonical_transmitter(transmitter)

        def change(p: dict[str, Any]) -> dict[str, Any]:
            dev = [d for d in p["devices"] if d["transmitter"].lower() != tx]
            if len(dev) == len(p["devices"]):
                raise HTTPException(404, f"unknown device {transmitter!r}")
            return sitestore.edited(p, devices=dev)

        return _apply(change)

    @app.put(f"{API}/admin/patterns/{{name}}", response_model=SiteOut)
    def put_pattern(name: str, body: CsvIn, who: Admin) -> SiteOut:
        """Add or replace a pattern (CSV text of ``patterns/<name>.csv``)."""
        _check_id(name)

        def change(p: dict[str, Any]) -> dict[str, Any]:
            return sitestore.edited(p, patterns={**p["patterns"], name: body.csv})

        return _apply(change)

    @app.delete(f"{API}/admin/patterns/{{name}}", response_model=SiteOut)
    def delete_pattern(name: str, who: Admin) -> SiteOut:
        """Remove a pattern (rejected while something uses it)."""

        def change(p: dict[str, Any]) -> dict[str, Any]:
            if name not in p["patterns"]:
                raise HTTPException(404, f"unknown pattern {name!r}")
            return sitestore.edited(
                p, patterns={k: v for k, v in p["patterns"].items() if k != name}
            )

        return _apply(change)

    @app.put(f"{API}/admin/survey", response_model=SiteOut)
    def put_survey(body: CsvIn, who: Admin) -> SiteOut:
        """Replace ``survey.csv``."""

        def change(p: dict[str, Any]) -> dict[str, Any]:
            return sitestore.edited(p, files={**p["files"], "survey.csv": body.csv})

        return _apply(change)

    return app


# ----------------------------------------------------------------------------- helpers
def _reject(request: Request, status: int, detail: str) -> JSONResponse:
    log.info("rejected", extra={"status": status, "path": request.url.path, "detail": detail})
    return JSONResponse({"detail": detail}, status_code=status)


def _one_line(errors: Any) -> str:
    errs = list(errors)
    if not errs:
        return "invalid request"
    e = errs[0]
    loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body") or "body"
    msg = " ".join(str(e.get("msg", "invalid")).split())
    more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
    return f"{loc}: {msg}{more}"[:300]


def _check_id(value: str) -> None:
    if not (0 < len(value) <= 64) or any(c in value for c in ",/\\") or not value.isprintable():
        raise HTTPException(
            422, f"{value[:70]!r} is not a valid id (1-64 printable characters, no comma or slash)"
        )


def _known(db: Database) -> tuple[set[str], set[str]]:
    receivers, transmitters = db.known_ids()
    return set(receivers), {canonical_transmitter(t) for t in transmitters}


def _drop_survey_rows(csv_text: str, receiver_id: str) -> str:
    import csv
    import io

    src = io.StringIO(csv_text)
    reader = csv.reader(src)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = next(reader, None)
    if header is None:
        return csv_text
    writer.writerow(header)
    col = header.index("receiver_id") if "receiver_id" in header else None
    for row in reader:
        if col is None or col >= len(row) or row[col].strip() != receiver_id:
            writer.writerow(row)
    return out.getvalue()


def _public(row: dict[str, Any]) -> dict[str, Any]:
    """An estimate's JSON object: the contract columns, and the optional ones when set."""
    return {k: row[k] for k in Estimate.model_fields if row.get(k) is not None}


def _sse(event: str, data: Any) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


def _site_out(db: Database) -> SiteOut:
    parts = db.site_rows()
    site = sitestore.build_site(parts)
    # each schema's fields are read from the same-named attributes of the site's objects
    return SiteOut(
        name=site.name,
        version=db.site_version(),
        area=Area.model_validate(site.area, from_attributes=True),
        receivers=[ReceiverOut.model_validate(r, from_attributes=True) for r in site.receivers],
        devices=[DeviceOut.model_validate(d, from_attributes=True) for d in site.devices],
        patterns=sorted(site.patterns),
    )


def _health(db: Database) -> Health:
    now = time.time()
    activity = db.receiver_activity(10.0)
    summaries = db.summaries()
    clocks: dict[str, dict[str, Any]] = {}
    for s in summaries.values():
        clocks.update(s.get("clocks", {}))
    ids = list(db.known_ids()[0])
    ids += sorted(set(activity) - set(ids))
    receivers = []
    for rid in ids:
        a = activity.get(rid)
        c = clocks.get(rid)
        estimated = c is not None and c.get("method") != "none"
        receivers.append(
            ReceiverHealth(
                receiver_id=rid,
                last_report_s=None if a is None else a["last_report_s"],
                seconds_since_report=None if a is None else max(0.0, now - a["last_report_s"]),
                frames_per_s=0.0 if a is None else a["frames_per_s"],
                clock_offset_s=c["offset_s"] if c is not None and estimated else None,
                clock_drift_ppm=c["drift_ppm"] if c is not None and estimated else None,
                clock_method=None if c is None else c.get("method"),
            )
        )
    last = db.last_batch_id()
    cursor = min((s["cursor_batch"] for s in summaries.values()), default=0)
    lat = db.recent_latencies_s(1_000)
    pct = lambda q: float(np.percentile(lat, q)) if lat else None  # noqa: E731
    return Health(
        status="ok",
        site_version=db.site_version(),
        batches_stored=last,
        backlog_batches=max(0, last - cursor),
        partitions={
            k: {kk: v for kk, v in s.items() if kk != "clocks"} for k, s in summaries.items()
        },
        receivers=receivers,
        latency_s={"p50": pct(50), "p95": pct(95), "n": float(len(lat))},
    )
