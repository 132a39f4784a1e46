"""The library API refuses what the files refuse: packets and settings built in
Python get the same one-line errors as ``packets.csv`` and ``tracker.toml``,
never a hang, a crash deep in a kernel, or NaN estimates."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.packets import PacketObservation, Packets, group_packets
from radiopose.tracker import SKIP_DUPLICATE, Tracker, TrackerConfig, locate

CONFIGS = (TrackerConfig, FilterConfig, Pose3dConfig)
WRONG = {
    "int": (2.5, True, "3", math.nan),
    "float": (math.nan, math.inf, "1.0", None, False),
    "float | None": (math.nan, "1.0", False),
    "bool": (1, "yes", None),
    "str": (3, None),
    "tuple[float, ...]": ((math.nan,), [1.0], (1.0, math.inf), ("1",)),
}


def _typed_fields():
    for cls in CONFIGS:
        for f in dataclasses.fields(cls):
            for value in WRONG.get(str(f.type), ()):
                yield pytest.param(cls, f.name, value, id=f"{cls.__name__}.{f.name}={value!r}")


@pytest.mark.parametrize(("cls", "name", "value"), list(_typed_fields()))
def test_every_setting_of_the_wrong_type_is_a_one_line_error(cls, name, value):
    with pytest.raises(InputError, match=rf"setting {name} = .* must be") as err:
        cls(**{name: value})
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: TrackerConfig(kernel="bogus"), "kernel = 'bogus' is not one of"),
        (lambda: TrackerConfig(k=5000), r"k = 5000 is out of range \[1, 1000\]"),
        (lambda: TrackerConfig(smoothing_lag_s=3600.0), r"smoothing_lag_s = 3600.0 must be in"),
        (lambda: FilterConfig(reentry_interval_s=1e-9), "must be at least 0.001 s"),
        (lambda: FilterConfig(k=0), r"k = 0 must be in \[1, 100000\]"),
        (lambda: Pose3dConfig(acquisition_tilts=0), "acquisition_tilts"),
        (lambda: Pose3dConfig(mode_centres=0), "mode_centres"),
        # these replace the 2-D filter's: refused here, not at the first packet as
        # a "filter setting"
        (lambda: Pose3dConfig(sigma_floor_db=0.0), "3-D filter setting sigma_floor_db"),
        (lambda: Pose3dConfig(proposal_window_s=-1.0), "3-D filter setting proposal_window_s"),
        (lambda: Pose3dConfig(reentry_interval_s=1e-9), "3-D filter setting reentry_interval_s"),
    ],
)
def test_settings_out_of_range_are_one_line_errors(build, message):
    with pytest.raises(InputError, match=message):
        build()


def test_the_streaming_lag_is_bounded(small_sim):
    with pytest.raises(InputError, match=r"lag_s = 3600.0 must be in \[0, 10\] s"):
        Tracker(small_sim.site, "filter", lag_s=3600.0)


# ------------------------------------------------------------------- packets in Python
def _packets(p: Packets, **columns) -> Packets:
    base = {k: getattr(p, k) for k in ("packet_id", "timestamp_s", "transmitter", "receiver_id")}
    return Packets(**{**base, "rss_dbm": p.rss_dbm, **columns})


def _with(p: Packets, column: str, row: int, value: float) -> Packets:
    a = getattr(p, column).copy()
    a[row] = value
    return _packets(p, **{column: a})


BAD_TABLES = [
    # a later row of a packet (row 5 is not a packet's first): its time was never read
    (lambda p: _with(p, "timestamp_s", 5, math.nan), r"row 5 \(from 0\): timestamp nan s"),
    (lambda p: _with(p, "timestamp_s", 0, math.inf), "timestamp inf s"),
    (lambda p: _with(p, "timestamp_s", 0, 1e12), "timestamp 1e\\+12 s"),
    (lambda p: _with(p, "rss_dbm", 5, math.nan), "RSS nan dBm from receiver"),
    (lambda p: _with(p, "rss_dbm", 5, -math.inf), "RSS -inf dBm from receiver"),
    (lambda p: _with(p, "rss_dbm", 5, 1000.0), r"RSS 1000 dBm .* \[-200, 50\] dBm"),
    (lambda p: _packets(p, rss_dbm=p.rss_dbm[:-3]), "columns differ in length: .* rss_dbm"),
    (lambda p: _packets(p, rss_dbm=p.rss_dbm[:, None]), r"rss_dbm has shape \(\d+, 1\)"),
]


@pytest.mark.parametrize("method", ["full", "lms", "filter"])
@pytest.mark.parametrize(("damage", "message"), BAD_TABLES)
def test_a_bad_packets_table_built_in_python_is_a_one_line_error(
    small_sim, method, damage, message
):
    with pytest.raises(InputError, match=message) as err:
        locate(small_sim.site, damage(small_sim.packets), method)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"timestamp_s": math.inf}, "timestamp inf s is not a finite number"),
        ({"timestamp_s": math.nan}, "timestamp nan s is not a finite number"),
        ({"rss_dbm": np.array([-60.0, math.nan, -70.0, -65.0])}, "RSS nan dBm"),
        ({"rss_dbm": np.array([-60.0, -70.0])}, r"4 receivers but RSS of shape \(2,\)"),
        ({"transmitter": "a phone"}, "not a transmitter id"),
    ],
)
@pytest.mark.parametrize("method", ["full", "lms", "filter"])
def test_a_bad_streamed_packet_is_a_one_line_error_and_the_track_lives_on(
    small_sim, method, change, message
):
    obs = group_packets(small_sim.packets)
    good = [o for o in obs if len(o.receiver_ids) == 4][:6]
    tracker = Tracker(small_sim.site, method)
    for o in good[:3]:
        tracker.update(o)
    with pytest.raises(InputError, match=message):
        tracker.update(replace(good[3], **change))
    tracker.update(good[3])  # the state was not touched: the same packet now goes in
    est, reason = tracker.update(good[4])
    assert reason is not None or (est is not None and np.isfinite(est.position_m).all())


def test_a_receiver_twice_in_a_python_packet_names_no_line(small_sim):
    o = group_packets(small_sim.packets)[0]
    twice = replace(o, receiver_ids=(o.receiver_ids[0],) * 2, rss_dbm=o.rss_dbm[:1].repeat(2))
    with pytest.raises(InputError, match="has two rows for receiver") as err:
        Tracker(small_sim.site, "full").update(twice)
    assert "line" not in str(err.value)


def test_rows_of_one_packet_at_different_times_are_an_error(small_sim, tmp_path):
    """A reused packet id (rows 0.375 s apart under one id) was merged into one
    packet at its first row's time and estimated; it is an error naming the
    row, its column and the first row's line, from a file and from Python."""
    from radiopose.packets import read_packets_csv, write_packets_csv

    pk = small_sim.packets
    first = pk.packet_id[0]
    rows = np.flatnonzero(pk.packet_id == first)
    t = pk.timestamp_s.copy()
    t[rows[-1]] += 0.375
    moved = replace(pk, timestamp_s=t)
    with pytest.raises(InputError, match=f"rows of packet {first} of .* disagree") as err:
        group_packets(moved)
    assert "line" not in str(err.value)
    path = tmp_path / "packets.csv"
    write_packets_csv(moved, path)
    with pytest.raises(InputError) as err:
        locate(small_sim.site, read_packets_csv(path), "top")
    message = str(err.value)
    assert f"packets.csv:{rows[-1] + 2}, column 'timestamp_s'" in message
    assert "(line 2)" in message and "\n" not in message


