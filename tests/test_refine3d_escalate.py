"""The 3-D refinement's escalation (``Pose3dConfig.refine_escalate_ratio``; docs/pose3d.md,
"Session 17"): a σ-free segment misfit of the refined track and mid-track restarts run
only when it is high.

* ``segment_misfit_ratio`` is near 1 for the truth of a noisy scene, far above 1 when
  part of the track is turned away, and does not change with σ (it is σ-free);
* ``locate`` runs the restarts and a second refinement only when the ratio is above
  the setting (off by default, offline only), with the setting's number of restarts;
* the settings' one-line errors.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import radiopose.filtering.refine3d as r3
import radiopose.tracker.filter as tf
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.particle3d import FilterModel3d, Pose3dConfig
from radiopose.likelihood import candidate_space
from radiopose.packets import group_packets
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings


@pytest.fixture(scope="module")
def scene():
    sim = simulate_handheld(
        replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=2.0), seed=18019
    )
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    model = FilterModel3d.build3d(sim.site, space, Pose3dConfig())
    obs = group_packets(sim.packets)
    records = [(o.timestamp_s, space.heard(o), i) for i, o in enumerate(obs)]
    idx = np.searchsorted(sim.truth.timestamp_s, [o.timestamp_s for o in obs])
    return model, records, sim.truth.position_m[idx], sim.truth.orientation_deg[idx]


def _estimates(pos, ori, sigma_db=1.0):
    return [
        (i, FilterEstimate(tuple(p), tuple(o), 0.1, 1.0, 0.0, sigma_db))
        for i, (p, o) in enumerate(zip(pos, ori, strict=True))
    ]


def test_the_ratio_is_near_one_on_the_truth_and_high_on_a_partly_wrong_track(scene):
    model, records, pos, ori = scene
    cfg = FilterConfig()
    right = r3.segment_misfit_ratio(model, records, _estimates(pos, ori), cfg)
    assert 1.0 <= right < 1.3  # 4 segments of ~600 readings each at σ 1 dB
    bent = ori.copy()
    bent[: len(bent) // 4, 0] += 60.0  # the first 0.5 s turned away
    wrong = r3.segment_misfit_ratio(model, records, _estimates(pos, bent), cfg)
    assert wrong > 2.0 * right
    # σ-free: the same tracks with another σ (the data term scales, the ratio does not much)
    again = r3.segment_misfit_ratio(model, records, _estimates(pos, bent, 2.0), cfg)
    assert again == pytest.approx(wrong, rel=0.25)
    assert r3.segment_misfit_ratio(model, records, [], cfg) == 0.0


def test_locate_escalates_only_above_the_ratio(monkeypatch):
    """Off (0): nothing more runs; with a ratio below the fit's (0.5: the ratio is at least 1,
    and exactly 1 on this 0.3 s file's one segment), the restarts run (the
    setting's number) and the file is refined again with them as more starts;
    with a ratio above it, or causal, nothing more runs."""
    sim = simulate_handheld(replace(HandheldConfig(), n_receivers=6, duration_s=0.3), seed=18018)
    calls: list[int] = []
    restarts: list[int] = []
    ratios: list[float] = []
    real_rs, real_mid = r3.refine_smoothed, tf.midtrack_tracks3d
    real_ratio = r3.segment_misfit_ratio

    def rs_spy(*args, alternatives=(), **kwargs):
        calls.append(len(alternatives))
        return real_rs(*args, alternatives=alternatives, **kwargs)

    def mid_spy(pf, records, seed, n_restarts, members):
        restarts.append(n_restarts)
        return real_mid(pf, records, seed, n_restarts, members)

    def ratio_spy(*args, **kwargs):
        ratios.append(real_ratio(*args, **kwargs))
        return ratios[-1]

    monkeypatch.setattr(r3, "refine_smoothed", rs_spy)
    monkeypatch.setattr(r3, "segment_misfit_ratio", ratio_spy)
    monkeypatch.setattr(tf, "midtrack_tracks3d", mid_spy)
    base = TrackerConfig()
    assert base.pose3d.refine_escalate_ratio == 1.3  # the default since 2026-11-28
    base = replace(base, pose3d=replace(base.pose3d, refine_escalate_ratio=0.0))
    locate(sim.site, sim.packets, "filter", base)
    assert len(calls) == 1 and restarts == [] and ratios == []
    low = replace(base, pose3d=replace(base.pose3d, refine_escalate_ratio=0.5,
                                       refine_escalate_restarts=3))  # fmt: skip
    calls.clear()
    locate(sim.site, sim.packets, "filter", low)
    assert len(ratios) == 1 and ratios[0] >= 1.0
    assert restarts == [3] and len(calls) == 2 and calls[1] == calls[0] + 3
    high = replace(low, pose3d=replace(low.pose3d, refine_escalate_ratio=ratios[0] + 1.0))
    calls.clear()
    locate(sim.site, sim.packets, "filter", high)
    assert restarts == [3] and len(calls) == 1
    locate(sim.site, sim.packets, "filter", replace(low, smoothing_lag_s=None))
    assert restarts == [3]


@pytest.mark.parametrize(
    ("field", "value"),
    [("refine_escalate_ratio", -1.0), ("refine_escalate_ratio", math.inf),
     ("refine_escalate_restarts", 0), ("refine_escalate_restarts", 101)],
)  # fmt: skip
def test_bad_settings_are_one_line_errors(field, value, tmp_path) -> None:
    with pytest.raises(InputError, match=field):
        replace(Pose3dConfig(), **{field: value})
    path = tmp_path / "tracker.toml"
    text = "inf" if value == math.inf else repr(value)
    path.write_text(f"[filter.pose3d]\n{field} = {text}\n", encoding="utf-8")
    with pytest.raises(InputError, match=field) as err:
        read_tracker_settings(path)
    assert "\n" not in str(err.value)
    path.write_text("[filter.pose3d]\nrefine_escalate_ratio = 0\n", encoding="utf-8")
    assert read_tracker_settings(path).pose3d_overrides["refine_escalate_ratio"] == 0.0


def test_a_memo_shares_the_solves_between_calls(scene, monkeypatch):
    """``refine_smoothed(memo=…)``: a second call on the same packets solves nothing
    again and returns the same estimates; with one more start only what that
    start adds is solved (the escalation's second refinement)."""
    model, records, pos, ori = scene
    calls: list[int] = []
    real = r3.refine_track

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(r3, "refine_track", counting)
    smoothed = _estimates(pos, ori)
    bent = ori + np.array([25.0, 0.0, 0.0])
    args = (model, records, smoothed, FilterConfig(), 0.2, 20.0, 5)
    kw = {"height_accel_noise_mps2": 1.0, "tilt_accel_noise_dps2": 400.0, "polish_starts": 2,
          "polish_margin": 1e9}  # fmt: skip
    plain = r3.refine_smoothed(*args, **kw)
    n_plain = len(calls)
    memo: dict = {}
    first = r3.refine_smoothed(*args, memo=memo, **kw)
    assert len(calls) == 2 * n_plain and first == plain
    again = r3.refine_smoothed(*args, memo=memo, **kw)
    assert len(calls) == 2 * n_plain and again == plain  # nothing solved again
    more = r3.refine_smoothed(*args, memo=memo, alternatives=[_estimates(pos, bent)], **kw)
    added = len(calls) - 2 * n_plain
    fresh = r3.refine_smoothed(*args, alternatives=[_estimates(pos, bent)], **kw)
    assert 1 <= added < len(calls) - 2 * n_plain - added  # fewer than a call without it
    assert more == fresh
