"""The server's API routes, one module per area.

:mod:`.reports` (receivers post frames), :mod:`.estimates` (estimates, alarms,
the event stream), :mod:`.site` (site, patterns, health) and :mod:`.admin`
(site edits). Each module's endpoints are plain functions whose dependencies
(database, roles) come from :mod:`radiopose.server.deps`; its ``add_routes``
adds them to :func:`radiopose.server.app.create_app`'s router. They are added
to the app's own router rather than through ``include_router``: FastAPI
0.165 keeps an included router as one nested route object, so ``app.routes``
would no longer list each route with its path (the server's tests walk it to
check that every route needs a token).
"""

from collections.abc import Callable

from fastapi import APIRouter

from radiopose.server.routers import admin, estimates, reports, site

ADD_ROUTES: tuple[Callable[[APIRouter], None], ...] = (
    reports.add_routes,
    estimates.add_routes,
    site.add_routes,
    admin.add_routes,
)
"""Every area's ``add_routes``, in the order the app adds them."""

__all__ = ["ADD_ROUTES"]