@pytest.mark.parametrize("method", ["filter", "top"])
def test_a_packet_given_twice_counts_once(small_sim, method):
    """The duplicate is skipped, and every other estimate is what it is
    without the duplicate (the filter once counted its evidence twice)."""
    obs = group_packets(small_sim.packets)[:12]

    def run(sequence: list[PacketObservation]):
        tracker = Tracker(small_sim.site, method)
        return [tracker.update(o) for o in sequence]

    once = run(obs)
    twice = run([*obs[:6], obs[5], *obs[6:]])
    assert twice[6] == (None, SKIP_DUPLICATE)
    del twice[6]
    for (a, ra), (b, rb) in zip(once, twice, strict=True):
        assert ra == rb
        if a is not None:
            assert a.position_m == b.position_m and a.orientation_deg == b.orientation_deg


def test_an_equal_time_is_not_a_duplicate(small_sim):
    """Two packets of one transmitter at one time (different ids) both count."""
    o = group_packets(small_sim.packets)[0]
    tracker = Tracker(small_sim.site, "top")
    assert tracker.update(o)[1] is None
    assert tracker.update(replace(o, packet_id=o.packet_id + "b"))[1] is None


# ------------------------------------------------------------------- settings that ran away
def test_a_bounded_search_on_a_small_grid_runs():
    """k beyond the bounded window's candidates: on a 5° azimuth grid the window
    around the last pose can hold fewer than k (the kernel asserted)."""
    from radiopose.simulate import ScenarioConfig, simulate

    sim = simulate(
        ScenarioConfig(size_m=10.0, step_m=0.25, duration_s=0.3, noise_db=0.5,
                       min_receiver_spacing_m=3.0, azimuth_step_deg=5.0),
        seed=1234,
    )  # fmt: skip
    res = locate(sim.site, sim.packets, "full", TrackerConfig(search="bounded"))
    assert res.summary.estimates_out > 0


