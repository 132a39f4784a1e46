"""Split modules keep their old import paths; folded helpers agree with what they replaced."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

from radiopose.errors import InputError, unreadable
from radiopose.motion import axis_change_deg
from radiopose.units import angle_diff_deg

# (old module, name, new module): the old path must give the very same object
MOVED = [
    ("radiopose.patterns.importers", "read_msi", "radiopose.patterns.importers.msi"),
    ("radiopose.patterns.importers", "read_basta_json", "radiopose.patterns.importers.basta"),
    ("radiopose.patterns.importers", "read_mitll", "radiopose.patterns.importers.mitll"),
    ("radiopose.capture.sync", "StreamingMatcher", "radiopose.capture.streaming"),
    ("radiopose.capture", "StreamingMatcher", "radiopose.capture.streaming"),
    ("radiopose.capture.records", "FrameRecords", "radiopose.capture.frames"),
    ("radiopose.capture.records", "iter_raw_records", "radiopose.capture.pcapfile"),
    ("radiopose.capture.records", "read_pcap", "radiopose.capture.dot11"),
    ("radiopose.capture.records", "read_capture_csv", "radiopose.capture.csvform"),
    ("radiopose.evaluate.demo", "run_methods", "radiopose.evaluate.method_runs"),
    ("radiopose.evaluate.demo", "build_scorer", "radiopose.evaluate.method_runs"),
    ("radiopose.evaluate.runner", "default_workers", "radiopose.parallel"),
    ("radiopose.evaluate.runner", "WORKER_ENV", "radiopose.parallel"),
    ("radiopose.security.runner", "default_workers", "radiopose.parallel"),
]


@pytest.mark.parametrize(("old", "name", "new"), MOVED)
def test_old_import_paths_give_the_moved_objects(old: str, name: str, new: str) -> None:
    moved = getattr(importlib.import_module(new), name)
    assert getattr(importlib.import_module(old), name) is moved


def test_server_old_import_paths() -> None:
    pytest.importorskip("fastapi")
    live = importlib.import_module("radiopose.server.live")
    worker = importlib.import_module("radiopose.server.worker")
    app = importlib.import_module("radiopose.server.app")
    middleware = importlib.import_module("radiopose.server.middleware")
    assert live.LiveWorker is worker.LiveWorker
    assert app.BodyLimit is middleware.BodyLimit
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        live.nope  # noqa: B018


def test_unreadable_names_the_file_in_one_line(tmp_path: Path) -> None:
    missing = tmp_path / "missing.csv"
    with pytest.raises(OSError) as lost:
        missing.read_text()
    assert str(unreadable(missing, lost.value)) == f"{missing}: file not found"
    with pytest.raises(OSError) as folder:
        tmp_path.read_text()
    err = unreadable(tmp_path, folder.value, "a CSV file")
    assert isinstance(err, InputError)
    assert str(err) == f"{tmp_path}: is a directory, expected a CSV file"


def test_axis_change_row_wise_equals_one_previous_at_a_time() -> None:
    rng = np.random.default_rng(4242)
    a = np.column_stack(
        [rng.uniform(0, 360, 50), rng.uniform(-90, 90, 50), rng.uniform(-180, 180, 50)]
    )
    b = np.column_stack(
        [rng.uniform(0, 360, 50), rng.uniform(-90, 90, 50), rng.uniform(-180, 180, 50)]
    )
    rows = axis_change_deg(a, b)
    for i in range(a.shape[0]):
        np.testing.assert_array_equal(rows[i], axis_change_deg(a[i], b[i])[0])
    # the attacker's former check, written out: wrapped azimuth and roll, plain pitch
    expected = np.maximum(
        np.abs(angle_diff_deg(a[:, 0], b[:, 0])),
        np.maximum(np.abs(a[:, 1] - b[:, 1]), np.abs(angle_diff_deg(a[:, 2], b[:, 2]))),
    )
    np.testing.assert_array_equal(rows.max(axis=1), expected)


def test_motion_limits_follow_the_tracker_config() -> None:
    from radiopose.security.attacker import MotionLimits
    from radiopose.tracker import TrackerConfig

    default = TrackerConfig()
    lim = MotionLimits()
    assert (lim.max_speed_mps, lim.max_rotation_deg, lim.rotation_period_s) == (
        default.max_speed_mps,
        default.max_rotation_deg,
        default.rotation_period_s,
    )
    other = TrackerConfig(max_speed_mps=3.0, max_rotation_deg=90.0, rotation_period_s=0.25)
    scaled = MotionLimits.of(other, scale=0.1)
    assert scaled.speed_mps == pytest.approx(0.3)
    assert scaled.rate_deg_s == pytest.approx(0.1 * 90.0 / 0.25)


def test_default_spool_is_per_user(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from radiopose.receiver import AgentConfig, default_spool_dir

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert default_spool_dir() == tmp_path / "data" / "radiopose" / "spool"
    assert AgentConfig("http://x", "t", "rx1").spool_dir == default_spool_dir()
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert default_spool_dir() == tmp_path / "home" / ".local" / "share" / "radiopose" / "spool"
    monkeypatch.setenv("XDG_DATA_HOME", "relative/dir")  # not absolute: ignored (XDG rules)
    assert default_spool_dir() == tmp_path / "home" / ".local" / "share" / "radiopose" / "spool"


def test_replay_reads_any_pcap_as_the_named_receiver(tmp_path: Path) -> None:
    """The agent's replay takes a pcap as its own receiver's, whatever the file name
    (one magic-number check: :func:`radiopose.capture.pcapfile.is_pcap_start`)."""
    from radiopose.capture.pcapfile import is_pcap_start
    from radiopose.capture.records import read_pcap
    from radiopose.capture.writer import write_receiver_pcaps
    from radiopose.receiver import replay_frames

    tx = "02:00:00:00:00:07"
    rows = [("1", 2.0, tx, "rx1", -55.0), ("2", 1.0, tx, "rx1", -56.0)]
    sim = write_receiver_pcaps(rows, tmp_path, rng=np.random.default_rng(7), epoch_s=10.0)
    path = sim.paths["rx1"]
    assert is_pcap_start(path.read_bytes()[:4])
    frames = replay_frames(path, "other-name")
    assert set(frames.receiver_id) == {"other-name"}
    expected = read_pcap(path, "other-name").frames.time_ordered()
    np.testing.assert_array_equal(frames.timestamp_ns, expected.timestamp_ns)
    assert list(frames.rss_dbm) == list(expected.rss_dbm)
    assert not is_pcap_start(b"rece")  # a CSV capture's header
