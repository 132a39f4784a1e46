"""The spoofing detector (issue 19): analytic CUSUM behaviour, the compiled and
streaming scorers, each attack on a seeded scenario (the residual signal through
the real filter), the silent attacker and the gap test, a genuine fast-rotating
track left alone and ``spoof detect``'s table.

Seeds 4240–4249 are this file's own (not the tuning seeds from 7000 nor the
held-out ones: 1000–1009, and 20000+ for the detector).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.security.attacks import (
    ATTACKS,
    AttackConfig,
    SiteModel,
    attack_stream,
    genuine_stream,
    scenario_for,
)
from radiopose.security.detect_experiment import (
    CONTRACT_ATTACKS,
    DETECTION_COLUMNS,
    DetectPlan,
    Track,
    detection_rows,
    filter_residuals,
)
from radiopose.security.detection import (
    ConsistencyDetector,
    DetectorConfig,
    _score_track_streaming,
    score_track,
)
from radiopose.simulate.trajectories import MotionConfig

SEED = 4242


# ----------------------------------------------------------------------------- analytic
def test_cusum_stays_quiet_on_stationary_residuals_and_fires_on_inflation() -> None:
    rng = np.random.default_rng(SEED)
    t = np.arange(60_000) * 0.005  # 5 minutes at 200 packets/s
    res = rng.normal(3.0, 1.0, (t.size, 4))  # offset 3 dB, σ 1 dB
    quiet = score_track(t, res, DetectorConfig())
    assert not quiet.alarm.any()
    start = 30_000
    res[start:] = rng.normal(3.0, 2.0, (t.size - start, 4))  # variance ×4
    loud = score_track(t, res, DetectorConfig())
    first = np.flatnonzero(loud.alarm)[0]
    assert start <= first and t[first] - t[start] < 0.5


def test_a_silence_a_real_device_does_not_show_is_evidence() -> None:
    rng = np.random.default_rng(SEED + 1)
    t = np.arange(2_000) * 0.005
    t[1_000:] += 0.25  # one 250 ms silence in 5 ms traffic
    res = rng.normal(0.0, 1.0, (t.size, 4))
    with_gap = score_track(t, res, DetectorConfig(gap_nats=10.0))
    without = score_track(t, res, DetectorConfig())  # the default: no gap test
    assert with_gap.score_nats[1_000] > without.score_nats[1_000] + 10.0
    assert with_gap.score_nats[1_000] == pytest.approx(
        without.score_nats[1_000] + 10.0 * np.log2(0.255 / (5 * 0.005)), abs=2.0
    )


def test_streaming_and_batch_forms_agree_and_config_is_checked() -> None:
    rng = np.random.default_rng(SEED + 2)
    t = np.arange(500) * 0.01
    res = rng.normal(0.0, 1.5, (t.size, 3))
    res[::7, 1] = np.nan  # a receiver missing some packets
    batch = score_track(t, res)
    det = ConsistencyDetector()
    stream = [det.update(float(a), b)[0] for a, b in zip(t, res, strict=True)]
    np.testing.assert_allclose(batch.score_nats, stream)
    # the compiled batch form against the streaming one: resets, gaps, the gap test
    t2 = t.copy()
    t2[300:] += 0.4
    new = np.zeros(t.size, bool)
    new[200] = True
    res2 = res * np.where(np.arange(t.size) > 350, 3.0, 1.0)[:, None]
    cfg = DetectorConfig(gap_nats=5.0, warmup_s=0.5, threshold_nats=10.0)
    fast = score_track(t2, res2, cfg, new)
    slow = _score_track_streaming(t2, res2, cfg, new)
    np.testing.assert_array_equal(fast.score_nats, slow.score_nats)
    np.testing.assert_array_equal(fast.alarm, slow.alarm)
    assert fast.alarm.any() and not fast.alarm.all()
    with pytest.raises(InputError, match="inflation"):
        DetectorConfig(inflation=1.0)
    with pytest.raises(InputError, match="signal"):
        DetectorConfig(signal="pose")
    with pytest.raises(InputError, match="value rows"):
        score_track(t, res[:-1])


# ----------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def site() -> SiteModel:
    return SiteModel.build(scenario_for(1.0), SEED)


def _first_alarm_after_attack(
    site: SiteModel, attack: str, config: DetectorConfig | None = None
) -> float:
    rng = np.random.default_rng([SEED, ATTACKS.index(attack)])
    stream = attack_stream(site, attack, 1.0, AttackConfig(), rng)
    out = score_track(stream.t_s, stream.rss_dbm, config or DetectorConfig())
    before = stream.t_s < stream.t_attack_s
    assert not out.alarm[before].any(), "false alarm on the genuine prefix"
    hits = np.flatnonzero(out.alarm & ~before)
    return float(stream.t_s[hits[0]] - stream.t_attack_s) if hits.size else math.inf


_NOT_MET = pytest.mark.xfail(
    strict=True,
    reason="issue 19 goal not reachable at 4 receivers within 0.5 s: the oracle bound (the "
    "attacker's true model against the best continuous genuine explanation) is below the "
    "evidence 1 false alarm per hour needs in 2 of 10 fixed and 6 of 10 moving tuning runs "
    "(docs/security.md, Attacks 1-2: the oracle bound)",
)


@pytest.mark.parametrize(
    "attack",
    [
        pytest.param("fixed", marks=_NOT_MET),
        pytest.param("moving", marks=_NOT_MET),
        "clone",
        "replay",
    ],
)
def test_each_attack_is_detected_within_half_a_second(site: SiteModel, attack: str) -> None:
    assert _first_alarm_after_attack(site, attack) <= 0.5


def test_without_the_detector_the_attack_goes_unflagged(site: SiteModel) -> None:
    """The detector is what flags: the same residuals with an unreachable threshold
    (the detector in effect removed) give no alarm."""
    rng = np.random.default_rng([SEED, ATTACKS.index("clone")])
    stream = attack_stream(site, "clone", 1.0, AttackConfig(), rng)
    on = score_track(stream.t_s, stream.rss_dbm, DetectorConfig())
    off = score_track(stream.t_s, stream.rss_dbm, DetectorConfig(threshold_nats=1e12))
    assert on.alarm.any() and not off.alarm.any()


def test_the_residual_signal_still_detects_a_clone_through_the_filter(site: SiteModel) -> None:
    """The first design (residual changes at the filter's pose) is kept selectable."""
    rng = np.random.default_rng([SEED, ATTACKS.index("clone")])
    stream = attack_stream(site, "clone", 1.0, AttackConfig(), rng)
    res, _, new = filter_residuals(site, stream, SEED)
    out = score_track(stream.t_s, res, DetectorConfig(signal="residual"), new)
    before = stream.t_s < stream.t_attack_s
    assert not out.alarm[before].any()
    hits = np.flatnonzero(out.alarm & ~before)
    assert hits.size and stream.t_s[hits[0]] - stream.t_attack_s <= 0.5


def test_genuine_fast_bounded_rotation_is_not_flagged() -> None:
    """A genuine device turning at 300–350 °/s (inside the 360 °/s bound) for 10 s."""
    scenario = replace(
        scenario_for(1.0),
        motion=replace(MotionConfig(), rotation="fast", fast_rate_deg_s=(300.0, 350.0)),
    )
    site = SiteModel.build(scenario, SEED + 3)
    stream = genuine_stream(site, 10.0, 1.0, np.random.default_rng(SEED + 3))
    out = score_track(stream.t_s, stream.rss_dbm, DetectorConfig())
    assert not out.alarm.any()


# ----------------------------------------------------------------------------- tables
def _track(kind: str, t_attack_s: float, alarm_at_s: float | None) -> Track:
    t = np.arange(0.0, 3.0, 0.005)
    res = np.random.default_rng(SEED + 4).normal(0.0, 1.0, (t.size, 4))
    if alarm_at_s is not None:  # residual changes 5 times larger from then on
        res[t >= alarm_at_s] *= 5.0
    return Track(kind, 1.0, 0, t, res, res, np.zeros(t.size, bool), t_attack_s, res)


def test_detection_rows_count_detections_delays_and_false_alarms() -> None:
    tracks = [
        _track("fixed", 2.0, 2.1),  # detected ~0.1 s after the start
        _track("fixed", 2.0, None),  # missed
        _track("genuine", math.inf, 2.5),  # one false alarm in 3 s of traffic
    ]
    rows = detection_rows(tracks, DetectorConfig(), 0.5)
    assert list(rows[0]) == list(DETECTION_COLUMNS)
    (fixed,) = [r for r in rows if r["attack"] == "fixed"]
    assert fixed["runs"] == 2 and fixed["detection_probability"] == 0.5
    assert 0.1 < fixed["median_detection_delay_s"] <= 0.25  # the change is at +0.1 s
    hours = (3.0 - 0.005 + 2 * (2.0 - 0.005)) / 3600.0
    assert fixed["false_alarms_per_hour"] == pytest.approx(1.0 / hours, rel=1e-6)


def test_spoof_detect_cli_writes_the_contract_table(tmp_path: Path, monkeypatch, capsys) -> None:
    from radiopose.cli import main
    from radiopose.security import detect_experiment

    tiny = DetectPlan(sigmas_db=(1.0,), attack_runs=1, genuine_chunks=1, chunk_s=3.0)
    monkeypatch.setattr(detect_experiment.DetectPlan, "quick", classmethod(lambda cls, seed: tiny))
    out = tmp_path / "det"
    code = main(["spoof", "detect", "--quick", "--workers", "0", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    lines = (out / "detection.csv").read_text().splitlines()
    assert lines[0] == ",".join(DETECTION_COLUMNS)
    assert [ln.split(",")[0] for ln in lines[1:]] == list(CONTRACT_ATTACKS)
    assert (out / "roc.csv").exists()
    # fixed and moving go undetected here: no delay is an empty field and '–' on
    # stdout, not 'nan' (the CSV had 'nan', stdout 'delay=nan s')
    delay = DETECTION_COLUMNS.index("median_detection_delay_s")
    fields = {ln.split(",")[0]: ln.split(",") for ln in lines[1:]}
    assert fields["fixed"][delay] == "" and float(fields["clone"][delay]) > 0
    roc = (out / "roc.csv").read_text()
    assert "nan" not in roc.lower() and ",1,0,," in roc
    stdout = capsys.readouterr().out
    assert "nan" not in stdout
    assert "P(detect ≤ 0.5 s)=0.00 delay=– (none detected) false alarms/h=" in stdout


def test_the_silent_attacker_sends_only_what_it_matches(site: SiteModel) -> None:
    """``silent`` is the ``fixed`` attacker minus the packets it cannot match: with an
    unbounded tolerance it is the ``fixed`` stream, with none it never sends."""
    streams = {}
    for name, attack, rms in (
        ("fixed", "fixed", 1.0),
        ("all", "silent", 1e9),
        ("none", "silent", 0.0),
        ("some", "silent", 1.0),
    ):
        rng = np.random.default_rng([SEED, 9])
        streams[name] = attack_stream(site, attack, 1.0, AttackConfig(match_rms_db=rms), rng)
    fixed, every, none, some = (streams[k] for k in ("fixed", "all", "none", "some"))
    np.testing.assert_array_equal(every.t_s, fixed.t_s)
    np.testing.assert_array_equal(every.rss_dbm, fixed.rss_dbm)
    assert not np.any(none.t_s >= none.t_attack_s)
    assert np.all(none.t_s == fixed.t_s[fixed.t_s < fixed.t_attack_s])
    assert set(some.t_s.tolist()) <= set(fixed.t_s.tolist())


def test_the_gap_test_flags_a_silent_attacker_that_waits(site: SiteModel) -> None:
    """A ``silent`` attacker that stays quiet for 0.34 s mid-attack: the shipped
    detector (gap test off) misses it, the gap test flags it at the first packet
    after the silence, and neither flags the genuine prefix."""
    rng = np.random.default_rng([SEED, 11])
    stream = attack_stream(site, "silent", 1.0, AttackConfig(), rng)
    t = stream.t_s
    attacker = t >= stream.t_attack_s
    gaps = np.diff(t)
    longest = int(np.argmax(gaps))
    assert gaps[longest] > 0.3 and attacker[longest]  # the silence is the attacker's
    assert not score_track(t, stream.rss_dbm, DetectorConfig()).alarm.any()
    flagged = score_track(t, stream.rss_dbm, DetectorConfig(gap_nats=10.0)).alarm
    assert not flagged[~attacker].any()
    assert np.flatnonzero(flagged)[0] == longest + 1
