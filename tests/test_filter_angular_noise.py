"""The 2-D filter's angular noise (docs/filter.md, "Angular noise", 2026-11-27).

Since 2026-11-27 the filter's white angular acceleration is 270 °/s²/√Hz (90
before) while the offline arbiter's prior keeps 90
(``refine_angular_accel_noise_dps2``). On the motion experiment's human-like
sway (``rotation="periodic"``), the hypotheses of the old density could not
follow the hand: on lead's tuning seed 7503 at σ = 0.5 dB both the forward and
the reversed pass lost the track (measured 49.2° / 1.26 m), and the arbiter had
no candidate in the truth's basin; with 270 the run is at 0.33° / 0.047 m.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from filter_support import BEFORE_COARSE, require_wrong_mode
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.simulate import MotionConfig, ScenarioConfig, simulate
from radiopose.tracker import TrackerConfig

SEED = 7503
"""The lead's periodic-rotation tuning seed (7500–7599, docs/filter.md)."""


@pytest.fixture(scope="module")
def runs():
    scenario = ScenarioConfig(noise_db=0.5, motion=MotionConfig(rotation="periodic"))
    sim = simulate(scenario, SEED)
    scorer = build_scorer(sim, "numba")
    base = TrackerConfig()
    # the angular noise alone decides without the coarse-grid HMM candidate
    # (session 13's default, which also leaves this lock: "default" below)
    alone = replace(base, filter=replace(base.filter, **BEFORE_COARSE))
    out = {"default": run_methods(sim, ("filter",), base, scorer)["filter"]}
    for name, q in (("noise", None), ("before", 90.0)):
        cfg = alone if q is None else replace(
            alone, filter=replace(alone.filter, angular_accel_noise_dps2=q)
        )  # fmt: skip
        out[name] = run_methods(sim, ("filter",), cfg, scorer)["filter"]
    return out


def test_hypotheses_follow_a_swaying_hand(runs) -> None:
    """With the density of before the run is lost (> 30°); with today's it is not
    (both without the coarse-grid HMM candidate); the default (with it) is not."""
    default, noise, before = runs["default"], runs["noise"], runs["before"]
    assert default.summary.coverage == before.summary.coverage == 1.0
    for run in (default, noise):
        assert run.orientation_error_deg.mean() < 5.0  # measured 0.33°
        assert run.position_error_m.mean() < 0.3  # measured 0.047 m
    # the wrong mode is chaotic (any change to the filter may move it): where it
    # does not occur the part's necessity cannot be shown, and the test is skipped
    require_wrong_mode(before.orientation_error_deg.mean(), 30.0, "before")  # measured 49.2°
