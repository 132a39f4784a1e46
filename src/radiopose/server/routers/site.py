"""The site and the server's health: ``GET /api/v1/site``, ``/patterns/{name}``, ``/health``."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException
from fastapi.responses import PlainTextResponse

from radiopose.server import sitestore
from radiopose.server.db import Database
from radiopose.server.deps import API, DB, Viewer
from radiopose.server.schemas import Area, DeviceOut, Health, ReceiverHealth, ReceiverOut, SiteOut


def add_routes(router: APIRouter) -> None:
    """Add this module's routes to ``router`` (the app's own, so they stay flat)."""
    router.add_api_route(f"{API}/site", site, methods=["GET"], response_model=SiteOut)
    router.add_api_route(
        f"{API}/patterns/{{name}}", pattern, methods=["GET"], response_class=PlainTextResponse
    )
    router.add_api_route("/health", health, methods=["GET"], response_model=Health)


def site(who: Viewer, db: DB) -> SiteOut:
    """The site: area, receivers with their orientation, devices, pattern names."""
    return site_out(db)


def pattern(name: str, who: Viewer, db: DB) -> str:
    """A pattern's CSV."""
    csv = db.site_rows()["patterns"].get(name)
    if csv is None:
        raise HTTPException(404, f"unknown pattern {name!r}")
    return csv


def health(who: Viewer, db: DB) -> Health:
    """Per receiver: last report, frames/s, clock offset and drift; pipeline backlog."""
    return health_of(db)


def site_out(db: Database) -> SiteOut:
    """The stored site as the API shows it (also the answer of every admin edit)."""
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


def health_of(db: Database) -> Health:
    """Per receiver activity and clock, the pipeline's backlog and latency, now."""
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

    # The partitions of the current partitioning (that of the partition updated
    # last): a run's rows of an earlier "k/N" stay in the table but no longer run.
    def partitioning(key: str) -> str:  # "k/N" -> "N"
        return key.rpartition("/")[2]

    current = max(summaries.items(), key=lambda kv: kv[1].get("updated_s", 0.0), default=None)
    n_parts = None if current is None else partitioning(current[0])
    live = {k: v for k, v in summaries.items() if partitioning(k) == n_parts}
    # (a lagged method commits output ahead of its checkpoint: the summary's cursor)
    cursor = min((s.get("cursor", s["cursor_batch"]) for s in live.values()), default=0)
    lat = db.recent_latencies_s(1_000)
    pct = lambda q: float(np.percentile(lat, q)) if lat else None  # noqa: E731
    # a failure newer than the partition's last commit: the pipeline is stuck or retrying
    # (of the current partitioning: an earlier one's partitions no longer run)
    failing = {
        k: e
        for k, e in db.pipeline_errors().items()
        if e["at_s"] > summaries.get(k, {}).get("updated_s", 0.0)
        and (n_parts is None or partitioning(k) == n_parts)
    }
    return Health(
        status="degraded" if failing else "ok",
        pipeline_errors=failing,
        site_version=db.site_version(),
        batches_stored=last,
        backlog_batches=max(0, last - cursor),
        partitions={
            k: {kk: v for kk, v in s.items() if kk != "clocks"} for k, s in summaries.items()
        },
        receivers=receivers,
        latency_s={"p50": pct(50), "p95": pct(95), "n": float(len(lat))},
    )
