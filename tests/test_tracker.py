"""Tracker: configuration, pure steps, the five methods, streaming = batch, bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.packets import PacketObservation, Packets, group_packets
from radiopose.tracker import (
    METHODS,
    SKIP_ACQUIRING,
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
    # the paper leaves acquisition open: pooled over 0.1 s by default (0 = per packet)
    assert c.acquisition_window_s == 0.1
    with pytest.raises(InputError, match="k = 0"):
        TrackerConfig(k=0)
    with pytest.raises(InputError, match="primary"):
        TrackerConfig(primary="both")


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
    s1, out = track_step("full", cand, 1.0, s0, TrackerConfig(acquisition_window_s=0.0))
    assert out.ok
    assert s0 == TrackState()
    np.testing.assert_array_equal(cand.positions_m, before)
    assert s1.position_m == out.position_m and s1.last_time_s == 1.0
    pooling, out = track_step("full", cand, 1.0, s0, TrackerConfig())  # the default pools
    assert s0 == TrackState()
    assert not out.ok and len(pooling.pending) == 1 and pooling.last_time_s == 1.0
    top = step_top(cand, 0.0, s0, TrackerConfig())
    assert top.position_m == tuple(cand.positions_m[0])


def _swapped_candidates() -> Candidates:
    """:func:`_two_mode_candidates` with the roles swapped: mode A (2, 2, 12°) has
    70 candidates and the better MSEs."""
    c = _two_mode_candidates()
    a = np.linalg.norm(c.positions_m[:, :2] - 2.0, axis=1) < 1.0
    mse = np.where(a, c.mse_db2 - 1.0, c.mse_db2 + 1.0)  # A: 1–2 dB², B: 2–3 dB²
    extra = np.flatnonzero(~a)[:40]  # 40 more A members: move 40 B ones over
    pos, ori = c.positions_m.copy(), c.orientations_deg.copy()
    pos[extra] = pos[np.flatnonzero(a)[0]]
    ori[extra] = ori[np.flatnonzero(a)[0]]
    mse[extra] = 1.5
    order = np.argsort(mse, kind="stable")
    return Candidates(pos[order], ori[order], mse[order])


@pytest.mark.parametrize("b_at", [0, 2])
def test_pooled_acquisition_waits_for_n_packets_and_follows_the_majority(b_at):
    # two packets favour mode A, one (first or last) mode B: neither the first
    # nor the last packet alone decides
    packets = [_swapped_candidates(), _swapped_candidates()]
    packets.insert(b_at, _two_mode_candidates())
    # one packet at a time: a packet's best mode (B) is taken at once
    per_packet = TrackerConfig(acquisition_window_s=0.0)
    s, out = track_step("full", packets[b_at], 0.0, TrackState(), per_packet)
    assert out.ok and abs(out.orientation_deg[0] - 200.0) < 1.5
    # three pooled: nothing until the third packet, then the pose most packets favour (A)
    cfg = TrackerConfig(acquisition_window_s=0.01)
    s = TrackState()
    outs = []
    for i, cand in enumerate(packets):
        s, out = track_step("full", cand, 0.005 * i, s, cfg)
        outs.append(out)
    assert [o.reason for o in outs[:2]] == [SKIP_ACQUIRING, SKIP_ACQUIRING]
    assert outs[2].ok and abs(outs[2].orientation_deg[0] - 12.0) < 1.5
    assert np.linalg.norm(np.array(outs[2].position_m[:2]) - [2, 2]) < 0.2
    assert s.pending == () and s.position_time_s == pytest.approx(0.01)
    # tracking afterwards is per packet, under the motion models, as in the paper
    s2, out = track_step("full", packets[b_at], 0.1, s, cfg)
    assert out.ok and abs(out.orientation_deg[0] - 12.0) < 1.5 and s2.pending == ()


def test_acquisition_window_with_sparse_packets_is_the_single_packet_rule():
    cfg = TrackerConfig(acquisition_window_s=0.05)
    s, out = track_step("full", _two_mode_candidates(), 0.0, TrackState(), cfg)
    assert out.reason == SKIP_ACQUIRING and len(s.pending) == 1 and s.acquiring_since_s == 0.0
    # the next packet comes after the window: it acquires from itself alone
    s, out = track_step("full", _swapped_candidates(), 1.0, s, cfg)
    assert out.ok and abs(out.orientation_deg[0] - 12.0) < 1.5
    assert s.pending == () and s.acquiring_since_s is None
    for bad in (-1.0, float("nan"), float("inf")):  # inf: no track would ever start
        with pytest.raises(InputError, match="acquisition_window_s"):
            TrackerConfig(acquisition_window_s=bad)


def test_acquisition_retries_every_packet_once_the_window_has_run():
    cfg = TrackerConfig(acquisition_window_s=0.01)
    rng = np.random.default_rng(3)
    scattered = Candidates(  # 5 candidates: no cluster of 10
        rng.uniform(0, 10, (5, 3)),
        np.column_stack([rng.uniform(0, 360, 5), np.zeros((5, 2))]),
        np.linspace(1.0, 2.0, 5),
    )
    s, out = track_step("full", scattered, 0.0, TrackState(), cfg)
    s, out = track_step("full", scattered, 0.02, s, cfg)
    assert not out.ok and out.reason != SKIP_ACQUIRING  # tried: the pool has no cluster
    assert s.acquiring_since_s == 0.0 and [t for t, _ in s.pending] == [0.02]
    s, out = track_step("full", _swapped_candidates(), 0.025, s, cfg)  # tries again at once
    assert out.ok and abs(out.orientation_deg[0] - 12.0) < 1.5


def test_pooled_acquisition_streaming_equals_batch(small_sim):
    cfg = TrackerConfig(acquisition_window_s=0.015)
    res = locate(small_sim.site, small_sim.packets, "full", cfg)
    assert dict(res.summary.skipped).get(SKIP_ACQUIRING, 0) >= 3
    tracker = Tracker(small_sim.site, "full", cfg)
    streamed = [tracker.update(o)[0] for o in group_packets(small_sim.packets)]
    got = [e for e in streamed if e is not None]
    assert len(got) == len(res.estimates) > 0
    np.testing.assert_array_equal(np.array([e.position_m for e in got]), res.estimates.position_m)


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
    twice = [*rows[:4], rows[1]]  # packet 0's rx2 row again, as line 6
    assert rows[1][0] == "0" and rows[4][0] != "0"
    with pytest.raises(
        InputError, match=r"p\.csv:6, column 'receiver_id'.*two rows for receiver.*first on line 3"
    ):
        locate(site, _packets(twice))
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
        Tracker(None, "magic")


def test_config_is_replaceable_and_frozen():
    c = replace(TrackerConfig(), k=50)
    assert c.k == 50
    with pytest.raises(AttributeError):
        c.k = 3


def test_a_state_pickled_before_the_acquisition_fields_still_loads():
    # live-server checkpoints written before TrackState had pending/acquiring_since_s
    import pickle

    s = TrackState(1.0, 1.0, (8.0, 8.0, 1.0), 1.0, (200.0, 0.0, 0.0))  # on mode B
    fields = {k: v for k, v in s.__dict__.items() if k not in ("pending", "acquiring_since_s")}
    old = object.__new__(TrackState)
    old.__dict__.update(fields)
    loaded = pickle.loads(pickle.dumps(old))
    assert loaded.pending == () and loaded.acquiring_since_s is None
    _, out = track_step("full", _two_mode_candidates(), 1.1, loaded, TrackerConfig())
    assert out.ok  # 0.1 s after the last estimate: tracking, not acquiring


@pytest.mark.parametrize("method", ["full", "filter"])
def test_devices_of_one_pattern_and_power_share_the_scorer_tables(small_sim, method):
    """Phones enrolled with the same pattern and transmit power share one set of
    the compiled scorer's tables (each with its own search hints) and the
    candidate arrays; each device's estimates are those of a tracker that saw
    only that device. A device with another power gets its own tables."""
    site = small_sim.site
    d0 = site.devices[0]
    devs = (
        replace(d0, transmitter="aa:00:00:00:00:01"),
        replace(d0, transmitter="aa:00:00:00:00:02"),
        replace(d0, transmitter="aa:00:00:00:00:03", tx_power_dbm=d0.tx_power_dbm + 3.0),
    )
    site = replace(site, devices=devs)
    obs = group_packets(small_sim.packets)
    own = [
        replace(o, transmitter=d.transmitter, packet_id=f"{i}-{o.packet_id}")
        for o in obs
        for i, d in enumerate(devs)
    ]
    together = Tracker(site, method)
    out = [together.update(o)[0] for o in own]
    assert sum(e is not None for e in out) >= 6  # estimates to compare
    a, b, c = (together.device(d.transmitter) for d in devs)
    assert b.scorer is not a.scorer and b.scorer.rows is a.scorer.rows
    assert b.space.positions_m is a.space.positions_m and b.space.transmitter == devs[1].transmitter
    assert c.scorer.rows is not a.scorer.rows
    for d in devs:
        alone = Tracker(site, method)
        mine = [o for o in own if o.transmitter == d.transmitter]
        expect = [alone.update(o)[0] for o in mine]
        got = [e for o, e in zip(own, out, strict=True) if o.transmitter == d.transmitter]
        assert [e is None for e in got] == [e is None for e in expect]
        for g, e in zip(got, expect, strict=True):
            if e is not None:
                assert g.position_m == e.position_m and g.orientation_deg == e.orientation_deg


def test_the_bounded_search_window_is_the_motion_bounds_plus_half_a_cell():
    """``search = "bounded"``: 10 ms after a pose at azimuth 100° on a 1° grid,
    the azimuth window is the rotation bound (360°/s × 10 ms = 3.6°) plus half a
    cell each side, [95.9°, 104.1°], and the positions those within the movement
    bound (10 m/s × 10 ms) plus half the cell diagonal (helper-65's mutant M04,
    which dropped the half cell, was held by a pin only)."""
    from types import SimpleNamespace

    from radiopose.likelihood import HeardRss
    from radiopose.tracker import METHODS, TrackerConfig, TrackState
    from radiopose.tracker.paper import _Grid

    calls = []
    spy = SimpleNamespace(
        supports_window=True,
        score_window=lambda heard, k, positions, lo, span: calls.append((positions, lo, span)),
        score_heard=lambda heard, k: calls.append("whole grid"),
    )
    g = np.arange(0.0, 2.01, 0.1)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    space = SimpleNamespace(
        positions_m=np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)]),
        n_positions=xx.size,
    )
    device = SimpleNamespace(
        config=TrackerConfig(search="bounded"), scorer=spy, space=space,
        engine=_Grid(half_diagonal_m=0.05 * np.sqrt(2.0), n_azimuth=360),
    )  # fmt: skip
    state = TrackState(
        last_time_s=1.0, position_time_s=1.0, position_m=(1.0, 1.0, 1.0),
        orientation_time_s=1.0, orientation_deg=(100.0, 0.0, 0.0),
    )  # fmt: skip
    METHODS["full"].score(device, HeardRss(np.arange(4), np.zeros(4)), 1.01, state)
    ((positions, lo, span),) = calls
    assert lo == pytest.approx(95.9) and span == pytest.approx(8.2)
    d = np.linalg.norm(space.positions_m[positions] - [1.0, 1.0, 1.0], axis=1)
    assert d.max() <= 0.1 + 0.05 * np.sqrt(2.0) + 1e-9
    assert len(positions) == 9  # (1 ± 0.1, 1 ± 0.1): the 3 × 3 cells within 0.171 m
