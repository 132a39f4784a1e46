"""``filter`` live: the streaming tracker with a fixed lag, and the live server running it.

* the streaming :class:`~radiopose.tracker.Tracker` with ``lag_s`` holds each
  packet's estimate back until the first packet at least ``lag_s`` later, emits
  the rest at :meth:`~radiopose.tracker.Tracker.flush`, loses none, and gives
  exactly what batch :func:`~radiopose.tracker.locate` gives with the same lag;
* the live server with ``method = "filter"`` stores an estimate for every
  packet, with its uncertainty (database, ``GET /api/v1/estimates``,
  ``radiopose db export``), and the export replays exactly;
* databases created before the uncertainty columns gain them (old rows read
  ``NULL``, their JSON has no such keys).

Seeds 5611 and 3 (the ``tiny`` site) are used here only.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import text

from radiopose.estimates import read_estimates_csv, write_estimates_csv
from radiopose.filtering import FilterConfig
from radiopose.packets import group_packets, read_packets_csv
from radiopose.server.app import import_site_dir
from radiopose.server.auth import create_token
from radiopose.server.db import Database
from radiopose.server.export import export_run
from radiopose.server.live import LiveConfig, PipelineState
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.site import load_site
from radiopose.tracker import PENDING, Tracker, TrackerConfig, TrackState, locate
from server_support import (  # fixtures and helpers
    RECEIVERS,
    db_url,
    fast_live,
    frame_dicts,
    pg_server,
    run_server,
    tiny,
    wait_for,
)

LAG_S = 0.25
REPLAY_CONFIG = TrackerConfig(
    smoothing_lag_s=LAG_S,
    filter=FilterConfig(
        offline_reverse_pass=False, offline_refine=False, offline_offset_selection=False
    ),
)
"""``locate`` as the live server runs the filter: the same lag, without the offline
passes after the forward one (docs/filter.md, "Live lag": a replay). The offset
selection too: on this trace it ran offline once the motion noise became
counter-based (pass 1's offset belief wandered 1.5 dB), and the replay then
differed from the live run."""


@pytest.fixture(scope="module")
def sim():
    cfg = ScenarioConfig(
        size_m=10.0, step_m=0.25, duration_s=1.0, noise_db=1.0, min_receiver_spacing_m=3.0
    )
    return simulate(cfg, seed=5611)


def test_streaming_lag_emits_each_estimate_once_the_lag_has_passed(sim):
    obs = group_packets(sim.packets)
    times = np.array([o.timestamp_s for o in obs])
    tr = Tracker(sim.site, "filter", TrackerConfig(), lag_s=LAG_S)
    released: dict[str, tuple[float | None, object]] = {}
    for o in obs:
        est, reason = tr.update(o)
        assert est is None and reason == PENDING
        for d in tr.take_delayed():
            assert d.packet_id not in released
            released[d.packet_id] = (o.timestamp_s, d)
    tail = tr.flush()
    assert tr.flush() == []  # nothing twice
    for d in tail:
        released[d.packet_id] = (None, d)
    assert set(released) == {o.packet_id for o in obs}  # nothing lost
    assert 0 < len(tail) <= int(LAG_S / 0.005) + 1
    for t_rel, d in released.values():
        t = d.timestamp_s
        due = times[times - LAG_S >= t]
        if t_rel is None:  # flushed at the end: no packet was late enough
            assert due.size == 0
        else:  # released by the first packet at least the lag later, not before
            assert t_rel == due.min()
            assert LAG_S - 1e-9 <= t_rel - t <= LAG_S + 0.006
    batch = locate(sim.site, sim.packets, "filter", REPLAY_CONFIG)
    streamed = [released[pid][1] for pid in batch.estimates.packet_id]
    assert len(streamed) == len(obs)
    np.testing.assert_array_equal([e.position_m for e in streamed], batch.estimates.position_m)
    np.testing.assert_array_equal(
        [e.orientation_deg for e in streamed], batch.estimates.orientation_deg
    )
    np.testing.assert_array_equal(
        [e.position_std_m for e in streamed], batch.estimates.position_std_m
    )


def test_a_silent_device_is_released_after_the_lag(sim):
    obs = group_packets(sim.packets)[:40]
    tr = Tracker(sim.site, "filter", lag_s=LAG_S)
    for o in obs:
        tr.update(o)
    early = tr.take_delayed()
    last = obs[-1].timestamp_s
    assert tr.release(last + 0.5 * LAG_S) == []  # not silent for the lag yet
    rest = tr.release(last + LAG_S)
    assert [e.packet_id for e in early + rest] == [o.packet_id for o in obs]
    assert tr.release(last + 2 * LAG_S) == [] and tr.flush() == []


def test_causal_streaming_is_lag_zero(sim):
    obs = group_packets(sim.packets)[:60]
    causal = Tracker(sim.site, "filter")
    lag0 = Tracker(sim.site, "filter", lag_s=0.0)
    for o in obs:
        e, _ = causal.update(o)
        assert lag0.update(o) == (None, PENDING)
        (d,) = lag0.take_delayed()
        assert d.packet_id == e.packet_id
        np.testing.assert_allclose(d.position_m, e.position_m, atol=1e-9)


def test_live_lag_is_bounded():
    with pytest.raises(ValueError, match="live_lag_s"):
        LiveConfig(live_lag_s=0.3)
    assert LiveConfig().live_lag_s == LAG_S


def test_the_live_default_is_full_at_a_2d_site_unless_chosen():
    """Issue 15's rule: ``filter`` becomes the 2-D live default only once its
    live variant meets the issue's goals (docs/methods.md, "The live default")."""
    site = simulate(ScenarioConfig(size_m=4.0, step_m=0.5, duration_s=0.05), seed=3).site
    assert LiveConfig().method is None
    assert LiveConfig().method_for(site) == "full"  # DEFAULT_LIVE_METHOD
    assert LiveConfig(method="filter").method_for(site) == "filter"


def test_a_checkpoint_pickled_by_the_single_module_tracker_still_loads():
    # checkpoints written while TrackState lived in radiopose/tracker.py
    st = PipelineState(track_states={"aa": TrackState(1.0, 1.0, (1.0, 2.0, 1.0))})
    old = pickle.dumps(st, protocol=0).replace(b"radiopose.tracker.paper", b"radiopose.tracker")
    assert b"radiopose.tracker\nTrackState" in old
    loaded = pickle.loads(old)
    assert loaded.track_states["aa"].position_m == (1.0, 2.0, 1.0)


def _post_all(client, tiny, per_batch: int = 40) -> None:
    """Every receiver's frames, in batches, receivers interleaved in time."""
    chunks = {r: list(range(0, len(tiny.frames[r]), per_batch)) for r in RECEIVERS}
    for i in range(max(len(c) for c in chunks.values())):
        for r in RECEIVERS:
            if i < len(chunks[r]):
                s = chunks[r][i]
                body = {
                    "receiver_id": r,
                    "batch_id": f"{r}-{i}",
                    "frames": frame_dicts(tiny.frames[r].take(slice(s, s + per_batch))),
                }
                assert client[r].post("/api/v1/reports", json=body).status_code < 300


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_live_filter_answers_every_packet_with_its_uncertainty(tiny, db_url, tmp_path: Path):
    db = Database(db_url)
    import_site_dir(db, tiny.site_dir)
    tokens = {r: create_token(db, "receiver", r) for r in RECEIVERS}
    tokens["viewer"] = create_token(db, "viewer")
    truth = read_packets_csv(tiny.root / "pcaps" / "pcap_truth.csv")
    n_packets = len(set(truth.packet_id))
    with run_server(db, fast_live(method="filter", live_lag_s=LAG_S)) as srv:
        clients = {r: srv.client(tokens[r]) for r in RECEIVERS}
        _post_all(clients, tiny)
        wait_for(lambda: len(db.packets()) == n_packets, 60)
        wait_for(lambda: len(db.estimates(limit=10**6)) == n_packets, 60)  # the idle flush
        live = (
            srv.client(tokens["viewer"])
            .get("/api/v1/estimates", params={"transmitter": tiny.transmitter})
            .json()
        )
    assert all(p["reason"] is None for p in db.packets())
    assert len(live) == n_packets and {e["method"] for e in live} == {"filter"}
    assert all(e["position_std_m"] >= 0 and e["azimuth_std_deg"] >= 0 for e in live)
    assert [e["timestamp_s"] for e in live] == sorted(e["timestamp_s"] for e in live)
    # the export carries the uncertainty and replays exactly with the same lag offline
    site_dir, _frames, packets_csv, estimates_csv = export_run(db, tmp_path / "export")
    exported = read_estimates_csv(estimates_csv)
    assert exported.position_std_m is not None and len(exported) == n_packets
    again = locate(
        load_site(site_dir),
        read_packets_csv(packets_csv),
        "filter",
        REPLAY_CONFIG,
    )
    write_estimates_csv(again.estimates, tmp_path / "relocated.csv")
    assert (tmp_path / "relocated.csv").read_bytes() == estimates_csv.read_bytes()
    db.close()


def test_an_old_database_gains_the_uncertainty_columns(db_url):
    db = Database(db_url)
    row = {
        "timestamp_s": 1.0, "transmitter": "aa", "packet_id": "1", "x_m": 1.0, "y_m": 2.0,
        "z_m": 1.0, "azimuth_deg": 10.0, "pitch_deg": 0.0, "roll_deg": 0.0, "method": "full",
        "last_report_s": 5.0, "estimated_s": 5.1,
    }  # fmt: skip
    db.commit_step("0/1", 1, b"", {}, [], [row])
    with db.engine.begin() as c:  # what a database of the previous release looks like
        for col in ("position_std_m", "azimuth_std_deg"):
            c.execute(text(f"ALTER TABLE estimates DROP COLUMN {col}"))
    url = db.url
    db.close()
    for create in (False, True):  # a worker's connection, then the server's
        again = Database(url, create=create)
        (old,) = again.estimates()
        assert old["position_std_m"] is None and old["x_m"] == 1.0
        again.close()
    again = Database(url)
    again.commit_step(
        "0/1",
        2,
        b"",
        {},
        [],
        [
            {
                **row,
                "packet_id": "2",
                "timestamp_s": 2.0,
                "position_std_m": 0.3,
                "azimuth_std_deg": 4.0,
            }
        ],
    )
    old, new = again.estimates()
    assert (old["azimuth_std_deg"], new["position_std_m"], new["azimuth_std_deg"]) == (
        None,
        0.3,
        4.0,
    )
    again.close()
