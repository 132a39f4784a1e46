"""The live server over a long run (helper-58's soak and restart review):
re-derived output kept once (repartitioning, lagged checkpoints), a failing
pipeline visible in /health, the batches index behind /health, departed
devices forgotten, unwritable or corrupt databases named in one line, and ids
holding ``/`` editable."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest

from radiopose.errors import InputError
from radiopose.server.app import import_site_dir
from radiopose.server.db import Database
from radiopose.server.live import LivePipeline
from radiopose.server.routers.site import health_of
from server_support import Running, db_url, fast_live, pg_server, server, store_frames, tiny


def _run_to_end(db: Database, cfg, n: int) -> LivePipeline:  # type: ignore[no-untyped-def]
    p = LivePipeline(db, cfg)
    for _ in range(n + 5):
        p.step()
    assert p.state.cursor == n
    p.config = fast_live(method=cfg.method, idle_flush_s=0.0)
    p.step()  # the idle flush closes the last packets; then the commit
    p.step()
    return p


def test_a_new_partitioning_reprocesses_what_is_stored_without_error(tiny, tmp_path: Path) -> None:
    """server.md: "a new N re-processes stored frames from the start". The packets
    and estimates it re-derives are those stored by the old partitioning: they
    are kept once, not an IntegrityError at every step (the pipeline once retried
    the same batch forever). /health's backlog reads the current partitioning."""
    db = Database(f"sqlite:///{tmp_path / 'a.db'}")
    import_site_dir(db, tiny.site_dir)
    n = store_frames(db, tiny, per_batch=20)
    cfg = fast_live(method="full", checkpoint_s=0.0, idle_flush_s=1e6)
    _run_to_end(db, cfg, n)
    packets, estimates = db.packets(), db.estimates(limit=10**6)
    assert len(packets) > 100 and len(estimates) > 10
    for k in (0, 1):
        _run_to_end(db, fast_live(method="full", partition=k, partitions=2, checkpoint_s=0.0), n)
    assert db.packets() == packets
    assert [e["packet_id"] for e in db.estimates(limit=10**6)] == [
        e["packet_id"] for e in estimates
    ]
    health = health_of(db)
    assert set(health.partitions) == {"0/1", "0/2", "1/2"} and health.backlog_batches == 0
    db.close()


def test_alarms_are_stored_once_when_output_is_re_derived(tmp_path: Path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'b.db'}")
    ev = {
        "transmitter": "phone",
        "packet_id": "7",
        "timestamp_s": 1.0,
        "state": "raised",
        "score_nats": 20.0,
        "x_m": 1.0,
        "y_m": 2.0,
    }
    cleared = {**ev, "packet_id": "9", "state": "cleared"}
    db.commit_step("0/1", 1, b"", {}, [], [], [ev])
    db.commit_step("0/1", 2, None, {}, [], [], [ev, cleared])  # a re-derived raise, a new clear
    db.add_alarms([cleared])
    assert [(a["packet_id"], a["state"]) for a in db.alarms()] == [
        ("7", "raised"),
        ("9", "cleared"),
    ]
    assert db.load_checkpoint("0/1") == (1, b"")  # the output-only commit kept the checkpoint
    db.close()


def test_health_reports_a_failing_pipeline_until_it_commits_again(tiny, tmp_path: Path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'c.db'}")
    import_site_dir(db, tiny.site_dir)
    assert health_of(db).status == "ok"
    db.note_pipeline_error("0/1", "IntegrityError: UNIQUE constraint failed")
    h = health_of(db)
    assert h.status == "degraded" and "IntegrityError" in str(h.pipeline_errors["0/1"]["message"])
    time.sleep(0.01)
    db.commit_step("0/1", 0, b"", {}, [], [])
    assert health_of(db).status == "ok"
    # an error of a partitioning that no longer runs does not count
    db.note_pipeline_error("1/2", "IntegrityError")
    time.sleep(0.01)
    db.commit_step("0/1", 0, b"", {}, [], [])
    assert health_of(db).status == "ok"
    # the backlog counts from what was processed (a lagged method's output-only
    # commits carry the cursor in the summary, ahead of the checkpoint's)
    for i in range(3):
        db.store_batch("rx1", f"b{i}", [(1, "h", "tx", -50.0)])
    db.commit_step("0/1", 3, None, {"cursor": db.last_batch_id()}, [], [])
    assert health_of(db).backlog_batches == 0
    db.close()


