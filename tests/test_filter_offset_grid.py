"""Issue 15, +6 dB: the offline offset selection's fixed grid of tight passes
(``FilterConfig.offset_selection_grid_db``) and reversed passes at the
runner-up passes' offsets (``offset_selection_reversed_passes``); both off by
default (docs/filter.md, "Offset grid").

* a grid offset joins the selection's candidates only away from all of them;
* the settings' one-line errors and the ``tracker.toml`` keys (``[]``: off);
* the selection runs a tight pass at each grid offset, and only when it runs
  (a device whose pass-1 candidates stay near the enrolled power gets none);
* the runner-up passes' reversed passes, largest evidence first, none by
  default;
* end to end, σ = 3 dB, device +6 dB: on tuning seed 7628 the default's
  passes never come near +6 dB and every candidate is a wrong lock (121°);
  the grid's +6 dB pass wins (1.3°). On tuning seed 7662 the grid's +6 dB pass
  wins the evidence and its reversed pass misses the truth's basin (93.9°);
  the runner-up's (+5.1 dB) reversed pass reaches it (1.6°). The parts
  removed leave the wrong locks.

Tuning seeds only (7600–7639 chose the grid, 7640–7699 checked it; 7662 led
to the runner-up's reversed pass).
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from filter_support import BEFORE_COARSE, loud_run
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig, offset
from radiopose.filtering.offset import OffsetPass, with_offsets_apart
from radiopose.tracker import TrackerConfig
from radiopose.tracker import filter as filter_method
from radiopose.tracker_settings import read_tracker_settings

GRID_DB = (-6.0, -3.0, 3.0, 6.0)


def test_grid_offsets_join_the_candidates_only_away_from_them() -> None:
    assert with_offsets_apart([0.0, 4.2], GRID_DB, 0.75) == [0.0, 4.2, -6.0, -3.0, 3.0, 6.0]
    assert with_offsets_apart([0.0, 5.5], (3.0, 6.0), 0.75) == [0.0, 5.5, 3.0]  # 6 is within 0.75
    assert with_offsets_apart([0.0], (), 0.75) == [0.0]
    assert with_offsets_apart([0.0], (0.5, 3.0, 3.0), 0.75) == [0.0, 3.0]  # repeats merge too


def test_settings_are_checked(tmp_path: Path) -> None:
    assert FilterConfig().offset_selection_grid_db == ()  # off by default
    assert FilterConfig().offset_selection_reversed_passes == 1
    for bad in ((math.nan,), (3.0, math.inf), (61.0,)):
        with pytest.raises(InputError, match="offset_selection_grid_db"):
            FilterConfig(offset_selection_grid_db=bad)
    for n in (0, 17, True, 1.5):
        with pytest.raises(InputError, match="offset_selection_reversed_passes"):
            FilterConfig(offset_selection_reversed_passes=n)  # type: ignore[arg-type]
    p = tmp_path / "tracker.toml"
    p.write_text(
        "[filter]\noffset_selection_grid_db = [-3.0, 3.0]\noffset_selection_reversed_passes = 2\n",
        encoding="utf-8",
    )
    over = read_tracker_settings(p).filter_overrides
    assert tuple(over["offset_selection_grid_db"]) == (-3.0, 3.0)
    assert over["offset_selection_reversed_passes"] == 2
    p.write_text("[filter]\noffset_selection_grid_db = []\n", encoding="utf-8")
    assert tuple(read_tracker_settings(p).filter_overrides["offset_selection_grid_db"]) == ()
    p.write_text('[filter]\noffset_selection_grid_db = ["x"]\n', encoding="utf-8")
    with pytest.raises(InputError, match="offset_selection_grid_db"):
        read_tracker_settings(p)


def _selection_centres(monkeypatch: pytest.MonkeyPatch, beliefs_db: list[float]) -> list[float]:
    """The tight passes' centres that :func:`select_offset` runs with the grid
    ``GRID_DB``, pass 1's beliefs ``beliefs_db`` and no particles (the passes are
    stand-ins that record their centre; their evidence is ``-c²``)."""
    ran: list[float] = []

    def fake_pass(pf: object, seed: int, records: list, c: float, per_packet: object) -> tuple:
        ran.append(c)
        return [], -(c**2)

    monkeypatch.setattr(offset, "run_pass", fake_pass)
    monkeypatch.setattr(offset, "ParticleFilter", lambda *a: None)
    pf = SimpleNamespace(
        config=FilterConfig(offset_selection_grid_db=GRID_DB), model=None, lag_s=1.0
    )
    st = SimpleNamespace(particles=None, log_weights=None, log_evidence=-1e9)
    offset.select_offset(pf, st, 0, [], [], np.array(beliefs_db))  # type: ignore[arg-type]
    return ran


def test_grid_passes_run_only_when_the_selection_does(monkeypatch: pytest.MonkeyPatch) -> None:
    # pass 1's beliefs near +4.2 dB: the selection runs, at 0, 4.2 and the grid
    # points not within 0.75 dB of those
    assert _selection_centres(monkeypatch, [4.2, 4.2]) == [0.0, 4.2, -6.0, -3.0, 3.0, 6.0]
    # beliefs near the enrolled power: no selection, so no grid pass either
    assert _selection_centres(monkeypatch, [0.3, 0.3]) == []


def test_runner_up_reversed_passes_largest_evidence_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ran: list[float] = []

    def fake_reversed(pf: object, records: list, centre_db: float, seed: int) -> tuple:
        ran.append(centre_db)
        return [("k", centre_db)], {}

    monkeypatch.setattr(filter_method, "run_reversed", fake_reversed)
    passes = [OffsetPass(math.nan, -10.0), OffsetPass(0.0, -30.0), OffsetPass(5.1, -2.0),
              OffsetPass(6.0, -1.0)]  # fmt: skip

    def more(n: int, ps: list[OffsetPass] = passes, best: int = 3) -> list:
        pf = SimpleNamespace(config=FilterConfig(offset_selection_reversed_passes=n))
        ran.clear()
        return filter_method._more_reversed(pf, [], ps, best, 0, 1)  # type: ignore[arg-type]

    assert more(1) == [] and ran == []  # the default: the chosen pass's only
    assert more(2) == [[("k", 5.1)]] and ran == [5.1]  # the runner-up, not the chosen +6.0
    assert len(more(3)) == 2 and ran[0] == 5.1 and math.isnan(ran[1])  # then pass 1 (wide)
    assert len(more(16)) == 3  # at most the passes there are, the chosen one left out
    assert more(2, passes[:1], 0) == []  # the selection ran no further pass


# ------------------------------------------------- end to end: tuning seeds 7628, 7662
def _loud_run(seed: int, **over: object) -> tuple[float, float]:
    """Offline ``filter`` errors (m, °) at σ = 3 dB, device +6 dB (filter_support),
    without the coarse-grid HMM candidate (``BEFORE_COARSE``: these cases were
    found without it, and it leaves 7628's lock by itself)."""
    return loud_run(seed, 3.0, TrackerConfig(), **{**BEFORE_COARSE, **over})


grid = partial(_loud_run, offset_selection_grid_db=GRID_DB)


@pytest.mark.slow  # an option off by default (offset_selection_grid_db = ()): session 14's cut
def test_loud_grid_pass_leaves_the_wrong_lock() -> None:
    """Tuning seed 7628: measured 4.29 m / 121.4° by default, 0.12 m / 1.3° with
    the grid."""
    pos_m, ori_deg = _loud_run(7628)
    assert ori_deg > 60.0 and pos_m > 2.0  # the part removed: the wrong lock stays
    pos_m, ori_deg = grid(7628)
    assert ori_deg < 5.0 and pos_m < 0.5


@pytest.mark.slow  # an option off by default (offset_selection_grid_db = ()): session 14's cut
def test_loud_runner_up_reversed_pass_reaches_the_truth() -> None:
    """Tuning seed 7662: measured 1.10 m / 93.9° with the grid alone (the +6 dB
    pass's reversed pass misses), 0.09 m / 1.6° with the runner-up's reversed
    pass too."""
    pos_m, ori_deg = grid(7662)
    assert ori_deg > 45.0 and pos_m > 0.6  # the part removed
    pos_m, ori_deg = grid(7662, offset_selection_reversed_passes=2)
    assert ori_deg < 5.0 and pos_m < 0.5
