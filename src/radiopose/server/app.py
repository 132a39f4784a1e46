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

The routes live in :mod:`radiopose.server.routers` (one router per area), their
dependencies (database, roles) in :mod:`radiopose.server.deps` and the body
limit in :mod:`radiopose.server.middleware`; this module assembles the app.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from radiopose.errors import InputError
from radiopose.server import sitestore
from radiopose.server.db import Database
from radiopose.server.deps import API, Admin, AnyRole, ReceiverRole, Viewer, require
from radiopose.server.live import LiveConfig
from radiopose.server.middleware import DRAIN_CAP_BYTES, BodyLimit
from radiopose.server.routers import ADD_ROUTES
from radiopose.server.worker import LiveWorker

__all__ = [
    "API",
    "DRAIN_CAP_BYTES",
    "STATIC_DIR",
    "Admin",
    "AnyRole",
    "BodyLimit",
    "ReceiverRole",
    "Viewer",
    "create_app",
    "import_site_dir",
    "require",
]

log = logging.getLogger("radiopose.server")
STATIC_DIR = Path(__file__).with_name("static")


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
        ``"thread"`` or ``"process"`` (see :class:`~radiopose.server.worker.LiveWorker`).
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

    for add_routes in ADD_ROUTES:
        add_routes(app.router)
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