def test_receiver_activity_by_index(tmp_path: Path) -> None:
    """Each receiver's last report and its frames in the window, as the scan gave
    them; the lookups use the (receiver_id, received_s) index, which an older
    database gains when opened."""
    path = tmp_path / "d.db"
    db = Database(f"sqlite:///{path}")
    now = time.time()
    rows = [(1, "h", "tx", -50.0)] * 3
    for rid, batch, ago in (("rx2", "a", 100.0), ("rx1", "b", 50.0), ("rx2", "c", 2.0)):
        db.store_batch(rid, batch, rows)
        with sqlite3.connect(path) as c:  # back-date the batch
            c.execute("UPDATE batches SET received_s = ? WHERE batch_id = ?", (now - ago, batch))
    act = db.receiver_activity(10.0)
    assert set(act) == {"rx1", "rx2"}
    assert act["rx1"]["last_report_s"] == pytest.approx(now - 50.0)
    assert act["rx2"]["last_report_s"] == pytest.approx(now - 2.0)
    assert act["rx1"]["frames_per_s"] == 0.0 and act["rx2"]["frames_per_s"] == 0.3
    db.close()
    with sqlite3.connect(path) as c:  # a database from before the index
        c.execute("DROP INDEX ix_batches_receiver_received")
    Database(f"sqlite:///{path}").close()
    with sqlite3.connect(path) as c:
        plan = c.execute(
            "EXPLAIN QUERY PLAN SELECT max(received_s) FROM batches WHERE receiver_id = 'rx1'"
        ).fetchall()
    assert "ix_batches_receiver_received" in str(plan)


def test_a_departed_device_is_forgotten_at_the_site_change(tiny, tmp_path: Path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'e.db'}")
    import_site_dir(db, tiny.site_dir)
    p = LivePipeline(db, fast_live(method="full"))
    p.step()
    p.state.track_states["02:aa:00:00:00:99"] = object()  # a device since removed
    p.state.alarm_detectors["02:aa:00:00:00:99"] = object()
    p.state.pending_obs[("02:aa:00:00:00:99", "3")] = object()  # type: ignore[assignment]
    db.replace_site(db.site_rows())  # an admin edit: a new site version
    p.step()
    st = p.state
    assert not st.track_states and not st.alarm_detectors and not st.pending_obs
    db.close()


def test_an_unwritable_or_corrupt_database_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "ro.db"
    Database(f"sqlite:///{path}").close()
    ro = Database(f"sqlite:///file:{path}?mode=ro&uri=true", create=False)
    with pytest.raises(InputError, match="cannot write to the database") as err:
        ro.check_writable()
    assert "\n" not in str(err.value)
    ro.close()
    Database(f"sqlite:///{path}").check_writable()  # a writable one passes
    bad = tmp_path / "bad.db"
    bad.write_bytes(b"this is not a database file at all" * 200)
    with pytest.raises(InputError, match="cannot open the database: file is not a database"):
        Database(f"sqlite:///{bad}")


def test_ids_holding_a_slash_can_be_edited(server: Running) -> None:
    """A transmitter id is any string without commas or whitespace: ``a/b`` is
    enrolled, edited and removed through the admin API (a 404 before), sent as
    is or as %2F."""
    admin = server.client(server.tokens["admin"])
    body = {"pattern": "device", "tx_power_dbm": 1}
    for path in ("/api/v1/admin/devices/a/b", "/api/v1/admin/devices/c%2Fd"):
        r = admin.put(path, json=body)
        assert r.status_code == 200, r.text
    devices = {d["transmitter"] for d in admin.get("/api/v1/site").json()["devices"]}
    assert {"a/b", "c/d"} <= devices
    assert admin.delete("/api/v1/admin/devices/a%2Fb").status_code == 200
    devices = {d["transmitter"] for d in admin.get("/api/v1/site").json()["devices"]}
    assert "a/b" not in devices and "c/d" in devices


def test_estimates_released_by_the_idle_flush_count_their_wait(tiny, tmp_path: Path) -> None:
    """A lagged method's last estimates come out at the idle flush; their latency
    counts from the last report's arrival (it read about 0 from the flush)."""
    db = Database(f"sqlite:///{tmp_path / 'f.db'}")
    import_site_dir(db, tiny.site_dir)
    n = store_frames(db, tiny, per_batch=20)
    p = LivePipeline(db, fast_live(method="filter", idle_flush_s=0.6, lagged_checkpoint_s=0.0))
    while p.state.cursor < n:
        p.step()
    before = db.last_estimate_id()
    time.sleep(0.7)
    p.step()  # the idle flush, and the commit of what it released
    p.step()
    flushed = [e for e in db.estimates(limit=10**6) if e["id"] > before]
    assert flushed
    assert min(e["estimated_s"] - e["last_report_s"] for e in flushed) >= 0.6
    db.close()


