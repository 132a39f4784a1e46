"""FastAPI dependencies of the server's routers: the database and the caller's role.

Everything comes from the request's app (``request.app.state``, set by
:func:`radiopose.server.app.create_app`), so the routers hold no state and
several apps never share any. Missing or unknown token: 401; wrong role: 403.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from radiopose.server.auth import READ_ROLES, Principal, hash_token
from radiopose.server.db import Database
from radiopose.server.worker import LiveWorker

API = "/api/v1"
"""Path prefix of version 1 of the API."""


def get_db(request: Request) -> Database:
    """The app's database."""
    db: Database = request.app.state.db
    return db


def get_worker(request: Request) -> LiveWorker | None:
    """The app's live pipeline, or ``None`` when this process runs the API only."""
    worker: LiveWorker | None = request.app.state.worker
    return worker


DB = Annotated[Database, Depends(get_db)]
Worker = Annotated[LiveWorker | None, Depends(get_worker)]

_bearer = HTTPBearer(auto_error=False, description="radiopose token (`radiopose token create`)")


def _principal(
    db: DB,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    if creds is None or not creds.credentials:
        raise HTTPException(401, "missing bearer token", headers={"WWW-Authenticate": "Bearer"})
    found = db.find_token(hash_token(creds.credentials))
    if found is None:
        raise HTTPException(401, "unknown token", headers={"WWW-Authenticate": "Bearer"})
    return Principal(*found)


def require(*roles: str) -> Callable[..., Principal]:
    """A dependency admitting only ``roles`` (401 without a valid token, 403 otherwise)."""

    def dep(who: Annotated[Principal, Depends(_principal)]) -> Principal:
        if who.role not in roles:
            raise HTTPException(
                403,
                f"{_article(who.role)} {who.role} token may not do this "
                f"(needs {' or '.join(roles)})",
            )
        return who

    return dep


Viewer = Annotated[Principal, Depends(require(*sorted(READ_ROLES)))]
Admin = Annotated[Principal, Depends(require("admin"))]
ReceiverRole = Annotated[Principal, Depends(require("receiver"))]
AnyRole = Annotated[Principal, Depends(require("receiver", "viewer", "admin"))]


def _article(word: str) -> str:
    """``a`` or ``an`` before ``word`` (a role name)."""
    return "an" if word[:1].lower() in "aeiou" else "a"
