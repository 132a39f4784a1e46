"""Site edits by an admin: ``PUT``/``DELETE`` under ``/api/v1/admin``.

Every edit builds the whole new site and validates it before storing it
(:func:`radiopose.server.sitestore.build_site`): a bad edit is a 422 and
changes nothing. Each answer is the new site.
"""

from __future__ import annotations

import csv
import io
import logging
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, HTTPException

from radiopose.capture.records import canonical_transmitter, transmitter_id_problem
from radiopose.ids import receiver_id_problem
from radiopose.server import sitestore
from radiopose.server.db import Database
from radiopose.server.deps import API, DB, Admin
from radiopose.server.routers.site import site_out
from radiopose.server.schemas import CsvIn, DeviceIn, ReceiverIn, SiteOut

log = logging.getLogger("radiopose.server")


def add_routes(router: APIRouter) -> None:
    """Add this module's routes to ``router`` (the app's own, so they stay flat).

    Receiver and transmitter ids are path parameters that may hold ``/`` (an id
    is any string without commas or whitespace: the contract), sent as is or
    as ``%2F``."""
    router.add_api_route(
        f"{API}/admin/receivers/{{receiver_id:path}}",
        put_receiver,
        methods=["PUT"],
        response_model=SiteOut,
    )
    router.add_api_route(
        f"{API}/admin/receivers/{{receiver_id:path}}",
        delete_receiver,
        methods=["DELETE"],
        response_model=SiteOut,
    )
    router.add_api_route(
        f"{API}/admin/devices/{{transmitter:path}}",
        put_device,
        methods=["PUT"],
        response_model=SiteOut,
    )
    router.add_api_route(
        f"{API}/admin/devices/{{transmitter:path}}",
        delete_device,
        methods=["DELETE"],
        response_model=SiteOut,
    )
    router.add_api_route(
        f"{API}/admin/patterns/{{name}}", put_pattern, methods=["PUT"], response_model=SiteOut
    )
    router.add_api_route(
        f"{API}/admin/patterns/{{name}}", delete_pattern, methods=["DELETE"], response_model=SiteOut
    )
    router.add_api_route(f"{API}/admin/survey", put_survey, methods=["PUT"], response_model=SiteOut)


def _apply(db: Database, change: Callable[[dict[str, Any]], dict[str, Any]]) -> SiteOut:
    parts = db.site_rows()
    new = change(parts)
    sitestore.build_site(new)  # validates; raises InputError -> 422, nothing changes
    db.replace_site(new)
    log.info("site changed", extra={"version": db.site_version()})
    return site_out(db)


def put_receiver(receiver_id: str, body: ReceiverIn, who: Admin, db: DB) -> SiteOut:
    """Add or replace a receiver (its survey rows must exist)."""
    if (problem := receiver_id_problem(receiver_id)) is not None:
        raise HTTPException(422, problem)

    def change(p: dict[str, Any]) -> dict[str, Any]:
        rx = [r for r in p["receivers"] if r["receiver_id"] != receiver_id]
        rx.append({"receiver_id": receiver_id, **body.model_dump()})
        order = (
            p["order"]
            if receiver_id in p["order"].split(",")
            else (f"{p['order']},{receiver_id}".strip(","))
        )
        return sitestore.edited(p, receivers=rx, order=order)

    return _apply(db, change)


def delete_receiver(receiver_id: str, who: Admin, db: DB) -> SiteOut:
    """Remove a receiver (and its survey rows)."""

    def change(p: dict[str, Any]) -> dict[str, Any]:
        if all(r["receiver_id"] != receiver_id for r in p["receivers"]):
            raise HTTPException(404, f"unknown receiver {receiver_id!r}")
        rx = [r for r in p["receivers"] if r["receiver_id"] != receiver_id]
        files = dict(p["files"])
        files["survey.csv"] = _drop_survey_rows(files["survey.csv"], receiver_id)
        return sitestore.edited(p, receivers=rx, files=files)

    return _apply(db, change)


def put_device(transmitter: str, body: DeviceIn, who: Admin, db: DB) -> SiteOut:
    """Enrol or update a device."""
    problem = transmitter_id_problem(transmitter)
    if problem:
        raise HTTPException(422, problem)
    tx = canonical_transmitter(transmitter)

    def change(p: dict[str, Any]) -> dict[str, Any]:
        dev = [d for d in p["devices"] if d["transmitter"].lower() != tx]
        dev.append({"transmitter": tx, **body.model_dump()})
        return sitestore.edited(p, devices=dev)

    return _apply(db, change)


def delete_device(transmitter: str, who: Admin, db: DB) -> SiteOut:
    """Remove an enrolled device."""
    tx = canonical_transmitter(transmitter)

    def change(p: dict[str, Any]) -> dict[str, Any]:
        dev = [d for d in p["devices"] if d["transmitter"].lower() != tx]
        if len(dev) == len(p["devices"]):
            raise HTTPException(404, f"unknown device {transmitter!r}")
        return sitestore.edited(p, devices=dev)

    return _apply(db, change)


def put_pattern(name: str, body: CsvIn, who: Admin, db: DB) -> SiteOut:
    """Add or replace a pattern (CSV text of ``patterns/<name>.csv``), validated
    as a pattern file even while nothing uses it."""
    _check_pattern_name(name)
    sitestore.check_pattern_csv(name, body.csv)

    def change(p: dict[str, Any]) -> dict[str, Any]:
        return sitestore.edited(p, patterns={**p["patterns"], name: body.csv})

    return _apply(db, change)


def delete_pattern(name: str, who: Admin, db: DB) -> SiteOut:
    """Remove a pattern (rejected while something uses it)."""

    def change(p: dict[str, Any]) -> dict[str, Any]:
        if name not in p["patterns"]:
            raise HTTPException(404, f"unknown pattern {name!r}")
        return sitestore.edited(p, patterns={k: v for k, v in p["patterns"].items() if k != name})

    return _apply(db, change)


def put_survey(body: CsvIn, who: Admin, db: DB) -> SiteOut:
    """Replace ``survey.csv``."""

    def change(p: dict[str, Any]) -> dict[str, Any]:
        return sitestore.edited(p, files={**p["files"], "survey.csv": body.csv})

    return _apply(db, change)


def _check_pattern_name(value: str) -> None:
    if not (0 < len(value) <= 64) or any(c in value for c in ",/\\") or not value.isprintable():
        raise HTTPException(
            422,
            f"{value[:70]!r} is not a valid pattern name (1-64 printable characters, no "
            "comma or slash: it names a file)",
        )


def _drop_survey_rows(csv_text: str, receiver_id: str) -> str:
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