def test_processes_opening_an_older_database_at_once_all_start(db_url: str) -> None:
    """Four processes opening a database from before the batches index each
    create it; PostgreSQL's IF NOT EXISTS is not safe under that race (3 of 4
    once failed with a duplicate key): a failure with the index there is fine."""
    import threading

    from sqlalchemy import create_engine, text

    Database(db_url).close()
    engine = create_engine(db_url)
    with engine.begin() as c:
        c.execute(text("DROP INDEX ix_batches_receiver_received"))
    engine.dispose()
    errors: list[BaseException] = []
    start = threading.Barrier(4)

    def open_it() -> None:
        start.wait()
        try:
            Database(db_url).close()
        except BaseException as exc:  # collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=open_it) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


@pytest.mark.parametrize("steps_after_edit", [-1, 0, 3])
def test_a_site_edit_then_a_crash_before_the_next_checkpoint_loses_nothing(
    tiny, tmp_path: Path, steps_after_edit: int
) -> None:
    """Output of a lagged method is committed ahead of its checkpoint. An admin
    edit of the receivers with a crash — just before the edit (the restarted
    pipeline's first step sees it), before the pipeline saw it, or a few steps
    after — must not mix that output (derived under the
    old site) with a re-derivation under the new one, whose packet numbering
    differs (helper-60: 40 of 170 packets lost, 47 estimates on the wrong
    packet): seeing the edit forces a checkpoint first (the run is then the
    uninterrupted one), and a restart whose checkpoint predates the edit
    re-derives what was committed ahead (the edit then takes effect at the
    checkpoint: a consistent run, not the uninterrupted one)."""

    def run(name: str, crash: bool) -> list[tuple[object, ...]]:
        db = Database(f"sqlite:///{tmp_path / name}")
        import_site_dir(db, tiny.site_dir)
        n = store_frames(db, tiny, per_batch=10)
        cfg = fast_live(method="filter", batches_per_step=2, idle_flush_s=1e6,
                        lagged_commit_s=0.0, lagged_checkpoint_s=1e9)  # fmt: skip
        p = LivePipeline(db, cfg)
        crash_in: int | None = None
        follower: dict[tuple[str, str], tuple[object, ...]] = {}  # a client of after_id
        last_id = 0

        def follow() -> None:
            nonlocal last_id
            for e in db.estimates(after_id=last_id, limit=10**6):
                follower[(e["transmitter"], e["packet_id"])] = (e["timestamp_s"], e["x_m"])
                last_id = max(last_id, e["id"])

        while p.state.cursor < n:
            if crash_in is None and p.state.cursor >= n // 3:
                if crash and steps_after_edit < 0:  # restarted, then the edit before a step
                    p = LivePipeline(db, cfg)
                parts = db.site_rows()  # the receivers reordered
                db.replace_site({**parts, "order": ",".join(parts["order"].split(",")[::-1])})
                crash_in = steps_after_edit if crash else -1
            if crash_in == 0:
                p = LivePipeline(db, cfg)  # the restart after a crash: its checkpoint
            p.step()
            follow()
            crash_in = None if crash_in is None else crash_in - 1
        p.config = fast_live(
            method="filter", idle_flush_s=0.0, lagged_commit_s=0.0, lagged_checkpoint_s=1e9
        )
        p.step()
        p.step()
        follow()
        rows = [(r["packet_id"], r["timestamp_s"], r["reason"]) for r in db.packets()]
        at = {r[0]: r[1] for r in rows}
        final = db.estimates(limit=10**6)
        estimated = {e["packet_id"]: e["timestamp_s"] for e in final}
        db.close()
        # a client following by id ends with every stored estimate as stored (ids of
        # output dropped and re-derived are never reused: it read past none of them)
        assert all(
            follower.get((e["transmitter"], e["packet_id"])) == (e["timestamp_s"], e["x_m"])
            for e in final
        )
        # each estimate on its own packet; every packet estimated or skipped with a reason
        assert all(at[k] == t for k, t in estimated.items())
        assert all(r[0] in estimated or r[2] is not None for r in rows)
        assert sorted(int(r[0]) for r in rows) == list(range(len(rows)))  # no gap
        return sorted(rows)

    straight = run("straight.db", False)
    crashed = run("crashed.db", True)
    if steps_after_edit > 0:  # the edit was seen and checkpointed: as if nothing happened
        assert crashed == straight


def _filter_half_way(tiny, tmp_path: Path) -> tuple[Database, LivePipeline, int]:  # type: ignore[no-untyped-def]
    """The tiny trace stored, and a lagged filter pipeline stepped through its
    first half; the database, the pipeline and the number of batches."""
    db = Database(f"sqlite:///{tmp_path / 'half.db'}")
    import_site_dir(db, tiny.site_dir)
    n = store_frames(db, tiny, per_batch=10)
    cfg = fast_live(method="filter", batches_per_step=2, idle_flush_s=1e6, lagged_commit_s=0.0)
    p = LivePipeline(db, cfg)
    while p.state.cursor < n // 2:
        p.step()
    return db, p, n


