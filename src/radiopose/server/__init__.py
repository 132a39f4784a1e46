"""The live system's central server (``radiopose serve``).

Modules, in the order a report travels: :mod:`~radiopose.server.schemas`
(request bodies and limits), :mod:`~radiopose.server.auth` (bearer tokens
and roles), :mod:`~radiopose.server.db` (SQLAlchemy models and repository),
:mod:`~radiopose.server.sitestore` (the site in the database),
:mod:`~radiopose.server.live` (matcher and tracker pipeline),
:mod:`~radiopose.server.app` (the FastAPI app), :mod:`~radiopose.server.export`
(replayable export), :mod:`~radiopose.server.demo` (``radiopose demo --live``)
and ``static/`` (the dashboard). Its dependencies (FastAPI, uvicorn,
SQLAlchemy, httpx) are part of the core install. See ``docs/server.md``.
"""
