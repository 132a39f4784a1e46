"""Issue 15, unknown transmit power: the offline device-level offset selection
(:mod:`radiopose.filtering.offset`, docs/filter.md "Accuracy round 4").

The candidates and the settings of the tight passes (hand-built inputs); the
selection only offline (never in the streaming ``Tracker``); and a seeded +6 dB
run whose issue bound (within 1.3× (+0.1 m, +1°) of the matched run over the
whole run) holds with the selection and is missed without it.

Seeds SEED_LOUD only (the filter was tuned on 7000–7059 and is reported on
1000–1029).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from filter_support import louder, tracker_before_angular_noise
from radiopose.errors import InputError
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig
from radiopose.filtering.offset import candidate_offsets_db, tight_config
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import Tracker, TrackerConfig

SEED_LOUD = 4201
"""A +6 dB run at σ = 0.5 dB that the filter without the selection gets wrong."""


def test_candidates_are_the_centre_the_final_and_the_median_belief_merged() -> None:
    beliefs = np.array([math.nan, 0.2, 5.8, 6.1, 6.0, 5.9])
    assert candidate_offsets_db(0.0, 6.3, beliefs, 0.75) == [0.0, 6.3]
    assert candidate_offsets_db(0.0, 3.0, beliefs, 0.75) == [0.0, 3.0, pytest.approx(5.9)]
    assert candidate_offsets_db(0.0, 0.5, np.array([0.4, math.nan]), 0.75) == [0.0]
    assert candidate_offsets_db(0.0, math.nan, np.array([math.nan]), 0.75) == [0.0]


def test_tight_passes_search_only_around_their_candidate() -> None:
    cfg = tight_config(FilterConfig(offset_selection_sd_db=0.8))
    assert cfg.offset_prior_sd_db == 0.8
    assert cfg.initial_offsets_db == (-0.8, 0.0, 0.8)
    assert cfg.offset_scans_per_reentry == 0
    assert not cfg.offline_offset_selection


@pytest.mark.parametrize(
    "bad",
    [
        {"offset_selection_sd_db": 0.0},
        {"offset_selection_merge_db": -1.0},
        {"offset_selection_trigger_db": math.nan},
    ],
)
def test_settings_are_validated(bad: dict[str, float]) -> None:
    with pytest.raises(InputError, match=next(iter(bad))):
        FilterConfig(**bad)


@pytest.fixture(scope="module")
def sim_loud():
    return simulate(ScenarioConfig(noise_db=0.5), SEED_LOUD)


@pytest.fixture(scope="module")
def scorer(sim_loud):
    return build_scorer(sim_loud, "numba")


def _run(sim, scorer, **filter_settings: object):
    # round 4's selection on its own: without round 6's reversed pass and arbiter,
    # which leave this run's wrong lock even without the selection, nor the live
    # re-solve (session 25), which runs them on the first 0.5 s when none is on
    settings = {
        "offline_reverse_pass": False,
        "offline_refine": False,
        "live_resolve_times_s": (),
        **filter_settings,
    }
    cfg = tracker_before_angular_noise(**settings)  # the case's wrong lock (filter_support)
    return run_methods(sim, ("filter",), cfg, scorer)["filter"]


def test_plus_6_db_is_within_the_issue_bound_only_with_the_selection(sim_loud, scorer) -> None:
    """The whole run (not only after the first second) within 1.3× (+0.1 m, +1°)
    of the matched run; without the selection the same run misses it."""
    matched = _run(sim_loud, scorer)
    loud = _run(louder(sim_loud), scorer)
    without = _run(louder(sim_loud), scorer, offline_offset_selection=False)
    assert loud.summary.coverage == matched.summary.coverage == 1.0
    pm, om = matched.position_error_m.mean(), matched.orientation_error_deg.mean()
    assert loud.position_error_m.mean() <= 1.3 * pm + 0.1
    assert loud.orientation_error_deg.mean() <= 1.3 * om + 1.0
    assert not (
        without.position_error_m.mean() <= 1.3 * pm + 0.1
        and without.orientation_error_deg.mean() <= 1.3 * om + 1.0
    )


def test_the_streaming_tracker_never_selects(sim_loud, scorer) -> None:
    """The live server's ``Tracker`` (not offline) keeps no record of the packets and
    its smoothed estimates are those of the filter without the selection."""
    sim = louder(sim_loud)
    packets = group_packets(sim.packets)[:60]
    tx = sim.site.devices[0].transmitter
    out = {}
    for selection in (True, False):
        cfg = TrackerConfig(filter=FilterConfig(offline_offset_selection=selection))
        tr = Tracker(sim.site, "filter", cfg, {tx: scorer}, lag_s=0.25)
        for obs in packets:
            tr.update(obs)
        ests = tr.take_delayed() + tr.flush()
        (state,) = tr.states.values()
        assert state.records is None
        out[selection] = np.array([e.position_m for e in ests])
    assert np.array_equal(out[True], out[False])
