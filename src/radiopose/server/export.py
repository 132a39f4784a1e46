"""Export a live run for replay: the site, raw frames, packets and estimates.

``radiopose db export --db URL -o DIR`` writes

* ``DIR/site/`` — the stored site (contract layout);
* ``DIR/frames.csv`` — every stored frame report, CSV capture form
  (``receiver_id, timestamp_s, frame_sha256, transmitter, rss_dbm``): feed
  it to ``radiopose sync`` to re-synchronise from scratch;
* ``DIR/packets.csv`` — the packets the live matcher formed, in the order
  the tracker saw them;
* ``DIR/estimates.csv`` — the live estimates.

``radiopose locate DIR/site DIR/packets.csv -o E.csv`` reproduces
``DIR/estimates.csv`` exactly (same method and settings, and no site edit
during the run). Packets the live tracker skipped as out of time order are
left out of ``packets.csv`` (``locate`` rejects such a table; live they had
no estimate either).
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from radiopose.estimates import Estimates, PoseEstimate, write_estimates_csv
from radiopose.packets import Packets, write_packets_csv
from radiopose.server.db import Database
from radiopose.server.sitestore import export_site
from radiopose.tables import atomic_writer, format_float


def export_run(db: Database, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write the export (see module docstring); return the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    site_dir = export_site(db.site_rows(), out / "site")

    frames_path = out / "frames.csv"
    with atomic_writer(frames_path) as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["receiver_id", "timestamp_s", "frame_sha256", "transmitter", "rss_dbm"])
        for chunk in db.iter_frames():
            for rid, t_ns, sha, tx, rss in chunk:
                w.writerow(
                    [
                        rid,
                        f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}",
                        sha,
                        tx,
                        format_float(rss, 3),
                    ]
                )

    from radiopose.tracker import SKIP_OUT_OF_ORDER

    rows = [p for p in db.packets() if p["reason"] != SKIP_OUT_OF_ORDER]
    ids, times, txs, rxs, rss = [], [], [], [], []
    for p in rows:
        for rid, value in zip(p["receiver_ids"], p["rss_dbm"], strict=True):
            ids.append(p["packet_id"])
            times.append(p["timestamp_s"])
            txs.append(p["transmitter"])
            rxs.append(rid)
            rss.append(value)
    obj = lambda v: np.asarray(v, dtype=object).reshape(len(v))  # noqa: E731
    packets_path = out / "packets.csv"
    write_packets_csv(
        Packets(obj(ids), np.asarray(times, float), obj(txs), obj(rxs), np.asarray(rss, float)),
        packets_path,
    )

    est = db.estimates(after_id=0, limit=10**9)
    poses = [
        PoseEstimate(
            e["timestamp_s"],
            e["transmitter"],
            e["packet_id"],
            (e["x_m"], e["y_m"], e["z_m"]),
            (e["azimuth_deg"], e["pitch_deg"], e["roll_deg"]),
            e["method"],
            math.nan if e["position_std_m"] is None else e["position_std_m"],
            math.nan if e["azimuth_std_deg"] is None else e["azimuth_std_deg"],
        )
        for e in est
    ]
    estimates_path = out / "estimates.csv"
    write_estimates_csv(Estimates.from_poses(poses), estimates_path)
    return [site_dir, frames_path, packets_path, estimates_path]
