"""The hand-held heading prior in the 3-D refinement's mode choice
(``Pose3dConfig.refine_heading_deg``; :func:`radiopose.filtering.refine3d.heading_cost`;
docs/pose3d.md, "Heading in the mode choice, 2026-11-28").

* ``heading_cost`` is zero for a track whose top points along its walk, grows
  with the angle to it, is zero at rest, and does not change when the whole
  track is moved or turned about the vertical (hypothesis);
* it is the 3-D filter's per-packet prior (``kernels3d.heading_prior``)
  summed over the packets;
* in ``refine_smoothed`` (over a fake solve) it decides between two modes
  that the objective alone ranks the other way, and only when it is on;
* the setting's one-line errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import radiopose.filtering.refine3d as r3
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.kernels3d import heading_prior
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.likelihood import HeardRss
from radiopose.tracker_settings import read_tracker_settings


def _walk(n: int, speed_mps: float, course_deg: float, dt_s: float = 0.02):
    """A straight walk at ``speed_mps`` along ``course_deg`` (from +x toward +y)
    and the azimuth that points the phone's top along it (``course − 90°``)."""
    t = np.arange(n) * dt_s
    c = math.radians(course_deg)
    pos = np.column_stack([speed_mps * t * math.cos(c), speed_mps * t * math.sin(c), 1.2 + 0 * t])
    ori = np.column_stack([np.full(n, (course_deg - 90.0) % 360.0), 40.0 + 0 * t, 0 * t])
    return t, pos, ori


@settings(max_examples=40, deadline=None)
@given(
    st.floats(0.2, 2.0), st.floats(0.0, 360.0), st.floats(-170.0, 170.0),
    st.floats(0.0, 360.0), st.floats(-20.0, 20.0), st.floats(-20.0, 20.0),
)  # fmt: skip
def test_heading_cost_geometry(
    speed: float, course: float, off: float, turn: float, dx: float, dy: float
) -> None:
    t, pos, ori = _walk(101, speed, course)
    assert r3.heading_cost(t, pos, ori, 30.0, 1.0, 0.3) == pytest.approx(0.0, abs=1e-9)
    bent = ori + np.array([off, 0.0, 0.0])
    c = r3.heading_cost(t, pos, bent, 30.0, 1.0, 0.3)
    # a constant deviation: (T / τ) κ g (1 − cos Δ), T the track's 2 s
    g = speed**2 / (speed**2 + 0.09)
    want = 2.0 * g * (1.0 - math.cos(math.radians(off))) / math.radians(30.0) ** 2
    assert c == pytest.approx(want, rel=1e-6, abs=1e-9)
    more = r3.heading_cost(t, pos, ori + np.array([off * 1.05, 0.0, 0.0]), 30.0, 1.0, 0.3)
    assert more >= c - 1e-12
    # the same track moved and turned about the vertical costs the same
    a = math.radians(turn)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    moved = pos.copy()
    moved[:, :2] = pos[:, :2] @ rot.T + np.array([dx, dy])
    turned = bent + np.array([turn, 0.0, 0.0])
    assert r3.heading_cost(t, moved, turned, 30.0, 1.0, 0.3) == pytest.approx(c, rel=1e-6, abs=1e-9)
    # at rest (and for a single packet) nothing
    still = np.repeat(pos[:1], t.size, axis=0)
    assert r3.heading_cost(t, still, bent, 30.0, 1.0, 0.3) == 0.0
    assert r3.heading_cost(t[:1], pos[:1], bent[:1], 30.0, 1.0, 0.3) == 0.0


def test_heading_cost_is_the_filters_prior_summed() -> None:
    """``heading_cost`` equals minus the log weight that the filter's compiled
    prior (``kernels3d.heading_prior``) gives, packet by packet, to particles
    on the track with the track's velocity, summed (a uniformly sampled track:
    every packet's share is ``dt``, half at the ends)."""
    n, dt = 51, 0.02
    t, pos, ori = _walk(n, 1.1, 35.0, dt)
    ori = ori + np.array([60.0, 0.0, 0.0])
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M : K.Z_M + 1] = pos
    S[:, K.VX_MPS] = 1.1 * math.cos(math.radians(35.0))
    S[:, K.VY_MPS] = 1.1 * math.sin(math.radians(35.0))
    S[:, K.AZIMUTH_RAD] = np.deg2rad(ori[:, 0])
    logw = np.zeros(n)
    heading_prior(S, logw, dt / 1.0, 1.0 / math.radians(25.0) ** 2, 0.3)
    share = np.full(n, dt)
    share[[0, -1]] = dt / 2
    want = float(-np.sum(logw * share / dt))
    assert r3.heading_cost(t, pos, ori, 25.0, 1.0, 0.3) == pytest.approx(want, rel=1e-9)


