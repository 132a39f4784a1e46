"""The live server at a 3-D site (``radiopose simulate --pose 3d``; docs/pose3d.md, "Live").

* receivers reporting the simulated hand-held phone's frames over HTTP give
  estimates with height, pitch and roll through ``GET /api/v1/estimates``, the
  same values are stored in the database, every packet is answered, and the
  export replays exactly with ``locate`` and the live lag (the site's height
  range and pitch/roll lists survive the database);
* the dashboard's transmitter table shows the height, pitch and roll (headless
  Chromium, as ``test_server_dashboard``);
* a pipeline restarted half-way from its checkpoint (the 3-D filter's particles,
  random state and smoother lineage pickled in ``PipelineState``) stores exactly
  the estimates of a pipeline that never stopped, each once.

Seed 18118 is used here only.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from radiopose.capture.records import FrameRecords, read_pcap
from radiopose.capture.writer import write_receiver_pcaps
from radiopose.estimates import write_estimates_csv
from radiopose.packets import read_packets_csv
from radiopose.server.app import import_site_dir
from radiopose.server.auth import create_token
from radiopose.server.db import Database
from radiopose.server.export import export_run
from radiopose.server.live import LiveConfig, LivePipeline
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.site import load_site, site_is_3d
from radiopose.tracker import TrackerConfig, locate
from server_support import db_url, fast_live, frame_dicts, pg_server, run_server, wait_for
from test_server_dashboard import page  # the headless browser (skips without one)

LAG_S = 0.25
SCENE = HandheldConfig(
    size_m=6.0, step_m=0.5, n_receivers=6, duration_s=2.0, interval_ms=20.0, noise_db=1.0,
    min_receiver_spacing_m=2.0, survey_step_m=1.0,
)  # fmt: skip


@dataclass(frozen=True)
class Site3d:
    root: Path
    site_dir: Path
    frames: dict[str, FrameRecords]
    receivers: tuple[str, ...]
    transmitter: str
    n_packets: int


@pytest.fixture(scope="module")
def site3d(tmp_path_factory: pytest.TempPathFactory) -> Site3d:
    root = tmp_path_factory.mktemp("site3d")
    sim = simulate_handheld(SCENE, seed=18118)
    sim.write(root)
    assert site_is_3d(load_site(root / "site"))
    pc = write_receiver_pcaps(
        sim.packets, root / "pcaps", rng=np.random.default_rng(18118),
        clock_offset_s={"rx2": 0.2, "rx5": -0.2}, jitter_s=2e-6, epoch_s=1000.0,
    )  # fmt: skip
    frames = {r: read_pcap(p, r).frames for r, p in pc.paths.items()}
    return Site3d(root, root / "site", frames, tuple(sim.site.receiver_ids),
                  str(sim.packets.transmitter[0]), len(set(sim.packets.packet_id)))  # fmt: skip


def _batches(s: Site3d, per_batch: int):  # type: ignore[no-untyped-def]
    """``(receiver, batch id, frames)`` of every receiver, receivers interleaved in time."""
    chunks = {r: list(range(0, len(s.frames[r]), per_batch)) for r in s.receivers}
    for i in range(max(len(c) for c in chunks.values())):
        for r in s.receivers:
            if i < len(chunks[r]):
                yield r, f"{r}-{i}", s.frames[r].take(slice(chunks[r][i], chunks[r][i] + per_batch))


POSE_KEYS = ("x_m", "y_m", "z_m", "azimuth_deg", "pitch_deg", "roll_deg")


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_live_filter_at_a_3d_site(site3d: Site3d, db_url: str, tmp_path: Path) -> None:
    db = Database(db_url)
    import_site_dir(db, site3d.site_dir)
    tokens = {r: create_token(db, "receiver", r) for r in site3d.receivers}
    viewer = create_token(db, "viewer")
    # no method chosen: at a 3-D site the live default is filter (the paper's
    # methods search every candidate per packet: far too slow live there)
    assert LiveConfig().method_for(load_site(site3d.site_dir)) == "filter"
    with run_server(db, fast_live(live_lag_s=LAG_S)) as srv:
        clients = {r: srv.client(tokens[r]) for r in site3d.receivers}
        for r, bid, f in _batches(site3d, 20):
            body = {"receiver_id": r, "batch_id": bid, "frames": frame_dicts(f)}
            assert clients[r].post("/api/v1/reports", json=body).status_code < 300
        wait_for(lambda: len(db.packets()) == site3d.n_packets, 120)
        wait_for(lambda: len(db.estimates(limit=10**6)) == site3d.n_packets, 120)
        live = (
            srv.client(viewer)
            .get("/api/v1/estimates", params={"transmitter": site3d.transmitter})
            .json()
        )
    assert len(live) == site3d.n_packets and {e["method"] for e in live} == {"filter"}
    assert all(len(p["receiver_ids"]) == 6 and p["reason"] is None for p in db.packets())
    # the pose is 3-D: heights inside the site's range and varying, the phone tilted
    z = np.array([e["z_m"] for e in live])
    pitch = np.array([e["pitch_deg"] for e in live])
    roll = np.array([e["roll_deg"] for e in live])
    assert z.min() >= SCENE.z_min_m - 1e-9 and z.max() <= SCENE.z_max_m + 1e-9
    assert np.ptp(z) > 0.01 and np.ptp(pitch) > 0.1 and np.ptp(roll) > 0.1
    assert np.mean(pitch) > 10.0  # held tilted toward the face (20–70°), not flat
    # what the API serves is what is stored
    stored = {e["packet_id"]: e for e in db.estimates(limit=10**6)}
    for e in live:
        assert tuple(e[k] for k in POSE_KEYS) == tuple(stored[e["packet_id"]][k] for k in POSE_KEYS)
    # the export (the site's height range and pitch/roll lists included) replays exactly
    site_dir, _frames, packets_csv, estimates_csv = export_run(db, tmp_path / "export")
    assert site_is_3d(load_site(site_dir))
    # (without the offline batch refinement, which the live filter never runs)
    replay = TrackerConfig(smoothing_lag_s=LAG_S)
    replay = replace(replay, pose3d=replace(replay.pose3d, refine=False))
    again = locate(load_site(site_dir), read_packets_csv(packets_csv), "filter", replay)
    write_estimates_csv(again.estimates, tmp_path / "relocated.csv")
    assert (tmp_path / "relocated.csv").read_bytes() == estimates_csv.read_bytes()
    db.close()


def _store(db: Database, s: Site3d) -> int:
    n = 0
    for r, bid, f in _batches(s, 10):
        rows = list(zip(f.timestamp_ns.tolist(), f.frame_sha256, f.transmitter,
                        f.rss_dbm.tolist(), strict=True))  # fmt: skip
        db.store_batch(r, bid, rows)
        n += 1
    return n


@pytest.mark.parametrize("checkpoint_s", [0.0, 1e9])
def test_a_restart_half_way_gives_the_same_estimates(
    site3d: Site3d, tmp_path: Path, checkpoint_s: float
) -> None:
    """Restarted from its checkpoint half-way (lagged commits, so output after the
    checkpoint is re-derived), the pipeline stores the same 3-D estimates, each
    once: with a checkpoint at every commit, and with only the first one (the
    output committed ahead of the checkpoint is re-derived and kept once)."""
    cfg = fast_live(
        method="filter", live_lag_s=LAG_S, batches_per_step=6, idle_flush_s=1e6,
        lagged_commit_s=0.1, lagged_checkpoint_s=checkpoint_s,
    )  # fmt: skip

    def run(name: str, restart: bool) -> list[tuple[object, ...]]:
        db = Database(f"sqlite:///{tmp_path / name}")
        import_site_dir(db, site3d.site_dir)
        n = _store(db, site3d)
        p = LivePipeline(db, cfg)
        redone = 0
        while p.state.cursor < n:
            # (with checkpoints only at the first commit the restart goes back to it)
            if restart and (p._committed_cursor if checkpoint_s == 0 else p.state.cursor) >= n // 2:
                p._last_commit_s = math.inf  # one more step whose output the crash loses
                p.step()
                redone = p.state.cursor - p._committed_cursor
                p, restart = LivePipeline(db, cfg), False  # a restart: the checkpoint
                assert 0 < p.state.cursor < n  # resumes, not afresh
                assert p.state.track_states or checkpoint_s > 0
            p.step()
        p.config = fast_live(
            method="filter", live_lag_s=LAG_S, idle_flush_s=0.0, lagged_checkpoint_s=checkpoint_s
        )
        end = time.monotonic() + 60
        while len(db.estimates(limit=10**6)) < site3d.n_packets and time.monotonic() < end:
            p.step()  # the idle flush emits the held-back estimates; then the commit
            time.sleep(0.05)
        rows = [
            (e["packet_id"], *(e[k] for k in POSE_KEYS), e["position_std_m"], e["azimuth_std_deg"])
            for e in db.estimates(limit=10**6)
        ]
        db.close()
        redos.append(redone)
        return rows

    redos: list[int] = []
    straight = run("a.db", False)
    restarted = run("b.db", True)
    assert len(straight) == site3d.n_packets
    assert len({r[0] for r in restarted}) == len(restarted)  # nothing twice
    assert sorted(restarted) == sorted(straight)
    assert redos[1] > 0  # the restart did re-derive batches processed but not committed


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_dashboard_shows_height_pitch_and_roll(site3d: Site3d, db_url: str, page) -> None:
    """The dashboard's transmitter table gives the full pose of the latest estimate."""
    db = Database(db_url)
    import_site_dir(db, site3d.site_dir)
    tokens = {r: create_token(db, "receiver", r) for r in site3d.receivers}
    viewer = create_token(db, "viewer")
    with run_server(db, fast_live(method="filter", live_lag_s=LAG_S)) as srv:
        page.goto(f"{srv.url}/#token={viewer}")
        page.wait_for_function("document.body.dataset.receivers === '6'", timeout=30_000)
        clients = {r: srv.client(tokens[r]) for r in site3d.receivers}
        for r, bid, f in _batches(site3d, 20):
            body = {"receiver_id": r, "batch_id": bid, "frames": frame_dicts(f)}
            assert clients[r].post("/api/v1/reports", json=body).status_code < 300
        wait_for(lambda: len(db.estimates(limit=10**6)) == site3d.n_packets, 120)
        page.wait_for_function(
            f"Number(document.body.dataset.moves || 0) >= {site3d.n_packets}", timeout=30_000
        )
        page.wait_for_timeout(1500)  # the table is redrawn on a timer
        last = page.evaluate("[...window.radiopose.tracks.values()][0].trail.slice(-1)[0]")
        cells = page.locator("#tx-table tbody tr").first.locator("td").all_inner_texts()
        heads = page.locator("#tx-table thead th").all_inner_texts()
    db.close()
    assert heads[1:3] == ["x, y, z (m)", "azimuth, pitch, roll"]
    assert cells[1] == f"{last['x_m']:.2f}, {last['y_m']:.2f}, {last['z_m']:.2f}"
    angles = [float(a.strip().rstrip("°")) for a in cells[2].split(",")]
    expect = [last["azimuth_deg"], last["pitch_deg"], last["roll_deg"]]
    assert angles == pytest.approx(expect, abs=0.5)
    assert last["z_m"] != SCENE.z_min_m and angles[1] != 0.0  # a 3-D pose, not the 2-D defaults


