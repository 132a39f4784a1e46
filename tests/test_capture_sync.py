"""Synchronisation: clock estimation, the ambiguity rule, streaming == batch,
real captures, simulator round trip, the ``radiopose sync`` command."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.capture.records import FrameRecords, read_capture, read_pcap
from radiopose.capture.sync import (
    ClockModel,
    StreamingMatcher,
    SyncConfig,
    TransmitterConflictError,
    _fit_clock,
    estimate_clocks,
    match_packets,
    synchronise,
)
from radiopose.capture.writer import read_pcap_truth, write_receiver_pcaps
from radiopose.cli import main
from radiopose.packets import Packets, group_packets

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"
needs_data = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"real captures not found at {DATA} (see shared/data/README.md)"
)
ESP32 = [
    DATA / f"probe-request-project_sc6-61_position_{k}_2024-03-17_anonymized.pcap" for k in (1, 2)
]
S = 1_000_000_000


def _frames(rows: list[tuple[str, float, str, float]], tx: str = "02:00:00:00:00:01"):
    """FrameRecords from (receiver, time_s, hash label, rss)."""
    obj = lambda xs: np.asarray(xs, dtype=object).reshape(-1)  # noqa: E731
    return FrameRecords(
        obj([r[0] for r in rows]),
        np.asarray([round(r[1] * S) for r in rows], dtype=np.int64).reshape(-1),
        obj([r[2] for r in rows]),
        obj([tx] * len(rows)),
        np.asarray([r[3] for r in rows], dtype=np.float64).reshape(-1),
    )


def _same(a: Packets, b: Packets) -> None:
    for name in ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def _concat(parts: list[Packets]) -> Packets:
    return Packets(
        *(
            np.concatenate([getattr(p, n) for p in parts])
            for n in ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm")
        )
    )


# --------------------------------------------------------------------------
# the ambiguity rule


def test_rule_unique_missing_duplicate_spread_and_far_repeat() -> None:
    rows = [
        # packet heard by all three
        ("a", 10.0, "h1", -50),
        ("b", 10.001, "h1", -51),
        ("c", 10.002, "h1", -52),
        # c missed it: two rows
        ("a", 20.0, "h2", -60),
        ("b", 20.003, "h2", -61),
        # b recorded it twice within the tolerance: ambiguous
        ("a", 30.0, "h3", -40),
        ("b", 30.0, "h3", -41),
        ("b", 30.002, "h3", -41),
        # chained over 8 ms although each step is within 5 ms: ambiguous
        ("a", 40.0, "h4", -40),
        ("b", 40.004, "h4", -40),
        ("c", 40.008, "h4", -40),
        # the same bytes again 100 s later: a separate packet
        ("a", 110.0, "h1", -70),
    ]
    packets, counts, repeated = match_packets(_frames(rows), ["a", "b", "c"], tolerance_s=0.005)
    groups = group_packets(packets)
    assert [(g.receiver_ids, list(g.rss_dbm)) for g in groups] == [
        (("a", "b", "c"), [-50, -51, -52]),
        (("a", "b"), [-60, -61]),
        (("a",), [-70]),
    ]
    assert groups[0].timestamp_s == pytest.approx(10.001)
    assert counts.packets == 3
    assert counts.packets_by_receivers == {1: 1, 2: 1, 3: 1}
    assert counts.ambiguous_duplicate == 1
    assert counts.ambiguous_spread == 1
    assert counts.ambiguous_frames == 6
    assert repeated.repeated == 1
    assert (repeated.shared, repeated.shared_matched) == (4, 2)
    assert (repeated.shared_ambiguous, repeated.shared_apart) == (2, 0)


def test_hash_accounting_separates_ambiguous_from_apart() -> None:
    rows = [
        ("a", 1.0, "m", -50),
        ("b", 1.001, "m", -50),  # matched
        ("a", 2.0, "d", -50),
        ("a", 2.0005, "d", -50),
        ("b", 2.001, "d", -50),  # duplicate
        ("a", 3.0, "f", -50),
        ("b", 900.0, "f", -50),  # same bytes, far apart
        ("a", 4.0, "s", -50),  # one receiver only: not shared
    ]
    _, _, h = match_packets(_frames(rows), ["a", "b"], tolerance_s=0.005)
    assert (h.shared, h.shared_matched, h.shared_ambiguous, h.shared_apart) == (3, 1, 1, 1)


def _frames_tx(rows: list[tuple[str, float, str, str]]) -> FrameRecords:
    """FrameRecords from (receiver, time_s, hash label, transmitter); row k's RSS is
    ``-40 - k`` dBm (it tells the frame of a packet row)."""
    frames = _frames([(r, t, h, -40.0 - k) for k, (r, t, h, _) in enumerate(rows)])
    return FrameRecords(
        frames.receiver_id,
        frames.timestamp_ns,
        frames.frame_sha256,
        np.asarray([r[3] for r in rows], dtype=object).reshape(-1),
        frames.rss_dbm,
    )


def test_one_hash_naming_two_transmitters_is_refused_not_rewritten() -> None:
    # the walkthrough's capture: before, all three rows became one packet of 'phone'
    rows = [
        ("c", 1.000, "h", "phone"),
        ("a", 1.001, "h", "aa:bb:cc:dd:ee:ff"),
        ("b", 1.002, "h", "aa:bb:cc:dd:ee:ff"),
    ]
    with pytest.raises(TransmitterConflictError, match="same frame_sha256") as err:
        match_packets(_frames_tx(rows), ["a", "b", "c"])
    assert err.value.rows == (0, 1) and err.value.column == "transmitter"
    assert "'aa:bb:cc:dd:ee:ff' at receiver a (1.001000 s), but 'phone' at receiver c" in str(
        err.value
    )
    # far apart in time (two chains) it is the same contradiction
    far = [("a", 1.0, "h", "phone"), ("b", 500.0, "h", "watch")]
    with pytest.raises(TransmitterConflictError):
        match_packets(_frames_tx(far), ["a", "b"])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["a", "b", "c"]),
            st.integers(0, 40).map(lambda k: k * 0.002),
            st.sampled_from(["h1", "h2", "h3"]),
            st.sampled_from(["phone", "watch"]),
        ),
        min_size=1,
        max_size=12,
    )
)
def test_a_packet_is_named_by_its_frames_transmitter_or_refused(rows) -> None:
    frames = _frames_tx(rows)
    mixed = any(len({tx for _, _, h2, tx in rows if h2 == h}) > 1 for h in {r[2] for r in rows})
    if mixed:
        with pytest.raises(TransmitterConflictError):
            match_packets(frames, ["a", "b", "c"])
    else:
        packets, _, _ = match_packets(frames, ["a", "b", "c"])
        for k in range(len(packets)):  # each row is named by its own frame's transmitter
            assert packets.transmitter[k] == rows[round(-40.0 - packets.rss_dbm[k])][3]
    # the streaming twin never stops: a mixed chain is dropped and counted
    m = StreamingMatcher(["a", "b", "c"], max_lag_s=float("inf"))
    order = np.argsort(frames.timestamp_ns, kind="stable")
    out = _concat([m.push(frames.take(order)), m.flush()])
    assert (m.counts.ambiguous_transmitter > 0) <= mixed
    for k in range(len(out)):
        assert out.transmitter[k] == rows[round(-40.0 - out.rss_dbm[k])][3]


def test_streaming_drops_and_counts_a_chain_naming_two_transmitters() -> None:
    rows = [
        ("a", 1.000, "h", "phone"),
        ("b", 1.001, "h", "watch"),  # one frame, two transmitters: neither is trusted
        ("a", 2.000, "g", "phone"),
        ("b", 2.001, "g", "phone"),
    ]
    m = StreamingMatcher(["a", "b"])
    out = _concat([m.push(_frames_tx(rows)), m.flush()])
    assert list(out.transmitter) == ["phone", "phone"] and set(out.packet_id) == {"0"}
    assert m.counts.ambiguous_transmitter == 1
    assert m.counts.ambiguous_frames == 2 and m.counts.packets == 1


def test_rule_uses_the_clock_models() -> None:
    rows = [("a", 100.0, "h", -50), ("b", 100.7, "h", -55)]
    frames = _frames(rows)
    _, counts, _ = match_packets(frames, ["a", "b"])
    assert counts.packets_by_receivers == {1: 2}
    clocks = {"b": ClockModel("b", offset_ns=700_000_000, method="offset")}
    packets, counts, _ = match_packets(frames, ["a", "b"], clocks)
    assert counts.packets_by_receivers == {2: 1}
    assert packets.timestamp_s[0] == pytest.approx(100.0)


def test_clock_model_inversion() -> None:
    c = ClockModel("b", offset_ns=-900_000_000, drift_ppm=-5.5, epoch_ns=1_000 * S)
    t_ref = np.array([0, 1_000 * S, 50_000 * S], dtype=np.int64) + 1_700_000_000 * S
    c2 = ClockModel("b", c.offset_ns, c.drift_ppm, int(t_ref[1]))
    t_rx = (
        t_ref + c2.offset_ns + np.rint(c2.drift_ppm * 1e-6 * (t_ref - c2.epoch_ns)).astype(np.int64)
    )
    assert np.all(np.abs(c2.to_reference_ns(t_rx) - t_ref) <= 2)


# --------------------------------------------------------------------------
# clock estimation


def test_robust_fit_with_many_outliers() -> None:
    rng = np.random.default_rng(3)
    n = 400
    t_ref = np.sort(rng.uniform(0, 86_400, n))
    true_off, true_drift = -0.9, -5.5e-6
    d = true_off + true_drift * (t_ref - 40_000) + rng.normal(0, 3e-4, n)
    out = rng.random(n) < 0.45  # coincidences far apart in time
    d[out] = rng.uniform(-80_000, 80_000, out.sum())
    t0 = 1_700_000_000
    ref_ns = np.round((t0 + t_ref) * S).astype(np.int64)
    rx_ns = ref_ns + np.round(d * S).astype(np.int64)
    off_ns, drift_ppm, epoch_ns, n_in, rms, method = _fit_clock(ref_ns, rx_ns, SyncConfig())
    assert method == "offset+drift"
    assert n_in == int((~out).sum())
    assert drift_ppm == pytest.approx(-5.5, abs=0.05)
    expect = true_off + true_drift * (epoch_ns / S - t0 - 40_000)
    assert off_ns / S == pytest.approx(expect, abs=1e-4)
    assert rms < 5e-4


def test_fit_without_enough_pairs() -> None:
    one = np.array([5 * S], dtype=np.int64)
    assert _fit_clock(one, one + S, SyncConfig())[-1] == "none"
    assert _fit_clock(one[:0], one[:0], SyncConfig())[-1] == "none"
    two = np.array([5 * S, 6 * S], dtype=np.int64)
    off, drift, _, n_in, _, method = _fit_clock(two, two + S, SyncConfig())
    assert (off, drift, n_in, method) == (S, 0.0, 2, "offset")


# --------------------------------------------------------------------------
# real captures


@pytest.fixture(scope="module")
def esp32() -> list:
    if not DATA.is_dir():
        pytest.skip(f"real captures not found at {DATA} (see shared/data/README.md)")
    return [read_pcap(p, rid) for p, rid in zip(ESP32, ("pos1", "pos2"), strict=True)]


def test_esp32_offset_drift_and_matches(esp32: list) -> None:
    _, report = synchronise(esp32)
    clock = report.clocks[1]
    assert clock.receiver_id == "pos2"
    assert clock.method == "offset+drift"
    assert clock.offset_s == pytest.approx(-0.90, abs=0.02)  # "about 0.9 s apart"
    assert -8.0 < clock.drift_ppm < -3.0  # several ppm
    assert clock.inliers >= 100
    assert clock.residual_rms_s < 1e-3
    assert report.counts.packets_by_receivers[2] == 108
    assert report.counts.ambiguous_duplicate == report.counts.ambiguous_spread == 0
    # All 154 byte-identical frames are accounted for: 108 matched on the clock
    # line, 46 only ever hours apart (the same bytes sent again, not one packet).
    h = report.hashes
    assert (h.shared, h.shared_matched, h.shared_ambiguous, h.shared_apart) == (154, 108, 0, 46)
    assert any("hashes heard by 2+ receivers: 154" in line for line in report.lines())

    # Every common hash is either matched or far (hours) from any copy at the other receiver.
    a, b = esp32[0].frames, esp32[1].frames
    tb = clock.to_reference_ns(b.timestamp_ns)
    common = set(a.frame_sha256) & set(b.frame_sha256)
    assert len(common) == 154
    gaps = []
    for h in common:
        ta = a.timestamp_ns[a.frame_sha256 == h]
        gaps.append(np.min(np.abs(ta[:, None] - tb[b.frame_sha256 == h][None, :])) / S)
    gaps = np.asarray(gaps)
    assert np.count_nonzero(gaps < 0.005) == 108
    assert np.all((gaps < 0.002) | (gaps > 1000))

    # A fixed window without clock estimation misses most genuine pairs.
    _, raw, _ = match_packets(FrameRecords.concat([a, b]), ["pos1", "pos2"], tolerance_s=0.005)
    assert raw.packets_by_receivers.get(2, 0) == 0


def test_esp32_reference_swapped(esp32: list) -> None:
    _, report = synchronise(esp32, SyncConfig(reference="pos2"))
    assert report.reference == "pos2"
    assert report.clocks[0].method == "reference"
    assert report.clocks[1].offset_s == pytest.approx(0.90, abs=0.02)
    assert report.counts.packets_by_receivers[2] == 108


def test_esp32_streaming_equals_batch(esp32: list) -> None:
    frames = FrameRecords.concat([c.frames for c in esp32])
    receivers = ["pos1", "pos2"]
    clocks = estimate_clocks(frames, receivers)
    batch, counts, _ = match_packets(frames, receivers, clocks)
    ordered = frames.take(np.argsort(frames.timestamp_ns, kind="stable"))
    m = StreamingMatcher(receivers, clocks, max_lag_s=3600.0)
    parts = [m.push(ordered.take(slice(k, k + 97))) for k in range(0, len(ordered), 97)]
    parts.append(m.flush())
    _same(_concat(parts), batch)
    assert m.counts == counts


# --------------------------------------------------------------------------
# simulator round trip

RX = ["rx1", "rx2", "rx3", "rx4"]


def _scenario(n_packets: int = 1500, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 900.0, n_packets))
    tx = np.where(rng.random(n_packets) < 0.5, "02:00:00:00:00:0a", "02:00:00:00:00:0b")
    rows: dict[str, list] = {
        k: [] for k in ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm")
    }
    for i in range(n_packets):
        for r in RX:
            rows["packet_id"].append(str(i))
            rows["timestamp_s"].append(t[i])
            rows["transmitter"].append(tx[i])
            rows["receiver_id"].append(r)
            rows["rss_dbm"].append(rng.uniform(-95.0, -25.0))
    return rows


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("sim")
    sim = write_receiver_pcaps(
        _scenario(),
        out,
        rng=np.random.default_rng(7),
        clock_offset_s={"rx2": 0.35, "rx3": -0.8, "rx4": 2.1},
        drift_ppm={"rx2": 12.0, "rx3": -7.0, "rx4": 3.0},
        jitter_s=50e-6,
        loss_fraction=0.1,
        duplicate_fraction=0.02,
        epoch_s=1_700_000_000.0,
        fcs={"rx3": True},
        antenna_signals={"rx4": True},
    )
    return out, sim


def _canonical(packets: Packets) -> tuple[list[tuple], np.ndarray]:
    """Packets in time order as (transmitter, receivers, RSS) and their times."""
    groups = sorted(group_packets(packets), key=lambda g: g.timestamp_s)
    keys = [(g.transmitter, g.receiver_ids, tuple(g.rss_dbm.tolist())) for g in groups]
    return keys, np.array([g.timestamp_s for g in groups])


def _assert_same_packets(a: Packets, b: Packets, time_tol_s: float = 2e-4) -> None:
    keys_a, t_a = _canonical(a)
    keys_b, t_b = _canonical(b)
    assert keys_a == keys_b
    assert np.max(np.abs(t_a - t_b), initial=0.0) < time_tol_s


def test_simulate_sync_round_trip(simulated) -> None:
    out, sim = simulated
    truth = read_pcap_truth(out)
    _same(truth, sim.truth)
    caps = [read_capture(sim.paths[r]) for r in RX]
    packets, report = synchronise(caps)
    assert [c.method for c in report.clocks] == ["reference"] + ["offset+drift"] * 3
    got = {c.receiver_id: c for c in report.clocks}
    for r, drift in (("rx2", 12.0), ("rx3", -7.0), ("rx4", 3.0)):
        assert got[r].drift_ppm == pytest.approx(drift, abs=0.2)
    # Same packets, receivers and RSS; times well within the tolerance.
    assert len(packets) > 4000
    _assert_same_packets(packets, truth)
    assert report.counts.ambiguous_duplicate > 0  # the duplicates were seen and dropped


def test_simulated_streaming_equals_batch_with_bounded_memory(simulated) -> None:
    _, sim = simulated
    frames = FrameRecords.concat([read_pcap(sim.paths[r]).frames for r in RX])
    clocks = estimate_clocks(frames, RX)
    batch, counts, _ = match_packets(frames, RX, clocks)
    # frames arrive per receiver in time order, receivers interleaved by wall-clock
    order = np.argsort(frames.timestamp_ns, kind="stable")
    rng = np.random.default_rng(11)
    cuts = np.sort(rng.choice(np.arange(1, len(order)), 300, replace=False))
    m = StreamingMatcher(RX, clocks, tolerance_s=0.005, max_lag_s=30.0)
    parts, peak = [], 0
    for chunk in np.split(order, cuts):
        parts.append(m.push(frames.take(chunk)))
        peak = max(peak, m.open_frames)
    parts.append(m.flush())
    _same(_concat(parts), batch)
    assert m.counts == counts
    assert m.open_frames == 0
    assert peak < len(frames) / 10  # a window, not the whole capture


def test_streaming_late_frames_are_counted() -> None:
    m = StreamingMatcher(["a", "b"], max_lag_s=1.0)
    m.push(_frames([("a", 0.0, "h0", -50), ("b", 0.0, "h0", -50)]))
    m.push(_frames([("a", 10.0, "h1", -50)]))  # b lags by 10 s > 1 s: closes up to 9 s
    m.push(_frames([("b", 5.0, "h2", -50)]))  # too late
    out = m.flush()
    assert m.counts.late_frames == 1
    assert m.counts.packets_by_receivers == {1: 1, 2: 1}
    assert len(out) == 1


# --------------------------------------------------------------------------
# the command


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_one_receiver_id_rule_at_every_entry(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A receiver id follows the transmitter ids' rule wherever it enters: a
    comma or a space is one line naming where (helper-63: `sync --receiver`
    refused a comma that a CSV capture let through quoted, and a space passed
    everywhere)."""
    _, sim = simulated
    hexd = "a" * 64
    for bad in ("r,x", "r x"):
        cap = tmp_path / "cap.csv"
        with open(cap, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["receiver_id", "timestamp_s", "frame_sha256", "transmitter", "rss_dbm"])
            w.writerow(["rx1", "1.0", hexd, "phone", "-50"])
            w.writerow([bad, "1.0", hexd, "phone", "-50"])
        code, _, err = _run(["sync", str(cap), "-o", str(tmp_path / "o.csv")], capsys)
        assert code == 2 and err.count("\n") == 1
        assert "cap.csv:3, column 'receiver_id': not a receiver id" in err
        code, _, err = _run(
            ["sync", str(sim.paths["rx1"]), "-o", str(tmp_path / "o.csv"),
             "--receiver", f"{bad}={sim.paths['rx1']}"], capsys,
        )  # fmt: skip
        assert code == 2 and "not a receiver id" in err and err.count("\n") == 1
        packets = tmp_path / "packets.csv"
        packets.write_text(
            f'packet_id,timestamp_s,transmitter,receiver_id,rss_dbm\n0,1.0,phone,"{bad}",-50\n'
        )
        from radiopose.errors import InputError
        from radiopose.packets import read_packets_csv

        with pytest.raises(InputError, match=r"packets\.csv:2, column 'receiver_id'"):
            read_packets_csv(packets)
        code, _, err = _run(["receiver", "--server", "http://127.0.0.1:1", "--token", "t",
                             "--id", bad, "--replay", str(cap)], capsys)  # fmt: skip
        assert code == 2 and "--id: not a receiver id" in err
        code, _, err = _run(["token", "create", "--db", str(tmp_path / "t.db"), "--role",
                             "receiver", "--receiver", bad], capsys)  # fmt: skip
        assert code == 2 and "--receiver: not a receiver id" in err
    assert not (tmp_path / "o.csv").exists()
    # a pcap's receiver id taken from its file name follows the rule too (helper-66)
    spaced = tmp_path / "r x.pcap"
    spaced.write_bytes(sim.paths["rx1"].read_bytes())
    code, _, err = _run(["sync", str(spaced), "-o", str(tmp_path / "o.csv")], capsys)
    assert code == 2 and "receiver id 'r x' (the file name is)" in err and "--receiver" in err
    args = ["sync", str(spaced), "--receiver", f"rx1={spaced}", "-o", str(tmp_path / "o.csv")]
    assert _run(args, capsys)[0] == 0