def test_a_method_taking_over_emits_the_lagged_estimates_held_back(tiny, tmp_path: Path) -> None:
    """A restart with another --method over a lagged method's checkpoint: the
    estimates filter still held back are emitted by it (about the lag's worth
    of packets per device stayed as "its estimate follows" with none)."""
    db, p, n = _filter_half_way(tiny, tmp_path)
    p._commit(p._unsaved, force_state=True)  # the checkpoint the restart reads
    p = LivePipeline(db, fast_live(method="full", idle_flush_s=1e6))
    assert p.state.method == ("filter", False) and p.state.track_states
    while p.state.cursor < n:
        p.step()
    p.config = fast_live(method="full", idle_flush_s=0.0)
    p.step()
    p.step()
    estimates = db.estimates(limit=10**6)
    by_method = {m: sum(e["method"] == m for e in estimates) for m in ("filter", "full")}
    assert by_method["filter"] > 0 and by_method["full"] > 0
    estimated = {e["packet_id"] for e in estimates}
    waiting = [r["packet_id"] for r in db.packets() if r["reason"] is None]
    assert waiting and set(waiting) <= estimated  # none left without its estimate
    assert p.state.method == ("full", False)
    db.close()


@pytest.mark.parametrize("edit", ["the device removed", "a receiver removed"])
def test_a_live_edit_leaves_no_packet_unanswered(tiny, tmp_path: Path, edit: str) -> None:
    """A live edit with the engine unchanged: the held-back estimates of a device
    the edit removes, and the packets open against a receiver it removes, are
    finished by the old tracker on the old site (helper-62: 13 packets had
    neither an estimate nor a reason; a removed receiver's open packets made the
    new tracker fail and drop the device's lag buffer)."""
    db, p, n = _filter_half_way(tiny, tmp_path)
    parts = db.site_rows()
    if edit == "the device removed":
        db.replace_site({**parts, "devices": parts["devices"][1:]})
    else:
        order = parts["order"].split(",")
        gone = order[-1]
        files = dict(parts["files"])
        files["survey.csv"] = "".join(
            ln + "\n" for ln in files["survey.csv"].splitlines() if gone not in ln
        )
        receivers = [r for r in parts["receivers"] if r["receiver_id"] != gone]
        db.replace_site(
            {**parts, "files": files, "receivers": receivers, "order": ",".join(order[:-1])}
        )
    while p.state.cursor < n:
        p.step()
    p.config = fast_live(method="filter", idle_flush_s=0.0, lagged_commit_s=0.0)
    p.step()
    p.step()
    rows = db.packets()
    estimated = {e["packet_id"]: e["timestamp_s"] for e in db.estimates(limit=10**6)}
    db.close()
    at = {r["packet_id"]: r["timestamp_s"] for r in rows}
    assert all(at[k] == t for k, t in estimated.items())
    assert [
        r["packet_id"] for r in rows if r["reason"] is None and r["packet_id"] not in estimated
    ] == []
    assert "method_failures" not in p.state.counts


class _RaisingMonitor:
    """An alarm monitor that raises on every estimate it is shown (wiring only)."""

    def __init__(self) -> None:
        self.seen: list[tuple[str, str]] = []

    def observe(self, obs, position_m, orientation_deg):  # type: ignore[no-untyped-def]
        self.seen.append((obs.transmitter, obs.packet_id))
        return {
            "transmitter": obs.transmitter, "packet_id": obs.packet_id,
            "timestamp_s": obs.timestamp_s, "state": "raised", "score_nats": 99.0,
            "x_m": float(position_m[0]), "y_m": float(position_m[1]),
        }  # fmt: skip


def test_estimates_flushed_by_a_live_edit_pass_the_alarm_monitor(tiny, tmp_path: Path) -> None:
    """The held-back estimates a live edit flushes (of the device it removes) are
    shown to the spoofing alarm monitor of the site they were derived under,
    like every other filter estimate, and their alarms are stored with them (they
    bypassed it: an attack in a device's last lag before its removal raised none)."""
    db, p, _n = _filter_half_way(tiny, tmp_path)
    monitor = _RaisingMonitor()
    p.alarm_monitor = monitor
    p.step()  # (the monitor sees the estimates of a step)
    parts = db.site_rows()
    removed = parts["devices"][0]["transmitter"].lower()
    seen_before = len(monitor.seen)
    waiting = {r["packet_id"] for r in db.packets() if r["reason"] is None} | {
        r["packet_id"] for r in p._unsaved if r["kind"] == "packet" and r["reason"] is None
    }
    db.replace_site({**parts, "devices": parts["devices"][1:]})
    p.step()  # the edit: the removed device's held-back estimates are flushed
    flushed = monitor.seen[seen_before:]
    assert flushed and all(tx == removed for tx, _ in flushed)
    assert {pid for _, pid in flushed} <= waiting
    alarmed = {(a["transmitter"], a["packet_id"]) for a in db.alarms()}
    assert set(flushed) <= alarmed
    assert p.alarm_monitor is not monitor  # the new site's monitor from here
    db.close()


