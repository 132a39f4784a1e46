"""Round 7 of the offline ``filter``'s +6 dB tails (issue 15, unknown transmit power;
docs/filter.md "Accuracy round 7"): the arbiter's device offset judged by the
offset selection's evidence (``FilterConfig.arbiter_offset_evidence``) and a
tight pass at the arbiter's offset (``offline_offset_refit``), both off by
default.

The penalty and the refit test on hand-made passes; the arbiter's choice with
a penalty on a small simulated site; end to end on tuning seeds 7060 (σ = 3 dB,
+6 dB: no tight pass near the device's offset; 78.1° by default, 0.90° with the
reversed refit pass at the arbiter's offset) and 7063 (σ = 3 dB, +6 dB: a
mirror track at +1 dB ties the truth's basin on the objective; 134.9° by
default, 2.58° with the evidence penalty).
"""

from __future__ import annotations

import math

import pytest

from filter_support import loud_run, small_site, turned
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering.offset import OffsetPass
from radiopose.filtering.offset_refit import evidence_penalty, needs_refit
from radiopose.filtering.refine2d import arbitrate
from radiopose.tracker import TrackerConfig

WIDE = OffsetPass(math.nan, -100.0)


def test_evidence_penalty_is_the_evidence_lost_near_a_pass() -> None:
    passes = [WIDE, OffsetPass(0.0, -110.0), OffsetPass(6.0, -102.0)]
    pen = evidence_penalty(passes, 1.0)
    assert pen is not None
    assert pen(6.0) == pytest.approx(0.0, abs=1e-6)  # the best pass's centre
    assert pen(0.0) == pytest.approx(8.0, abs=0.01)  # the pass that lost by 8 nats
    assert pen(7.0) == pytest.approx(0.5, abs=0.01)  # one sd from the best: ½
    assert pen(3.0) > 4.0  # between them, far from both
    assert pen(math.nan) == math.inf
    # pass 1 (wide, no centre) does not count; one tight pass compares nothing
    assert evidence_penalty([WIDE, OffsetPass(0.0, -110.0)], 1.0) is None
    assert evidence_penalty([WIDE], 1.0) is None
    with pytest.raises(ValueError, match="positive"):
        evidence_penalty(passes, 0.0)


def test_refit_runs_only_away_from_every_tight_pass_and_the_enrolled_power() -> None:
    passes = [WIDE, OffsetPass(0.0, -110.0), OffsetPass(3.0, -105.0)]
    assert needs_refit(5.25, passes, 1.5, 1.5)  # 2.25 dB from the nearest pass
    assert not needs_refit(4.0, passes, 1.5, 1.5)  # within 1.5 dB of +3
    assert not needs_refit(1.0, [WIDE], 1.5, 1.5)  # at the enrolled power
    assert needs_refit(-2.0, [WIDE], 1.5, 1.5)  # pass 1 alone, found away from it
    assert not needs_refit(math.nan, passes, 1.5, 1.5)


def test_settings_are_checked() -> None:
    cfg = FilterConfig()
    assert not cfg.arbiter_offset_evidence and not cfg.offline_offset_refit  # off by default
    with pytest.raises(InputError, match="offset_refit_passes"):
        FilterConfig(offset_refit_passes="sideways")
    with pytest.raises(InputError, match="offset_refit_tolerance_db"):
        FilterConfig(offset_refit_tolerance_db=0.0)


def test_arbiter_adds_the_offset_penalty_to_the_objective() -> None:
    site = small_site()
    model, records, truth = site.model, site.records, site.truth
    wrong = turned(truth, records, len(records) // 4, 3 * len(records) // 4)
    cfg = FilterConfig()
    _, log = arbitrate(model, records, [wrong, truth], 0.5, cfg, 30)
    assert log[0].chosen == 1 and log[0].penalties == (0.0, 0.0)
    b_wrong, b_truth = log[0].offsets_db
    assert abs(b_wrong - b_truth) > 0.01  # the two optima sit at different offsets
    cut = 0.5 * (b_wrong + b_truth)

    def against_truth(b: float) -> float:
        return 1e6 if (b - cut) * (b_truth - cut) > 0 else 0.0

    _, log = arbitrate(model, records, [wrong, truth], 0.5, cfg, 30, offset_penalty=against_truth)
    assert log[0].chosen == 0  # the penalty outweighs the truth's lead
    assert log[0].penalties == (0.0, 1e6)
    assert log[0].costs[1] < log[0].costs[0]  # the objective itself is unchanged


# ------------------------------------------------- end to end: tuning seed 7063
ROUND7 = {
    "arbiter_offset_evidence": True,
    "offline_offset_refit": True,
    "offset_refit_passes": "reversed",
    "offset_refit_tolerance_db": 1.5,
}


def _loud_run(seed: int, sigma_db: float, over: dict) -> tuple[float, float]:
    return loud_run(seed, sigma_db, TrackerConfig(), **over)


@pytest.mark.slow  # an option off by default (offline_offset_refit = false): session 14's cut
def test_round7_evidence_penalty_moves_the_arbiters_choice_on_a_tuning_seed() -> None:
    """Tuning seed 7063, σ = 3 dB, +6 dB: the default keeps a mirror track at the
    wrong offset (134.9° / 12.7 m); round 7's evidence penalty moves the
    arbiter to another candidate (83.9° / 1.81 m: still wrong), and without the
    penalty (the refit alone) the default's choice stays.

    Until the motion noise became counter-based (docs/performance.md,
    "Counter-based motion noise") round 7 fixed this run (2.58°) and seed 7060
    (the refit pass: 78.1° → 0.90°); with the new draws 7060's default is right
    (0.9°) and no +6 dB, σ = 3 dB run of tuning seeds 7060–7099 and 7240–7287
    is fixed by the options (docs/filter.md, round 7): they stay off, and this
    test checks only that the penalty acts."""
    default_deg = _loud_run(7063, 3.0, {})[1]
    assert default_deg > 100.0
    _, penalised_deg = _loud_run(7063, 3.0, ROUND7)
    assert abs(penalised_deg - default_deg) > 20.0
    # the part removed: the default's choice stays
    refit_only = {**ROUND7, "arbiter_offset_evidence": False}
    assert abs(_loud_run(7063, 3.0, refit_only)[1] - default_deg) < 1.0
