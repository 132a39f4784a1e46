"""Tracker: configuration, pure steps, the five methods, streaming = batch, bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.packets import PacketObservation, Packets, group_packets
from radiopose.tracker import (
    METHODS,
    SKIP_TOO_FEW_RECEIVERS,
    SKIP_UNKNOWN_TRANSMITTER,
    Candidates,
    Tracker,
    TrackerConfig,
    TrackState,
    locate,
    step_full,
    step_top,
    track_step,
)


def test_config_defaults_are_the_papers():
    c = TrackerConfig()
    assert (c.k, c.orientation_eps_deg, c.orientation_min_samples) == (100, 2.0, 10)
    assert (c.position_eps_m, c.position_min_samples, c.max_speed_mps) == (0.5, 10, 10.0)
    assert (c.max_rotation_deg, c.rotation_period_s, c.primary) == (180.0, 0.5, "position")
    assert c.rotation_model.gap_s == pytest.approx(0.25)
    with pytest.raises(InputError, match="k = 0"):
        TrackerConfig(k=0)
    with pytest.raises(InputError, match="primary"):
        TrackerConfig(primary="both")  # type: ignore[arg-type]


def _two_mode_candidates() -> Candidates:
    """Mode A: 30 candidates near (2, 2) at 12°; mode B: 70 better ones near (8, 8) at 200°."""
    rng = np.random.default_rng(1)
    pa = np.column_stack([rng.normal(2, 0.05, 30), rng.normal(2, 0.05, 30), np.ones(30)])
    pb = np.column_stack([rng.normal(8, 0.05, 70), rng.normal(8, 0.05, 70), np.ones(70)])
    oa = np.column_stack([12.0 + rng.integers(-1, 2, 30), np.zeros((30, 2))])
    ob = np.column_stack([200.0 + rng.integers(-1, 2, 70), np.zeros((70, 2))])
    mse = np.concatenate([np.linspace(2.0, 3.0, 30), np.linspace(1.0, 2.0, 70)])
    order = np.argsort(mse, kind="stable")
    return Candidates(np.vstack([pa, pb])[order], np.vstack([oa, ob])[order], mse[order])


def test_full_picks_best_cluster_without_history():
    out = step_full(_two_mode_candidates(), 0.0, TrackState(), TrackerConfig())
    assert out.ok
    assert np.linalg.norm(np.array(out.position_m[:2]) - [8, 8]) < 0.1
    assert abs(out.orientation_deg[0] - 200.0) < 1.0


def test_rotation_model_keeps_the_track_on_the_reachable_mode():
    state = TrackState(0.0, 0.0, (2.0, 2.0, 1.0), 0.0, (10.0, 0.0, 0.0))
    cand = _two_mode_candidates()
    out = step_full(cand, 0.01, state, TrackerConfig(use_movement_model=False))
    assert out.ok and abs(out.orientation_deg[0] - 12.0) < 1.5  # 3.6° allowed in 10 ms
    free = step_full(
        cand, 0.01, state, TrackerConfig(use_movement_model=False, use_rotation_model=False)
    )
    assert abs(free.orientation_deg[0] - 200.0) < 1.5
    # past the gap cap (0.25 s) the orientation is re-acquired without constraint
    late = step_full(cand, 0.3, state, TrackerConfig(use_movement_model=False))
    assert abs(late.orientation_deg[0] - 200.0) < 1.5


def test_movement_model_rejects_far_clusters():
    state = TrackState(0.0, 0.0, (5.0, 5.0, 1.0), None, None)
    out = step_full(_two_mode_candidates(), 0.005, state, TrackerConfig())
    assert not out.ok and out.reason == "rejected by movement model"


def test_primary_orientation_takes_position_from_the_orientation_cluster():
    cand = _two_mode_candidates()
    out = step_full(cand, 0.0, TrackState(), TrackerConfig(primary="orientation"))
    assert np.linalg.norm(np.array(out.position_m[:2]) - [8, 8]) < 0.1


def test_track_step_is_pure():
    cand = _two_mode_candidates()
    before = cand.positions_m.copy()
    s0 = TrackState()
    s1, out = track_step("full", cand, 1.0, s0, TrackerConfig())
    assert s0 == TrackState()
    np.testing.assert_array_equal(cand.positions_m, before)
    assert s1.position_m == out.position_m and s1.last_time_s == 1.0
    top = step_top(cand, 0.0, s0, TrackerConfig())
    assert top.position_m == tuple(cand.positions_m[0])


def test_every_method_runs_and_counts_add_up(small_sim):
    for m in METHODS:
        res = locate(small_sim.site, small_sim.packets, m)
        s = res.summary
        assert s.packets_in == len(small_sim.truth)
        assert s.estimates_out == len(res.estimates)
        assert s.estimates_out + sum(n for _, n in s.skipped) == s.packets_in
        assert set(res.estimates.method) <= {m}
    assert locate(small_sim.site, small_sim.packets, "top").summary.coverage == 1.0


def test_streaming_equals_batch(small_sim):
    batch = locate(small_sim.site, small_sim.packets, "full")
    tr = Tracker(small_sim.site, "full")
    stream = [e for e, _ in (tr.update(o) for o in group_packets(small_sim.packets)) if e]
    assert [e.packet_id for e in stream] == list(batch.estimates.packet_id)
    np.testing.assert_allclose([e.position_m for e in stream], batch.estimates.position_m)
    assert list(tr.states) == [small_sim.site.devices[0].transmitter.lower()]


def _packets(rows, path="p.csv") -> Packets:
    pid, t, tx, rx, rss = zip(*rows, strict=True)
    return Packets(
        np.array(pid, object),
        np.array(t, float),
        np.array(tx, object),
        np.array(rx, object),
        np.array(rss, float),
        np.arange(2, 2 + len(rows)),
        path,
    )


def _rows(sim, n=4, drop=()):
    tx = sim.site.devices[0].transmitter
    out = []
    for o in group_packets(sim.packets)[:n]:
        for rid, v in zip(o.receiver_ids, o.rss_dbm, strict=True):
            if (o.packet_id, rid) not in drop:
                out.append((o.packet_id, o.timestamp_s, tx, rid, v))
    return out


def test_bad_input_errors(small_sim):
    site = small_sim.site
    with pytest.raises(InputError, match="no packets"):
        locate(
            site,
            _packets([("0", 0.0, "x", "rx1", -50.0)]).__class__(
                *(np.empty(0, object),) * 5, np.empty(0, int), "p.csv"
            ),
        )
    rows = _rows(small_sim)
    bad_rx = [*rows[:3], (rows[3][0], rows[3][1], rows[3][2], "rx99", rows[3][4])]
    with pytest.raises(
        InputError, match=r"p\.csv:5, column 'receiver_id'.*'rx99' is not in the site"
    ):
        locate(site, _packets(bad_rx))
    backwards = [r for r in rows if r[0] == "1"] + [r for r in rows if r[0] == "0"]
    with pytest.raises(InputError, match=r"timestamp_s.*earlier than the previous packet"):
        locate(site, _packets(backwards))
    stranger = [(p, t, "aa:bb:cc:dd:ee:ff", rx, v) for p, t, _, rx, v in rows]
    with pytest.raises(InputError, match="no packet is from an enrolled transmitter"):
        locate(site, _packets(stranger))


def test_unknown_transmitter_and_too_few_receivers_are_counted_skips(small_sim):
    rows = _rows(small_sim, n=6, drop={("2", "rx1"), ("2", "rx2")})
    rows += [("x", 0.5, "aa:bb:cc:dd:ee:ff", "rx1", -50.0)]
    res = locate(small_sim.site, _packets(rows), "top")
    skipped = dict(res.summary.skipped)
    assert skipped == {SKIP_TOO_FEW_RECEIVERS: 1, SKIP_UNKNOWN_TRANSMITTER: 1}
    assert res.summary.estimates_out == 5
    assert any("skipped 1: unknown transmitter" in line for line in res.summary.lines())


def test_streaming_skips_out_of_order_packets(small_sim):
    obs = group_packets(small_sim.packets)
    tr = Tracker(small_sim.site, "top")
    assert tr.update(obs[3])[0] is not None
    est, reason = tr.update(obs[1])
    assert est is None and reason == "timestamp before previous packet"
    pkt = PacketObservation("z", 9.0, "aa:bb:cc:dd:ee:ff", ("rx1",), np.array([-40.0]))
    assert tr.update(pkt) == (None, SKIP_UNKNOWN_TRANSMITTER)


def test_unknown_method():
    with pytest.raises(InputError, match="unknown method"):
        Tracker(None, "magic")  # type: ignore[arg-type]


def test_config_is_replaceable_and_frozen():
    c = replace(TrackerConfig(), k=50)
    assert c.k == 50
    with pytest.raises(AttributeError):
        c.k = 3  # type: ignore[misc]