def test_an_unrecorded_engine_taken_over_leaves_no_packet_unanswered(tiny, tmp_path: Path) -> None:
    """A checkpoint written before engines were recorded (no ``method``, no
    ``site_version``: an older version), restarted with another --method: what
    filter held back cannot be handed over, so those packets get the skip
    reason SKIP_ENGINE_UNRECORDED (about the lag's worth per device had
    neither an estimate nor a reason)."""
    import pickle

    from radiopose.tracker import SKIP_ENGINE_UNRECORDED

    db, p, n = _filter_half_way(tiny, tmp_path)
    p._commit(p._unsaved, force_state=True)
    key = p.config.partition_key
    cursor, blob = db.load_checkpoint(key)  # type: ignore[misc]
    old = pickle.loads(blob)
    for name in ("method", "site_version", "pending_obs"):  # fields an older version lacked
        del old.__dict__[name]
    db.commit_step(key, cursor, pickle.dumps(old), db.summaries()[key], [], [])
    p = LivePipeline(db, fast_live(method="full", idle_flush_s=1e6))
    assert p.state.method is None and p.state.track_states
    while p.state.cursor < n:
        p.step()
    p.config = fast_live(method="full", idle_flush_s=0.0)
    p.step()
    p.step()
    estimated = {e["packet_id"] for e in db.estimates(limit=10**6)}
    rows = db.packets()
    db.close()
    assert [
        r["packet_id"] for r in rows if r["reason"] is None and r["packet_id"] not in estimated
    ] == []
    assert any(r["reason"] == SKIP_ENGINE_UNRECORDED for r in rows)