def _two_modes(monkeypatch, heading):
    """:func:`refine_smoothed` over a fake solve with two starts walking along
    +x at 1 m/s for 4 s: A with its top ahead (azimuth 270°), B turned round
    (90°). The objective prefers B by 5 nats under the random walks and 10
    under the constant-rate prior. Returns the kept track's azimuth."""
    n = 201
    t, pos, _ = _walk(n, 1.0, 0.0)
    heard = HeardRss(np.array([0, 1]), np.array([-50.0, -60.0]))
    records = [(float(ti), heard, i) for i, ti in enumerate(t)]

    def track(az: float) -> list[tuple[object, FilterEstimate]]:
        return [
            (i, FilterEstimate(tuple(pos[i]), (az, 40.0, 0.0), 0.1, 1.0, 0.0, 1.0))
            for i in range(n)
        ]

    walk_cost = {270.0: 105.0, 90.0: 100.0}
    rate_cost = {270.0: 150.0, 90.0: 140.0}

    def fake(model, times, h, p, o, off, sigma, prior, **kw):
        rate = prior.tilt_accel_noise_dps2 > 0
        cost = (rate_cost if rate else walk_cost)[float(o[0, 0])]
        return r3.RefinedTrack(np.array(p), np.array(o), off, sigma, cost, cost, 1)

    monkeypatch.setattr(r3, "refine_track", fake)
    out = r3.refine_smoothed(
        None, records, track(90.0), FilterConfig(), 0.2, 20.0, 10, alternatives=[track(270.0)],
        hybrid_segment_s=0.0, height_accel_noise_mps2=1.0, tilt_accel_noise_dps2=400.0,
        polish_starts=3, polish_margin=10.0, polish_switch=5.0, heading=heading,
    )  # fmt: skip
    return out[0][1].orientation_deg[0]


def test_the_heading_decides_between_modes_only_when_on(monkeypatch):
    assert _two_modes(monkeypatch, None) == 90.0  # the objective alone: B
    # B's heading cost over 4 s at 1 m/s, 30°: 4 κ g · 2 ≈ 26.8 nats > 10
    assert _two_modes(monkeypatch, (30.0, 1.0, 0.3)) == 270.0
    # a spread so wide that the prior weighs less than the objective's 10 nats
    assert _two_modes(monkeypatch, (150.0, 1.0, 0.3)) == 90.0


@pytest.mark.parametrize("bad", [-1.0, 181.0, math.nan, math.inf])
def test_bad_refine_heading_is_a_one_line_error(bad: float, tmp_path) -> None:
    with pytest.raises(InputError, match="refine_heading_deg") as exc:
        Pose3dConfig(refine_heading_deg=bad)
    assert "\n" not in str(exc.value)
    path = tmp_path / "tracker.toml"
    path.write_text("[filter.pose3d]\nrefine_heading_deg = 200.0\n", encoding="utf-8")
    with pytest.raises(InputError, match="refine_heading_deg") as exc:
        read_tracker_settings(path)
    assert "\n" not in str(exc.value)


def test_tracker_toml_switches_the_heading_off(tmp_path) -> None:
    """0 is a value in ``tracker.toml`` (it switches the part off), the default is 30."""
    assert Pose3dConfig().refine_heading_deg == 30.0
    path = tmp_path / "tracker.toml"
    for text, want in (("0", 0.0), ("0.0", 0.0), ("12.5", 12.5)):
        path.write_text(f"[filter.pose3d]\nrefine_heading_deg = {text}\n", encoding="utf-8")
        assert read_tracker_settings(path).pose3d_overrides["refine_heading_deg"] == want


def test_locate_hands_the_heading_to_the_mode_choice(monkeypatch):
    """``refine_heading_deg`` > 0: ``locate`` hands the refinement the spread
    with the heading prior's time and speed; 0: nothing."""
    from dataclasses import replace

    from filter_support import scene_3d
    from radiopose.tracker import TrackerConfig, locate

    sim, *_ = scene_3d()
    seen: list[object] = []

    def spy(model, records, smoothed, *args, **kw):
        seen.append(kw.get("heading"))
        return list(smoothed)  # (the refinement itself is not this test's)

    monkeypatch.setattr(r3, "refine_smoothed", spy)
    base = TrackerConfig()
    for deg in (0.0, 20.0):
        # (no escalation: the spy's unrefined track would be refined a second time)
        p3 = replace(base.pose3d, refine_heading_deg=deg, heading_prior_time_s=2.0,
                     refine_reverse_pass=False, refine_coarse_path=False,
                     refine_escalate_ratio=0.0)  # fmt: skip
        locate(sim.site, sim.packets, "filter", replace(base, pose3d=p3))
    assert seen == [None, (20.0, 2.0, 0.3)]