def test_a_long_lag_with_frequent_reentries_does_not_reserve_memory_for_all(small_sim):
    """The smoother's genealogy once reserved rows for every re-entry within the
    lag for every packet: 10 s at a re-entry per ms was a MemoryError."""
    cfg = TrackerConfig(filter=FilterConfig(reentry_interval_s=1e-3, n_particles=200))
    tracker = Tracker(small_sim.site, "filter", cfg, lag_s=10.0)
    for o in group_packets(small_sim.packets)[:10]:
        tracker.update(o)
    (state,) = tracker.states.values()
    # rows per packet: the 200 particles and at most 400 re-entered (was 101,220)
    assert state.lineage.rows.shape[1] <= 600
    assert len(tracker.flush()) == 10


def test_a_coarse_table_bound_too_small_for_one_position_is_an_error():
    """The position step widened forever once the grid was one position."""
    from radiopose.filtering.particle3d import CoarseGrid
    from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
    from radiopose.survey_height import build_height_model

    sim = simulate_handheld(
        HandheldConfig(size_m=6.0, step_m=0.5, n_receivers=6, duration_s=0.05,
                       min_receiver_spacing_m=2.0, survey_step_m=1.0),
        seed=18019,
    )  # fmt: skip
    (dev,) = sim.site.devices
    height = build_height_model(sim.site)
    with pytest.raises(InputError, match="max_table_entries = 1000 is too small for this site"):
        CoarseGrid.build(
            sim.site, height, dev.tx_power_dbm, sim.site.patterns[dev.pattern],
            Pose3dConfig(max_table_entries=1000),
        )  # fmt: skip


# ------------------------------------------------------------------- sync and security
def _frame_records(rss=(-50.0, -60.0)):
    from radiopose.capture.frames import FrameRecords

    n = len(rss)
    obj = lambda xs: np.asarray(xs, dtype=object).reshape(-1)  # noqa: E731
    return FrameRecords(
        obj([f"rx{i + 1}" for i in range(n)]),
        np.arange(n, dtype=np.int64) * 1000,
        obj(["ab" * 32] * n),
        obj(["02:00:00:00:00:01"] * n),
        np.asarray(rss, dtype=np.float64),
    )


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: _sync(max_candidates=0), r"max_candidates = 0 is out of range"),
        (lambda: _sync(max_candidates=-1), r"max_candidates = -1 is out of range"),
        (lambda: _sync(max_drift_ppm=math.nan), r"max_drift_ppm = nan must be a finite"),
        (lambda: _sync(max_drift_ppm=-5.0), r"max_drift_ppm = -5.0 is out of range"),
        (lambda: _sync(min_pairs=-3), r"min_pairs = -3 is out of range"),
        (lambda: _sync(tolerance_s=math.nan), r"tolerance_s = nan must be a finite"),
        (lambda: _frame_records((-50.0, math.nan)), r"RSS nan dBm of receiver 'rx2'"),
        (lambda: _match(tolerance_s=math.nan), r"tolerance_s = nan must be in \(0, 60\] s"),
        (lambda: _match(tolerance_s=-1.0), r"tolerance_s = -1.0 must be in"),
        (lambda: _clocks([]), "no receivers given"),
        (lambda: _spoof(limit_scales=(1.0, math.nan)), "limit_scales"),
        (lambda: _spoof(target_noise_db=math.inf), "target_noise_db"),
        (lambda: _spoof(follow_radius_m=math.inf), "follow_radius_m"),
        (lambda: _spoof(n_targets=2.5), "n_targets = 2.5 must be an integer"),
        (lambda: _attacker(min_distance_m=math.nan), "min_distance_m = nan"),
        (lambda: _score_track([0.0, math.nan]), "finite and non-decreasing"),
        (lambda: _score_track([1.0, 0.0]), "finite and non-decreasing"),
    ],
)
def test_sync_and_security_inputs_built_in_python_are_one_line_errors(build, message):
    with pytest.raises(InputError, match=message) as err:
        build()
    assert "\n" not in str(err.value)


