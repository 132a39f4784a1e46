"""The 3-D refinement's annealed starts (``Pose3dConfig.refine_anneal_sigma``,
``refine_anneal_keep_direct``; docs/pose3d.md, "Annealed refinement"): each
start is first refined at σ times each factor, largest first, each solve from
the last one's optimum, then at σ; with ``keep_direct`` the start is also
refined at σ directly and the lower objective stands. Off by default; the
settings are validated; end to end on a tuning seed whose default ends in a
180° wrong mode (marked ``slow``: ``pytest -m slow`` runs it).

The solve order is checked over a fake solve; the end-to-end check uses tuning
seed SEED_FIXED only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from filter_support import require_wrong_mode
from radiopose.errors import InputError
from radiopose.evaluate.pose3d import axis_errors
from radiopose.filtering import FilterConfig, refine3d
from radiopose.filtering.config import FilterEstimate
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.likelihood import HeardRss
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings

SEED_FIXED = 7481
"""A tuning seed (6 receivers, σ 1 dB, 4 s) whose default track ends in a
near-180° wrong mode (0.99 m / 175.6°) that the annealed starts fix (0.19 m /
12.3°; docs/pose3d.md, "Annealed refinement")."""


def _solves(
    monkeypatch: pytest.MonkeyPatch, anneal: tuple[float, ...], keep_direct: bool, costs: dict
) -> tuple[float, list[tuple[float, float]]]:
    """:func:`refine_smoothed` over a fake solve, one start at x = 0 m and no
    polish: each solve moves the track's x by 1 m and returns the objective
    ``costs[(σ, start x)]`` (σ 1 dB). Returns the kept track's x and the solves made
    as ``(σ, start x)``."""
    n = 12
    t = np.arange(n) * 0.005
    heard = HeardRss(np.array([0, 1]), np.array([-50.0, -60.0]))
    records = [(float(ti), heard, i) for i, ti in enumerate(t)]
    track = [(i, FilterEstimate((0.0, 1.0, 1.2), (10.0, 40.0, 0.0), 0.1, 1.0, 0.0, 1.0))
             for i in range(n)]  # fmt: skip
    calls: list[tuple[float, float]] = []

    def fake(model, times, h, pos, ori, off, sigma, prior, **kw):  # type: ignore[no-untyped-def]
        calls.append((float(sigma), float(pos[0, 0])))
        moved = np.array(pos, dtype=float)
        moved[:, 0] += 1.0
        cost = costs[(float(sigma), float(pos[0, 0]))]
        return refine3d.RefinedTrack(moved, np.array(ori), off, sigma, cost, cost, 1)

    monkeypatch.setattr(refine3d, "refine_track", fake)
    out = refine3d.refine_smoothed(
        None, records, track, FilterConfig(), 0.2, 20.0, 10, polish_starts=0,  # type: ignore[arg-type]
        anneal_sigma=anneal, anneal_keep_direct=keep_direct,
    )  # fmt: skip
    return out[0][1].position_m[0], calls


def test_each_start_is_solved_at_each_factor_then_at_sigma(monkeypatch: pytest.MonkeyPatch):
    costs = {(10.0, 0.0): 1.0, (3.0, 1.0): 2.0, (1.0, 2.0): 50.0, (1.0, 0.0): 9.0}
    x, calls = _solves(monkeypatch, (), False, costs)
    assert calls == [(1.0, 0.0)] and x == 1.0  # off: one solve at σ
    x, calls = _solves(monkeypatch, (10.0, 3.0), False, costs)
    assert calls == [(10.0, 0.0), (3.0, 1.0), (1.0, 2.0)] and x == 3.0  # each from the last


def test_keep_direct_keeps_the_lower_objective(monkeypatch: pytest.MonkeyPatch):
    annealed_lower = {(3.0, 0.0): 0.0, (1.0, 1.0): 4.0, (1.0, 0.0): 5.0}
    x, calls = _solves(monkeypatch, (3.0,), True, annealed_lower)
    assert calls == [(3.0, 0.0), (1.0, 1.0), (1.0, 0.0)] and x == 2.0  # the annealed track
    direct_lower = {(3.0, 0.0): 0.0, (1.0, 1.0): 6.0, (1.0, 0.0): 5.0}
    x, _ = _solves(monkeypatch, (3.0,), True, direct_lower)
    assert x == 1.0  # the direct solve's track
    x, calls = _solves(monkeypatch, (3.0,), False, direct_lower)
    assert len(calls) == 2 and x == 2.0  # without keep_direct: the annealed track, however high


def test_settings_are_checked(tmp_path: Path) -> None:
    assert Pose3dConfig().refine_anneal_sigma == ()  # off by default
    assert Pose3dConfig().refine_anneal_keep_direct is False
    for bad in ((1.0,), (0.5,), (3.0, 10.0), (float("nan"),), (101.0,)):
        with pytest.raises(InputError, match="refine_anneal_sigma"):
            Pose3dConfig(refine_anneal_sigma=bad)
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\nrefine_anneal_sigma = [3.0]\nrefine_anneal_keep_direct = true\n")
    got = read_tracker_settings(p).pose3d()
    assert tuple(got.refine_anneal_sigma) == (3.0,) and got.refine_anneal_keep_direct is True
    p.write_text("[filter.pose3d]\nrefine_anneal_sigma = [2.0, 4.0]\n")
    with pytest.raises(InputError, match="refine_anneal_sigma"):
        read_tracker_settings(p)


@pytest.mark.slow  # two 3-D offline runs (~40 CPU s); the option is off (not confirmed)
def test_annealed_starts_leave_a_flipped_mode():
    """Tuning seed SEED_FIXED (6 receivers, σ 1 dB, 4 s, offline): by default
    the track ends in a near-180° wrong mode; with the starts annealed at 3 σ
    it does not. Removing the annealing breaks the second bound."""
    cfg = replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=4.0)
    sim = simulate_handheld(cfg, seed=SEED_FIXED)
    base = TrackerConfig()
    on = replace(base, pose3d=replace(base.pose3d, refine_anneal_sigma=(3.0,)))
    e_off = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", base).estimates)
    # the later default stages (coarse path, orientation path, detrended maps)
    # leave this flip by themselves on some hosts (12.5° seen 2026-11-28)
    require_wrong_mode(float(e_off.rotation_deg.mean()), 90.0, f"seed {SEED_FIXED} by default")
    assert e_off.position_m.mean() > 0.6
    e_on = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", on).estimates)
    assert e_on.rotation_deg.mean() < 20.0 and e_on.position_m.mean() < 0.3
    assert e_on.coverage == 1.0
