"""Where the spoofing detector is wired in: ``locate --method filter``'s trailing
columns, the alarms table, ``GET /api/v1/alarms``, the estimates' alarm flag and
the live monitor (issue 19)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from radiopose.estimates import read_estimates_csv
from radiopose.packets import PacketObservation
from radiopose.security.detection import ALARM_COLUMN, SCORE_COLUMN
from radiopose.simulate import ScenarioConfig, simulate
from server_support import db_url, tiny  # noqa: F401 - fixtures of the live-server tests

SEED = 4244


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("small")
    cfg = ScenarioConfig(
        size_m=6.0,
        step_m=0.25,
        n_receivers=4,
        duration_s=3.0,
        interval_ms=20.0,
        azimuth_step_deg=2.0,
        noise_db=0.5,
        min_receiver_spacing_m=2.0,
    )
    sim = simulate(cfg, seed=SEED)
    sim.write(root)
    return root, sim


def test_locate_filter_writes_score_and_alarm_as_trailing_columns(
    small, tmp_path: Path, capsys
) -> None:
    from radiopose.cli import main

    root, _ = small
    out = tmp_path / "est.csv"
    code = main(
        ["locate", str(root / "site"), str(root / "packets.csv"), "-o", str(out),
         "--method", "filter", "-q"],
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    header = out.read_text().splitlines()[0].split(",")
    assert header[-2:] == [SCORE_COLUMN, ALARM_COLUMN]
    assert header.index("method") < header.index(SCORE_COLUMN)
    est = read_estimates_csv(out)  # readers ignore the columns they do not know
    assert len(est) > 0
    col = [ln.split(",")[-1] for ln in out.read_text().splitlines()[1:]]
    assert set(col) <= {"0", "1"}
    assert "spoofing detector" in err
    # the paper's methods get no detector columns
    out2 = tmp_path / "full.csv"
    code = main(["locate", str(root / "site"), str(root / "packets.csv"), "-o", str(out2), "-q"])
    assert code == 0, capsys.readouterr().err
    assert SCORE_COLUMN not in out2.read_text().splitlines()[0]


@pytest.mark.parametrize("signal", ["rss", "residual"])
def test_alarm_monitor_raises_on_a_clone_elsewhere(small, signal: str) -> None:
    from radiopose.security.detection import DetectorConfig
    from radiopose.server.alarms import AlarmMonitor

    _, sim = small
    site = sim.site
    tx = site.devices[0].transmitter
    ids = site.receiver_ids
    rng = np.random.default_rng(SEED)
    mon = AlarmMonitor(site, DetectorConfig(signal=signal))
    pose_p, pose_o = (2.0, 3.0, sim.config.z_m), (40.0, 0.0, 0.0)
    from radiopose.security.detection import pose_residuals_db

    model = mon._model(tx)
    expected = np.asarray(pose_p)[None, :], np.asarray(pose_o)[None, :]
    base = -pose_residuals_db(model, *expected, np.zeros((1, len(ids))))[0]  # expected RSS
    events = []
    for i in range(600):
        rss = base + rng.normal(0.0, 0.5, base.shape)
        if i >= 400 and i % 2:  # a clone elsewhere sends every other packet
            rss = rss + np.array([6.0, -6.0, 4.0, -4.0])
        obs = PacketObservation(str(i), i * 0.01, tx, ids, rss)
        e = mon.observe(obs, pose_p, pose_o)
        if e is not None:
            events.append(e)
    assert events and events[0]["state"] == "raised"
    assert 4.0 <= events[0]["timestamp_s"] <= 4.5


def test_alarms_table_endpoint_and_estimate_flags(small, tmp_path: Path) -> None:
    import asyncio

    import httpx

    from radiopose.server.app import create_app, import_site_dir
    from radiopose.server.auth import create_token
    from radiopose.server.db import Database

    root, sim = small
    db = Database(f"sqlite:///{tmp_path / 'a.db'}")
    import_site_dir(db, root / "site")
    tx = sim.site.devices[0].transmitter
    db.add_alarms(
        [
            {"transmitter": tx, "packet_id": "7", "timestamp_s": 1.0, "state": "raised",
             "score_nats": 41.0, "x_m": 1.0, "y_m": 2.0},
            {"transmitter": tx, "packet_id": "9", "timestamp_s": 2.0, "state": "cleared",
             "score_nats": 19.0, "x_m": 1.0, "y_m": 2.0},
        ]
    )  # fmt: skip
    row = {"kind": "estimate", "transmitter": tx, "x_m": 0.0, "y_m": 0.0, "z_m": 1.0,
           "azimuth_deg": 0.0, "pitch_deg": 0.0, "roll_deg": 0.0, "method": "filter",
           "last_report_s": 0.0}  # fmt: skip
    est = [
        {**row, "packet_id": str(i), "timestamp_s": t, "estimated_s": 0.0}
        for i, t in enumerate((0.5, 1.5, 2.5))
    ]
    db.commit_step("p", 0, b"", {}, [], [{k: v for k, v in e.items() if k != "kind"} for e in est])
    viewer = create_token(db, "viewer")
    app = create_app(db, run_pipeline=False)
    auth = {"Authorization": f"Bearer {viewer}"}

    async def calls() -> list:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            return [
                await client.get("/api/v1/alarms"),
                await client.get("/api/v1/alarms", headers=auth),
                await client.get("/api/v1/estimates", headers=auth),
            ]

    anonymous, alarms, estimates = asyncio.run(calls())
    assert anonymous.status_code == 401
    assert alarms.status_code == 200
    body = alarms.json()
    assert [a["state"] for a in body] == ["raised", "cleared"]
    assert body[0]["score_nats"] == 41.0 and math.isfinite(body[0]["raised_s"])
    assert [e["spoof_alarm_flag"] for e in estimates.json()] == [0, 1, 0]
    db.close()


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_live_filter_pipeline_stores_alarm_events(
    tiny,  # noqa: F811 - the fixture
    db_url: str,  # noqa: F811
    tmp_path: Path,
    monkeypatch,
) -> None:
    """The live chain end to end: reports in, ``filter`` estimates, the monitor's
    events in the alarms table and the API. The detector is set to a hair trigger
    (threshold 0.01 nats, no warm-up) so genuine traffic raises alarms."""
    import threading

    from radiopose.receiver import AgentConfig, ReceiverAgent, run_replay
    from radiopose.security.detection import DetectorConfig
    from radiopose.server import alarms
    from radiopose.server.app import import_site_dir
    from radiopose.server.auth import create_token
    from radiopose.server.db import Database
    from server_support import RECEIVERS, fast_live, run_server, wait_for

    monkeypatch.setattr(
        alarms, "DetectorConfig", lambda: DetectorConfig(threshold_nats=0.01, warmup_s=0.0)
    )
    db = Database(db_url)
    import_site_dir(db, tiny.site_dir)
    tokens = {r: create_token(db, "receiver", r) for r in RECEIVERS}
    viewer = create_token(db, "viewer")
    with run_server(db, fast_live(method="filter")) as srv:
        agents = []
        for r in RECEIVERS:
            cfg = AgentConfig(srv.url, tokens[r], r, spool_dir=tmp_path / "spool" / r)
            agents.append(ReceiverAgent(cfg))
        threads = [
            threading.Thread(target=run_replay, args=(a, tiny.frames[a.config.receiver_id]))
            for a in agents
        ]
        for a in agents:
            a.refresh_transmitters()
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        for a in agents:
            assert a.drain(60)
            a.close()
        events = wait_for(lambda: db.alarms(), 60)
        assert events[0]["state"] == "raised"
        assert events[0]["transmitter"].lower() == tiny.transmitter.lower()
        got = srv.client(viewer).get("/api/v1/alarms").json()
        assert [e["id"] for e in got][: len(events)] == [e["id"] for e in events]
        flagged = srv.client(viewer).get("/api/v1/estimates").json()
        assert any(e["spoof_alarm_flag"] == 1 for e in flagged)
    db.close()


@pytest.mark.parametrize("lag_s", [0.0, 0.25])
def test_live_detectors_resume_from_the_checkpoint(
    tiny,  # noqa: F811
    tmp_path: Path,
    monkeypatch,
    lag_s: float,
) -> None:
    """A pipeline restarted from its checkpoint half-way ends with the same detector
    state and the same alarm events as one that never stopped (hair-trigger
    detector, so genuine traffic raises and clears alarms all along). With the
    live lag the packets waiting for their estimates are in the checkpoint too
    (they were not: the restarted detector skipped them and its events
    differed)."""
    from radiopose.security.detection import DetectorConfig
    from radiopose.server import alarms
    from radiopose.server.app import import_site_dir
    from radiopose.server.db import Database
    from radiopose.server.live import LivePipeline
    from server_support import fast_live, store_frames

    monkeypatch.setattr(
        alarms, "DetectorConfig", lambda: DetectorConfig(threshold_nats=0.5, warmup_s=0.0)
    )
    cfg = fast_live(
        method="filter", live_lag_s=lag_s, batches_per_step=4, checkpoint_s=0.0, idle_flush_s=1e6,
        lagged_commit_s=0.0, lagged_checkpoint_s=0.0,
    )  # fmt: skip

    def run(name: str, restart: bool):  # type: ignore[no-untyped-def]
        db = Database(f"sqlite:///{tmp_path / name}")
        import_site_dir(db, tiny.site_dir)
        n = store_frames(db, tiny, per_batch=10)
        p = LivePipeline(db, cfg)
        while p.state.cursor < n:
            if restart and p.state.cursor >= n // 2:
                p, restart = LivePipeline(db, cfg), False  # a restart: the checkpoint
                assert p.alarm_monitor is None and p.state.cursor >= n // 2
            p.step()
        events = [(e["packet_id"], e["state"], e["score_nats"]) for e in db.alarms()]
        db.close()
        return p, events

    straight, events = run("a.db", False)
    restarted, events_restarted = run("b.db", True)
    assert len(events) >= 2  # the hair trigger fires on genuine traffic
    assert events_restarted == events
    det, det_r = straight.state.alarm_detectors, restarted.state.alarm_detectors
    assert list(det) == list(det_r) == [tiny.transmitter.lower()]
    a, b = det[tiny.transmitter.lower()], det_r[tiny.transmitter.lower()]
    assert (a.n, a.var_db2, a.cusum_nats, a.alarm) == (b.n, b.var_db2, b.cusum_nats, b.alarm)
    assert restarted.alarm_monitor._detectors is det_r