def _sync(**kw):
    from radiopose.capture.sync import SyncConfig

    return SyncConfig(**kw)


def _match(**kw):
    from radiopose.capture.sync import match_packets

    return match_packets(_frame_records(), ["rx1", "rx2"], **kw)


def _clocks(receivers):
    from radiopose.capture.sync import estimate_clocks

    return estimate_clocks(_frame_records(), receivers)


def _spoof(**kw):
    from radiopose.security.experiments import SpoofConfig

    return SpoofConfig(**kw)


def _attacker(**kw):
    from radiopose.security.attacker import AttackerModel

    return AttackerModel(**kw)


def _score_track(t_s):
    from radiopose.security.detection import score_track

    return score_track(np.asarray(t_s), np.full((len(t_s), 3), -50.0))


# ------------------------------------------------------------------- importers, streaming sync
@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"tolerance_s": math.nan}, "tolerance_s = nan must be a number"),
        ({"tolerance_s": math.inf}, "tolerance_s = inf must be a number"),
        ({"tolerance_s": -0.005}, "tolerance_s = -0.005"),
        ({"max_lag_s": -1.0}, "max_lag_s = -1.0 must be a number in \\(0, 86400\\] s or inf"),
        ({"max_lag_s": math.nan}, "max_lag_s = nan"),
        ({"max_lag_s": True}, "max_lag_s = True"),
        ({"receivers": ["A", "A", "B"]}, "must be distinct"),
        ({"receivers": []}, "must be distinct and at least one"),
    ],
)
def test_streaming_matcher_settings_are_checked(kw, message):
    """NaN and inf crashed in int conversion, a negative lag dropped every frame
    of the second receiver, a repeated receiver held every packet until flush."""
    from radiopose.capture.streaming import StreamingMatcher

    kw = {"receivers": ["A", "B"], **kw}
    with pytest.raises(InputError, match=message):
        StreamingMatcher(kw.pop("receivers"), **kw)


def test_a_frame_of_an_unknown_receiver_is_an_input_error():
    from radiopose.capture.streaming import StreamingMatcher

    with pytest.raises(InputError, match="frame of unknown receiver 'rx1'"):
        StreamingMatcher(["A", "B"]).push(_frame_records())


def test_a_json_nested_too_deeply_is_an_input_error(tmp_path):
    from radiopose.patterns.importers.basta import read_basta_json

    p = tmp_path / "deep.json"
    p.write_text("[" * 200_000 + "]" * 200_000, encoding="utf-8")
    with pytest.raises(InputError, match="nested too deeply"):
        read_basta_json(p)


def _mitll_copy(tmp_path, shared_data, edit):
    import shutil

    src = shared_data / "phone-patterns-mitll" / "iPhone-11-2"
    dst = tmp_path / "phone"
    shutil.copytree(src, dst)
    first = sorted(dst.glob("*.csv"))[0]
    lines = first.read_text(encoding="utf-8").split("\n")
    edit(lines)
    first.write_text("\n".join(lines), encoding="utf-8")
    return dst, first


def test_a_mitll_field_beyond_csvs_limit_is_an_input_error(tmp_path, shared_data):
    from radiopose.patterns.importers.mitll import read_mitll

    def edit(lines):
        lines[2] = lines[2] + ',"' + "x" * 200_000 + '"'

    dst, first = _mitll_copy(tmp_path, shared_data, edit)
    with pytest.raises(InputError, match=rf"{first.name}:3: not a CSV row: field larger"):
        read_mitll(dst)


def test_mitll_line_numbers_count_newlines_only(tmp_path, shared_data):
    """A U+2028 in a line shifted every later line number by one."""
    from radiopose.patterns.importers.mitll import read_mitll

    bad = {}

    def edit(lines):
        lines[2] = lines[2] + "\u2028junk"
        for k in range(4, len(lines)):
            cells = lines[k].split(",")
            if len(cells) > 3 and cells[1].strip() == "Bluetooth":
                bad["line"] = k + 1
                lines[k] = ",".join([*cells[:-1], "abc"])
                return

    dst, first = _mitll_copy(tmp_path, shared_data, edit)
    with pytest.raises(InputError) as err:
        read_mitll(dst)
    assert f"{first.name}:{bad['line']}," in str(err.value), str(err.value)
