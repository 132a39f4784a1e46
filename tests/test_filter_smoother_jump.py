"""The backward smoother (``FilterConfig.smoother = "backward"``) against the
genealogy on a seeded run with a jump, end to end through ``locate``.

Seed 4107 (σ = 3 dB, the standard scenario) is used here only: the causal
filter holds wrong poses at first and its particles jump to the right one
from re-entered hypotheses; the genealogy gives those a past of their pose
moved back along a guessed turn rate (its first 0.2 s 51.5° off), the
backward smoother finds their past among the earlier re-entries' hypotheses
in the same mode (1.1°; docs/filter.md, "Smoother"). Until the motion noise
became counter-based (docs/performance.md, "Counter-based motion noise") the seed was 4105,
whose run then showed the same (51° against 1.5°); with the new draws 4105's
jump is a later one (88.6° against 22.9°), and 4107 is the seed of 4101–4124
that shows the first-0.2 s case. Seeds 4101–4124 are used here only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from filter_support import require_wrong_mode, tracker_before_angular_noise
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.simulate import ScenarioConfig, simulate

SEED = 4107


@pytest.fixture(scope="module")
def runs():
    sim = simulate(ScenarioConfig(noise_db=3.0), SEED)
    scorer = build_scorer(sim, "numba")
    base = tracker_before_angular_noise()  # the case's wrong lock (filter_support)
    out = {}
    for name in ("lineage", "backward"):
        # the smoothers themselves: without round 6's offline reversed pass and arbiter
        cfg = replace(
            base,
            filter=replace(
                base.filter, smoother=name, offline_reverse_pass=False, offline_refine=False
            ),
        )
        out[name] = run_methods(sim, ("filter",), cfg, scorer)["filter"]
    return sim, out


def test_backward_smoother_keeps_the_past_of_a_jump(runs) -> None:
    sim, out = runs
    for run in out.values():
        assert run.summary.coverage == 1.0
    t0 = float(sim.packets.timestamp_s.min())

    def first_fifth_s(run) -> float:
        """Mean orientation error over the run's first 0.2 s, degrees."""
        t = np.asarray(run.estimates.timestamp_s)
        return float(run.orientation_error_deg[t < t0 + 0.2].mean())

    lineage, backward = first_fifth_s(out["lineage"]), first_fifth_s(out["backward"])
    assert backward < 8.0  # measured 1.1°
    # the genealogy's made-up past (measured 51.5°) is a chaotic wrong mode
    require_wrong_mode(lineage, 25.0, "lineage")
    # and over the whole run no worse than the genealogy
    whole = {k: float(r.orientation_error_deg.mean()) for k, r in out.items()}
    assert whole["backward"] < whole["lineage"]


def test_backward_estimates_carry_the_same_columns(runs) -> None:
    _, out = runs
    a, b = out["lineage"].estimates, out["backward"].estimates
    np.testing.assert_array_equal(np.asarray(a.packet_id), np.asarray(b.packet_id))
    assert b.position_std_m is not None and b.azimuth_std_deg is not None
    assert np.all(np.isfinite(b.position_std_m)) and np.all(np.isfinite(b.azimuth_std_deg))