def test_tls_files_are_checked_before_serving(tiny, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """A missing or malformed certificate/key is one line naming the option and
    the file, before the database or the site is touched (it was "No such file
    or directory" or "[SSL] PEM lib (_ssl.c:3905)", naming neither; helper-63);
    a real self-signed pair passes the check."""
    import shutil
    import subprocess

    from radiopose.cli import main
    from radiopose.cli.server import _check_tls

    db = tmp_path / "s.db"
    serve = ["serve", str(tiny.site_dir), "--db", str(db), "--port", "18999"]
    assert main([*serve, "--ssl-certfile", str(tmp_path / "no.pem"),
                 "--ssl-keyfile", str(tmp_path / "no.key")]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert f"--ssl-certfile {tmp_path / 'no.pem'}: No such file or directory" in err
    assert err.count("\n") == 1 and not db.exists()
    junk = tmp_path / "junk.pem"
    junk.write_bytes(b"\x00\xff not a certificate\n")
    assert main([*serve, "--ssl-certfile", str(junk), "--ssl-keyfile", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "not a PEM certificate and its private key" in err and str(junk) in err
    assert err.count("\n") == 1 and not db.exists()
    if shutil.which("openssl") is None:
        pytest.skip("no openssl command to make a self-signed pair")
    cert, key = tmp_path / "c.pem", tmp_path / "k.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key),
         "-out", str(cert), "-days", "1", "-subj", "/CN=localhost"],
        check=True, capture_output=True,
    )  # fmt: skip
    _check_tls(cert, key)
    with pytest.raises(InputError, match="not a PEM certificate"):
        _check_tls(key, cert)  # swapped


# ------------------------------------------------------- receiver clocks over a long run
@pytest.fixture(scope="module")
def drifting(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """240 s of a device at 2.5 packets/s heard by 3 receivers whose clocks run
    0.3 s apart and drift by +40 and -30 ppm (5 ms, the matching tolerance,
    after 125 s at 40 ppm): the site, every receiver's frames, and the number of
    packets offline ``sync`` hears at all three."""
    import numpy as np

    from radiopose.capture.records import read_pcap
    from radiopose.capture.sync import SyncConfig, synchronise
    from radiopose.capture.writer import write_receiver_pcaps
    from radiopose.simulate import ScenarioConfig, simulate

    root = tmp_path_factory.mktemp("drift")
    cfg = ScenarioConfig(size_m=6.0, step_m=0.5, n_receivers=3, duration_s=240.0,
                         interval_ms=400.0, azimuth_step_deg=5.0, noise_db=0.5,
                         min_receiver_spacing_m=3.0)  # fmt: skip
    sim = simulate(cfg, seed=5)
    sim.write(root)
    pc = write_receiver_pcaps(
        sim.packets, root / "pcaps", rng=np.random.default_rng(5),
        clock_offset_s={"rx2": 0.3, "rx3": -0.3}, drift_ppm={"rx2": 40.0, "rx3": -30.0},
        jitter_s=2e-6, epoch_s=1000.0,
    )  # fmt: skip
    captures = {r: read_pcap(p, r) for r, p in pc.paths.items()}
    packets, _ = synchronise(list(captures.values()), SyncConfig())
    _, per_packet = np.unique(packets.packet_id, return_counts=True)
    return root / "site", {r: c.frames for r, c in captures.items()}, int((per_packet == 3).sum())


def _live_receptions(
    site_dir: Path,
    frames: dict,  # type: ignore[type-arg]
    db_path: Path,
    outage: tuple[int, int] | None = None,
    fresh_first: str | None = None,
) -> dict[int, int]:
    """Store the frames as agents would (1 s of each receiver's clock per batch,
    receivers interleaved in time), run the live pipeline to the end; packets
    by the number of receivers that heard them. ``outage = (a, b)``: the server
    was down while rounds ``a`` to ``b - 1`` were captured; they arrive 20 s
    after the ones before, rx2's after the others' (each agent drains its spool
    at its own pace). ``fresh_first``: that receiver spooled nothing over the
    outage (its batches of those rounds are gone), and its first batch after it,
    a fresh one, arrives before the others' spools."""
    from collections import Counter

    import numpy as np

    db = Database(f"sqlite:///{db_path}")
    import_site_dir(db, site_dir)
    t0 = min(int(f.timestamp_ns.min()) for f in frames.values() if len(f))
    rounds: dict[int, list[tuple[str, str, list]]] = {}  # type: ignore[type-arg]
    for r, f in frames.items():
        k = (f.timestamp_ns - t0) // 1_000_000_000
        for i in np.unique(k):
            sel = np.flatnonzero(k == i)
            rows = [(int(f.timestamp_ns[j]), f.frame_sha256[j], f.transmitter[j],
                     float(f.rss_dbm[j])) for j in sel]  # fmt: skip
            rounds.setdefault(int(i), []).append((r, f"{r}-{i}", rows))
    order = [b for i in sorted(rounds) for b in rounds[i]]
    first_late = None
    if outage is not None:
        a, b = outage
        before = [x for i in sorted(rounds) if i < a for x in rounds[i]]
        down = [x for i in sorted(rounds) if a <= i < b for x in rounds[i]]
        after = [x for i in sorted(rounds) if i >= b for x in rounds[i]]
        if fresh_first is not None:  # it spooled nothing; its next batch comes first
            down = [x for x in down if x[0] != fresh_first]
            first = next(x for x in after if x[0] == fresh_first)
            after = [first] + [x for x in after if x is not first]
        spooled = [x for x in down if x[0] != "rx2"] + [x for x in down if x[0] == "rx2"]
        order = before + (after[:1] + spooled + after[1:] if fresh_first else spooled + after)
        first_late = len(before)
    n = 0
    for r, bid, rows in order:
        db.store_batch(r, bid, rows)
        n += 1
    if first_late is not None:  # arrivals after the outage: 20 s later
        import sqlite3

        with sqlite3.connect(db_path) as con:
            ids = [i for (i,) in con.execute("SELECT id FROM batches ORDER BY id")]
            con.execute("UPDATE batches SET received_s = received_s + 20 WHERE id >= ?",
                        (ids[first_late],))  # fmt: skip
    p = LivePipeline(db, fast_live(method="lms", idle_flush_s=1e6, calibration_s=3.0))
    while p.state.cursor < n:
        p.step()
    p.config = fast_live(method="lms", idle_flush_s=0.0)
    p.step()
    p.step()
    heard = Counter(len(r["receiver_ids"]) for r in db.packets())
    db.close()
    return dict(heard)


def test_drifting_receiver_clocks_are_followed_over_a_long_run(drifting, tmp_path: Path) -> None:
    """The live server re-estimates the clocks as the run goes (every 10 s from
    the last 30 s): at +40/-30 ppm it matches what offline sync matches. With the
    3 s calibration alone (offset only, never again) matching fell apart after
    about 2 minutes (helper-64: at 20 ppm a live run lost packets after 250 s)."""
    site_dir, frames, all_three = drifting
    heard = _live_receptions(site_dir, frames, tmp_path / "d.db")
    assert all_three >= 590  # (600 packets sent, none lost)
    assert heard.get(3, 0) >= all_three - 3 and heard.get(1, 0) <= 6


def test_after_an_outage_the_agents_spools_are_waited_for(drifting, tmp_path: Path) -> None:
    """The server down for 30 s of capture; then the agents deliver their spools,
    rx2's after the others' (30 s behind them, more than max_lag_s = 5 s): the
    pipeline catches up — packets close at most 120 s behind the leader until
    every receiver is back within 5 s — and matches what an uninterrupted run
    matches (helper-64: a kill -9 and restart of 6 s lost 112 receptions as late
    frames)."""
    site_dir, frames, all_three = drifting
    heard = _live_receptions(site_dir, frames, tmp_path / "o.db", outage=(100, 130))
    assert heard.get(3, 0) >= all_three - 3 and heard.get(2, 0) <= 6


def test_after_an_outage_a_fresh_first_batch_still_starts_the_catch_up(
    drifting, tmp_path: Path
) -> None:
    """The first batch after the outage is a fresh one, from a receiver that had
    nothing spooled (rx3 heard nothing over it): pushing it moved the horizon past
    the others' spooled frames, and no catch-up started because it was not a
    spooled one (helper-68: 64 packets lost a receiver, 131 frames late). Every
    pause now starts the catch-up before its first batch is pushed."""
    site_dir, frames, _ = drifting
    heard = _live_receptions(
        site_dir, frames, tmp_path / "f.db", outage=(100, 130), fresh_first="rx3"
    )
    # rx3's 30 s of the outage are gone: 75 packets at two receivers, none lost
    # (before: 64 packets lost, both others' frames late, and 12 at two receivers)
    assert sum(heard.values()) == 600 and heard.get(2, 0) >= 70 and heard.get(3, 0) >= 515


def test_a_receiver_that_joins_late_gets_a_clock(drifting, tmp_path: Path) -> None:
    """A receiver first heard 20 s after the calibration is calibrated from its
    first 3 s of frames (it kept 'no clock', offset 0, for good: every frame a
    packet of its own; helper-64, also on the real ESP32 captures)."""
    site_dir, frames, all_three = drifting
    late = frames["rx3"]
    start = int(late.timestamp_ns.min()) + 20 * 1_000_000_000
    late_frames = {**frames, "rx3": late.take(late.timestamp_ns >= start)}
    heard = _live_receptions(site_dir, late_frames, tmp_path / "l.db")
    # about 50 packets before it joins are heard by two; a few while it calibrates
    assert heard.get(3, 0) >= all_three - 60 and heard.get(1, 0) <= 20


def test_chains_dropped_at_the_idle_flush_are_counted_in_the_summary(tiny, tmp_path: Path) -> None:
    """One hash heard twice by rx1 and once by rx2: the idle flush drops the chain
    (duplicated at a receiver), and the summary /health shows says so, although
    the flush emitted nothing (it kept 'open_frames: 3' and no count; helper-64)."""
    db = Database(f"sqlite:///{tmp_path / 'dup.db'}")
    import_site_dir(db, tiny.site_dir)
    h, tx = "ab" * 32, tiny.transmitter
    db.store_batch(
        "rx1", "dup-1", [(500_000_000_000, h, tx, -50.0), (500_001_000_000, h, tx, -51.0)]
    )
    db.store_batch("rx2", "dup-2", [(500_000_500_000, h, tx, -52.0)])
    p = LivePipeline(db, fast_live(method="full", idle_flush_s=1e6))
    p.step()
    p.config = fast_live(method="full", idle_flush_s=0.0)
    p.step()
    summary = db.summaries()[p.config.partition_key]
    db.close()
    assert summary["open_frames"] == 0 and summary["phase"] == "matching"
    assert (summary["ambiguous_duplicate"], summary["ambiguous_spread"]) == (1, 0)
    assert summary["ambiguous_frames"] == 3


def test_a_restart_re_derives_the_same_packets_with_refreshed_clocks(
    drifting, tmp_path: Path
) -> None:
    """The clocks' re-estimates read their frames back from the database and
    keep their schedule in the checkpoint, so a pipeline restarted from an old
    checkpoint (a lagged method's: output is committed ahead of it) regroups
    nothing: packets and estimates equal an uninterrupted run's (helper-66: with
    the frame window in memory only, a restart stored 21 receptions in two
    packets each and estimated them twice)."""
    import numpy as np

    site_dir, frames, _ = drifting
    late = frames["rx3"]
    start = int(late.timestamp_ns.min()) + 20 * 1_000_000_000
    scene = {**frames, "rx3": late.take(late.timestamp_ns >= start)}
    t0 = min(int(f.timestamp_ns.min()) for f in scene.values())
    end = t0 + 90 * 1_000_000_000

    def run(name: str, restart_at: int | None) -> tuple[list, list]:  # type: ignore[type-arg]
        db = Database(f"sqlite:///{tmp_path / name}")
        import_site_dir(db, site_dir)
        rounds: dict[int, list] = {}  # type: ignore[type-arg]
        for r, f in scene.items():
            k = (f.timestamp_ns - t0) // 1_000_000_000
            for i in np.unique(k[f.timestamp_ns < end]):
                sel = np.flatnonzero(k == i)
                rows = [(int(f.timestamp_ns[j]), f.frame_sha256[j], f.transmitter[j],
                         float(f.rss_dbm[j])) for j in sel]  # fmt: skip
                rounds.setdefault(int(i), []).append((r, f"{r}-{i}", rows))
        n = 0
        for i in sorted(rounds):
            for r, bid, rows in rounds[i]:
                db.store_batch(r, bid, rows)
                n += 1
        cfg = fast_live(method="filter", batches_per_step=1, idle_flush_s=1e6, calibration_s=3.0,
                        lagged_commit_s=0.0, lagged_checkpoint_s=1e9)  # fmt: skip
        p = LivePipeline(db, cfg)
        steps = 0
        while p.state.cursor < n:
            p.step()
            steps += 1
            if steps == 50:  # a checkpoint after the calibration and a first re-estimate
                p._commit(p._unsaved, force_state=True)
                p._unsaved = []
            if steps == restart_at:
                p = LivePipeline(db, cfg)  # from that checkpoint: steps 51 on again
        p.config = fast_live(method="filter", idle_flush_s=0.0, lagged_commit_s=0.0)
        p.step()
        p.step()
        packets = sorted(
            (r["packet_id"], r["timestamp_s"], tuple(r["receiver_ids"])) for r in db.packets()
        )
        estimates = sorted((e["packet_id"], e["x_m"]) for e in db.estimates(limit=10**6))
        db.close()
        return packets, estimates

    straight = run("straight.db", None)
    restarted = run("restarted.db", 90)
    assert len(straight[0]) > 200
    assert restarted == straight


def test_a_late_receiver_heard_in_sparse_bursts_gets_a_clock(drifting, tmp_path: Path) -> None:
    """Probe requests come in short bursts tens of seconds apart: here 1.2 s (3
    packets) every 40 s, and rx3 first heard 20 s in. No 30 s window holds the 5
    pairs a refresh asks for, so rx3 had no clock for good — every frame a packet
    of its own (helper-67, on the real ESP32 captures: 0 packets at both
    receivers against offline sync's 20). The long look (every frame rx3 shares
    with the reference over the last 30 windows, 2 pairs as sync asks) gives it
    one from its second burst."""
    site_dir, frames, _ = drifting
    t0 = min(int(f.timestamp_ns.min()) for f in frames.values())
    second = 1_000_000_000

    rx1 = frames["rx1"]
    rel = rx1.timestamp_ns - t0
    sent = {  # the packets of the bursts (by their hash, as every receiver heard them)
        h: t for h, t, keep in zip(rx1.frame_sha256, rel, rel % (40 * second) < 1.2 * second,
                                   strict=True) if keep
    }  # fmt: skip

    def bursts(f, start_s: float):  # type: ignore[no-untyped-def]
        return f.take([sent.get(h, -1) >= start_s * second for h in f.frame_sha256])

    sparse = {r: bursts(f, 20.0 if r == "rx3" else 0.0) for r, f in frames.items()}
    heard = _live_receptions(site_dir, sparse, tmp_path / "b.db")
    # rx3 hears 5 bursts of 3 packets (40 s … 200 s); from its second one on all three match
    assert heard.get(3, 0) >= 9 and heard.get(1, 0) <= 6


def test_an_output_only_commit_leaves_the_checkpoint_row_alone(tmp_path: Path) -> None:
    """A lagged method commits its output several times a second and its state
    (megabytes) every few seconds: the summary of an output-only commit goes to
    its own table, so the checkpoint row — state included — is not rewritten.
    Updating the summary column in the checkpoint row rewrote the whole row
    whenever the summary's length changed (the paced benchmark: 8 filter phones
    wrote 23.4 MB/s, 6.3 MB/s with this)."""
    import os

    io = Path("/proc/self/io")
    if not io.exists():
        pytest.skip("no /proc/self/io here (not Linux)")

    def written() -> int:  # bytes this process handed to write calls
        return next(int(v.split()[1]) for v in io.read_text().splitlines() if v.startswith("wchar"))

    db = Database(f"sqlite:///{tmp_path / 's.db'}")
    state = os.urandom(2_000_000)
    db.commit_step("0/1", 5, state, {"phase": "matching", "n": 0}, [], [])
    before = written()
    for n in range(1, 6):  # (a summary whose length changes, as its counts grow: SQLite
        # then rewrites the whole record; an update of the same length is done in place)
        db.commit_step("0/1", 5 + n, None, {"phase": "matching", "n": n, "c": "x" * n}, [], [])
    assert written() - before < 500_000  # (five rewrites of the state were 10 MB)
    assert db.load_checkpoint("0/1") == (5, state)
    summary = db.summaries()["0/1"]
    assert summary["n"] == 5 and summary["cursor_batch"] == 5
    db.close()