def test_a_site_change_from_3d_to_2d_turns_the_default_method_and_its_alarms(
    site3d: Site3d, tmp_path: Path
) -> None:
    """With no method chosen the live method follows the site: filter (and its
    spoofing alarm monitor) at the 3-D site, then full with no monitor once the
    stored site is 2-D (the old site's monitor once stayed on, fed full's
    estimates against the old receivers)."""
    from radiopose.simulate import ScenarioConfig, simulate

    simulate(ScenarioConfig(size_m=6.0, step_m=0.5, duration_s=0.05), seed=2).write(tmp_path / "s2")
    db = Database(f"sqlite:///{tmp_path / 'db.sqlite'}")
    import_site_dir(db, site3d.site_dir)
    p = LivePipeline(db, LiveConfig())
    p._refresh_site()
    assert p.tracker is not None and p.tracker.method == "filter"
    assert p.alarm_monitor is not None and len(p.alarm_monitor.site.receiver_ids) == 6
    import_site_dir(db, tmp_path / "s2" / "site")
    p._refresh_site()
    assert p.tracker.method == "full" and p.alarm_monitor is None and not p.state.pending_obs


def test_serve_without_a_method_leaves_it_to_the_stored_site(
    site3d: Site3d,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``radiopose serve SITE`` with no ``--method`` (and no ``live_method`` in
    tracker.toml) hands the live pipeline no method, so the default follows the
    stored site through admin edits; it once fixed the directory's default at
    start-up (``full`` stayed on after an edit made the site 3-D). The printed
    line names the default at the stored site."""
    import uvicorn

    import radiopose.server.app as server_app
    from radiopose.cli import main

    seen: list[LiveConfig | None] = []

    def fake_create_app(db, live=None, **_kw):  # type: ignore[no-untyped-def]
        seen.append(live)
        return object()

    monkeypatch.setattr(server_app, "create_app", fake_create_app)
    monkeypatch.setattr(uvicorn, "run", lambda *a, **k: None)
    db = f"sqlite:///{tmp_path / 'x.db'}"
    for extra, method in (((), None), (("--method", "full"), "full")):
        seen.clear()
        assert main(["serve", str(site3d.site_dir), "--db", db, *extra]) == 0
        (live,) = seen
        assert live is not None and live.method == method
    out = capsys.readouterr().out
    assert "live method filter (the default at this site) (lag 0.25 s)" in out
    assert "live method full\n" in out


@pytest.mark.parametrize(
    ("method", "crash"),
    [(None, "none"), (None, "in the step applying the edit"), (None, "before the pipeline saw it"),
     ("filter", "none")],
)  # fmt: skip
def test_an_edit_that_makes_the_site_2d_answers_every_packet(
    tmp_path: Path, method: str | None, crash: str
) -> None:
    """The 3-D filter holds estimates back (its lag). An admin edit that makes the
    site 2-D hands over to another engine — `full` by default, the 2-D filter
    with --method filter — and every packet still ends with an estimate or a
    skip reason (helper-61: 13 packets per device had neither, with the method
    fixed, or after a crash in the step applying the edit)."""
    import re
    import shutil

    from radiopose.server.sitestore import read_site_parts

    root = tmp_path / "scene"
    sim = simulate_handheld(replace(SCENE, duration_s=6.0), seed=18119)
    sim.write(root)
    pc = write_receiver_pcaps(
        sim.packets, root / "pcaps", rng=np.random.default_rng(18119),
        clock_offset_s={"rx2": 0.2, "rx5": -0.2}, jitter_s=2e-6, epoch_s=1000.0,
    )  # fmt: skip
    frames = {r: read_pcap(q, r).frames for r, q in pc.paths.items()}
    site3d = Site3d(root, root / "site", frames, tuple(sim.site.receiver_ids),
                    str(sim.packets.transmitter[0]), len(set(sim.packets.packet_id)))  # fmt: skip
    two = tmp_path / "site2d"
    shutil.copytree(site3d.site_dir, two)
    toml = (two / "site.toml").read_text()
    toml = re.sub(r"z_min_m.*\nz_max_m.*\nz_step_m.*\n", "z_m = 1.2\n", toml)
    (two / "site.toml").write_text(re.sub(r"(pitch|roll)_deg = .*\n", "", toml))
    parts2d, _ = read_site_parts(two)
    db = Database(f"sqlite:///{tmp_path / 'db.sqlite'}")
    import_site_dir(db, site3d.site_dir)
    n = _store(db, site3d)
    cfg = fast_live(method=method, batches_per_step=6, idle_flush_s=1e6, lagged_checkpoint_s=5.0)
    p = LivePipeline(db, cfg)
    while p.state.cursor < n // 2:
        p.step()
    db.replace_site(parts2d)
    if crash == "before the pipeline saw it":
        p = LivePipeline(db, cfg)
    elif crash == "in the step applying the edit":
        p._refresh_site()  # the forced checkpoint and the hand-over; then the process dies
        p = LivePipeline(db, cfg)
    while p.state.cursor < n:
        p.step()
    p.config = fast_live(method=method, idle_flush_s=0.0, lagged_commit_s=0.0)
    p.step()
    p.step()
    assert p.tracker is not None and p.tracker.method == (method or "full")
    estimated = {e["packet_id"]: e["timestamp_s"] for e in db.estimates(limit=10**6)}
    rows = db.packets()
    db.close()
    at = {r["packet_id"]: r["timestamp_s"] for r in rows}
    assert all(at[k] == t for k, t in estimated.items())
    unanswered = [
        r["packet_id"] for r in rows if r["reason"] is None and r["packet_id"] not in estimated
    ]
    assert unanswered == []