def test_cli_sync_simulated(simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_dir, sim = simulated
    target = tmp_path / "packets.csv"
    code, out, err = _run(
        ["sync", *(str(sim.paths[r]) for r in RX), "-o", str(target), "--tolerance-ms", "5"],
        capsys,
    )
    assert code == 0, err
    assert "offset" in out and "drift" in out and "4 receivers:" in out
    with open(target, newline="") as fh:
        header = next(csv.reader(fh))
    assert header == ["packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm"]
    from radiopose.packets import read_packets_csv

    _assert_same_packets(read_packets_csv(target), read_pcap_truth(out_dir))


def test_cli_receiver_names_and_csv(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, sim = simulated
    target = tmp_path / "p.csv"
    args = ["sync", str(sim.paths["rx1"]), str(sim.paths["rx2"]), "-o", str(target)]
    code, out, err = _run([*args, "--receiver", f"north={sim.paths['rx2']}"], capsys)
    assert code == 0, err
    assert "north: offset" in out
    # the CSV capture form of the same frames gives the same packets
    frames = FrameRecords.concat([read_pcap(sim.paths[r]).frames for r in ("rx1", "rx2")])
    cap_csv = tmp_path / "cap.csv"
    with open(cap_csv, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["receiver_id", "timestamp_s", "frame_sha256", "transmitter", "rss_dbm"])
        for i in range(len(frames)):
            w.writerow(
                [
                    frames.receiver_id[i],
                    f"{frames.timestamp_ns[i] / S:.9f}",
                    frames.frame_sha256[i],
                    frames.transmitter[i],
                    frames.rss_dbm[i],
                ]
            )
    target2 = tmp_path / "p2.csv"
    code, _, err = _run(["sync", str(cap_csv), "-o", str(target2), "-q"], capsys)
    assert code == 0, err
    code, _, err = _run([*args[:3], "-o", str(target), "-q"], capsys)
    from radiopose.packets import read_packets_csv

    _assert_same_packets(read_packets_csv(target2), read_packets_csv(target), 1e-6)


@pytest.mark.parametrize(
    ("make", "extra", "message"),
    [
        (lambda d: d.joinpath("e.pcap").write_bytes(b""), [], "empty file"),
        (lambda d: d.joinpath("e.pcap").write_bytes(b"\x93garbage" * 9), [], "not a pcap"),
        (lambda d: None, [], "file not found"),
        (lambda d: d.joinpath("e.pcap").write_bytes(b"\xd4\xc3\xb2\xa1\x02"), [], "truncated"),
        (None, ["--receiver", "x=other.pcap"], "unknown capture other.pcap"),
        (None, ["--receiver", "nonsense"], "expects ID=FILE"),
        (None, ["--reference", "rx9"], "unknown reference receiver 'rx9'"),
        (None, ["--tolerance-ms", "0"], "--tolerance-ms"),
    ],
)
def test_cli_bad_input_one_line_no_output(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str], make, extra, message
) -> None:
    _, sim = simulated
    target = tmp_path / "never.csv"
    if make is None:
        files = [str(sim.paths["rx1"])]
    else:
        make(tmp_path)
        files = [str(sim.paths["rx1"]), str(tmp_path / "e.pcap")]
    code, _, err = _run(["sync", *files, "-o", str(target), *extra], capsys)
    assert code == 2
    assert message in err
    assert err.count("\n") == 1 and err.startswith("radiopose: ")
    assert not target.exists()
    assert not list(tmp_path.glob(".never.csv*"))


def test_cli_one_hash_naming_two_transmitters_names_the_rows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    head = "receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm\n"
    h = "a" * 64
    one = tmp_path / "mixtx.csv"
    one.write_text(
        head + f"rx3,1.000,{h},phone,-61\nrx1,1.001,{h},aa:bb:cc:dd:ee:ff,-50\n"
        f"rx2,1.002,{h},aa:bb:cc:dd:ee:ff,-60\n"
    )
    target = tmp_path / "o.csv"
    code, _, err = _run(["sync", str(one), "-o", str(target), "-q"], capsys)
    assert code == 2
    assert err == (
        f"radiopose: {one}:3, column 'transmitter': 'aa:bb:cc:dd:ee:ff', but line 2 has "
        "'phone' for the same frame_sha256 aaaaaaaaaaaa…; a frame's hash covers its "
        "transmitter address, so these cannot be one frame\n"
    )
    assert not target.exists()
    # across two capture files: both named
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text(head + f"rx1,1.000,{'b' * 64},phone,-50\nrx1,2.000,{h},phone,-50\n")
    b.write_text(head + f"rx2,2.001,{h},watch,-50\n")
    code, _, err = _run(["sync", str(a), str(b), "-o", str(target), "-q"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"radiopose: {b}:2, column 'transmitter': 'watch', but {a}:3 has 'phone'")
    assert not target.exists()
    # the same transmitter written in two ways is one transmitter
    b.write_text(head + f"rx2,2.001,{h},PHONE,-50\n")
    code, _, err = _run(["sync", str(a), str(b), "-o", str(target), "-q"], capsys)
    assert code == 0, err


def test_cli_duplicate_receiver_ids(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = [("1", 1.0, "02:00:00:00:00:01", "rx", -50.0)]
    a = write_receiver_pcaps(rows, tmp_path / "a", rng=np.random.default_rng(0)).paths["rx"]
    b = write_receiver_pcaps(rows, tmp_path / "b", rng=np.random.default_rng(0)).paths["rx"]
    code, _, err = _run(["sync", str(a), str(b), "-o", str(tmp_path / "o.csv")], capsys)
    assert code == 2 and "appears in both" in err
    code, _, err = _run(
        ["sync", str(a), str(b), "-o", str(tmp_path / "o.csv"), "--receiver", f"rx2={b}"], capsys
    )
    assert code == 0, err


def test_cli_output_path_errors_are_one_line(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, sim = simulated
    rx1 = sim.paths["rx1"]
    before = rx1.read_bytes()
    cases = [
        (str(tmp_path), "is a directory"),  # -o names a directory
        (str(rx1 / "x.csv"), "a parent is not a directory"),
        (str(rx1), "would overwrite one of the captures"),
    ]
    for target, message in cases:
        code, _, err = _run(["sync", str(rx1), str(sim.paths["rx2"]), "-o", target], capsys)
        assert code == 2, target
        assert message in err
        assert err.count("\n") == 1 and err.startswith("radiopose: ")
    assert rx1.read_bytes() == before
    code, _, err = _run(
        [
            "sync",
            str(rx1),
            "-o",
            str(tmp_path / "o.csv"),
            "--receiver",
            f"a={rx1}",
            "--receiver",
            f"b={rx1}",
        ],
        capsys,
    )
    assert code == 2 and "already named 'a'" in err


def test_default_reference_skips_a_receiver_without_frames(simulated, tmp_path: Path) -> None:
    _, sim = simulated
    nothing = write_receiver_pcaps(
        [("1", 1.0, "02:00:00:00:00:01", "mute", 5.0)],  # +5 dBm: implausible, skipped
        tmp_path / "m",
        rng=np.random.default_rng(0),
    ).paths["mute"]
    caps = [read_pcap(nothing), *(read_pcap(sim.paths[r]) for r in RX)]
    assert caps[0].stats[0].frames_kept == 0
    _, report = synchronise(caps)
    assert report.reference == "rx1"
    assert sorted(c.method for c in report.clocks[1:]) == ["none"] + ["offset+drift"] * 3


# --------------------------------------------------------------------------
# radiopose simulate --pcap -> radiopose sync


def _packet_rows(path: Path) -> list[list[str]]:
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


# seed 10 has packets no receiver heard (ids once had gaps there); 41 has none;
# 30 s is shorter than the 60 s over which drift used to be fitted
@pytest.mark.parametrize(("seed", "duration_s"), [("10", "70"), ("41", "70"), ("7", "30")])
def test_cli_simulate_pcap_sync_round_trip(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], seed: str, duration_s: str
) -> None:
    """simulate --pcap -> sync gives back the simulator's own packets.csv."""
    sim_dir = tmp_path / "sim"
    code, out, err = _run(
        [
            "simulate",
            "-o",
            str(sim_dir),
            "--seed",
            seed,
            "--pcap",
            "--loss",
            "0.1",
            "--duration-s",
            duration_s,
            "--interval-ms",
            "50",
            "--clock-drift-ppm",
            "30",
        ],
        capsys,
    )
    assert code == 0, err
    pcaps = sorted((sim_dir / "captures").glob("*.pcap"))
    assert [p.name for p in pcaps] == ["rx1.pcap", "rx2.pcap", "rx3.pcap", "rx4.pcap"]
    assert all(str(p) in out for p in pcaps)
    assert not (sim_dir / "captures" / "pcap_truth.csv").exists()  # no duplicates: packets.csv
    synced = tmp_path / "synced.csv"
    code, out, err = _run(["sync", *map(str, pcaps), "-o", str(synced)], capsys)
    assert code == 0, err

    want, got = _packet_rows(sim_dir / "packets.csv"), _packet_rows(synced)
    assert len(got) == len(want) > 1500
    sent = len(_packet_rows(sim_dir / "truth.csv")) - 1
    heard = len({r[0] for r in want[1:]})
    if seed in ("10", "41"):
        assert (sent > heard) == (seed == "10")  # seed 10: some packet nobody heard
    assert {r[0] for r in want[1:]} == {str(i) for i in range(heard)}  # no gaps
    # Every column equal except the time, which carries the receivers' timestamp
    # latency (half-normal, 20 us scale) through the clock correction.
    assert [r[:1] + r[2:] for r in got] == [r[:1] + r[2:] for r in want]
    dt = np.array([float(g[1]) - float(w[1]) for g, w in zip(got[1:], want[1:], strict=True)])
    assert np.all(np.abs(dt) < 1e-4)
    # the receivers' true clocks were recovered
    clocks = {
        r[0]: (float(r[1]), float(r[2]))
        for r in _packet_rows(sim_dir / "captures" / "clocks.csv")[1:]
    }
    assert clocks["rx1"] == (0.0, 0.0)
    for rid in ("rx2", "rx3", "rx4"):
        offset_s, drift_ppm = clocks[rid]
        line = next(x for x in out.splitlines() if x.strip().startswith(f"{rid}: offset"))
        assert "offset+drift" in line
        assert float(line.split("drift ")[1].split()[0]) == pytest.approx(drift_ppm, abs=0.5)
        assert 0.0 <= offset_s <= 1.0


def test_cli_simulate_pcap_duplicates_are_dropped_by_the_rule(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sim_dir = tmp_path / "sim"
    code, _, err = _run(
        ["simulate", "-o", str(sim_dir), "--seed", "42", "--pcap", "--duplicates", "0.05"],
        capsys,
    )
    assert code == 0, err
    synced = tmp_path / "synced.csv"
    code, out, err = _run(
        ["sync", *map(str, sorted((sim_dir / "captures").glob("*.pcap"))), "-o", str(synced)],
        capsys,
    )
    assert code == 0, err
    from radiopose.packets import read_packets_csv

    sim_packets = read_packets_csv(sim_dir / "packets.csv")
    expected = read_packets_csv(sim_dir / "captures" / "pcap_truth.csv")
    got = read_packets_csv(synced)
    n_sim = len(set(sim_packets.packet_id))
    n_kept = len(set(expected.packet_id))
    assert 0 < n_kept < n_sim  # some packets were recorded twice somewhere
    assert f"ambiguous: {n_sim - n_kept} duplicated at a receiver" in out
    _assert_same_packets(got, expected, 1e-4)
    # row for row, ids included (both number the surviving packets in time order)
    want = _packet_rows(sim_dir / "captures" / "pcap_truth.csv")
    assert [r[:1] + r[2:] for r in _packet_rows(synced)] == [r[:1] + r[2:] for r in want]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--duplicates", "1.5"], "--duplicates 1.5 is out of range (allowed: [0, 1])"),
        (["--jitter-us", "-1"], "--jitter-us -1 is out of range (allowed: [0, 1000])"),
        (["--clock-drift-ppm", "nan"], "--clock-drift-ppm nan is out of range"),
        (
            ["--clock-offset-ms", "-1"],
            "--clock-offset-ms -1 is out of range (allowed: [0, 3.6e+06])",
        ),
    ],
)
def test_cli_simulate_pcap_bad_settings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    code, _, err = _run(["simulate", "-o", str(tmp_path / "s"), "--pcap", *extra], capsys)
    assert code == 2 and message in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()


def test_sync_of_captures_without_frames_names_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """CSV captures with a header only name no receiver: the one-line error names
    the files (it named none; helper-63), and nothing is written."""
    cap = tmp_path / "empty.csv"
    cap.write_text("receiver_id,timestamp_s,frame_sha256,transmitter,rss_dbm\n")
    code, _, err = _run(["sync", str(cap), "-o", str(tmp_path / "o.csv")], capsys)
    assert code == 2 and err.count("\n") == 1
    assert f"no frames of any receiver in {cap}" in err
    assert not (tmp_path / "o.csv").exists()
