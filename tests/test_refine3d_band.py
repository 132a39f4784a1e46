"""The 3-D refinement's hand-held band prior (``radiopose.filtering.refine3d.PoseBand``,
``Pose3dConfig.hand_height_m`` / ``hand_pitch_deg``; docs/pose3d.md,
"A hand-held band, 2026-11-28"): its cost is the objective's, it pulls a weakly
observed track into the band and leaves one inside alone, it reaches the solve
from ``locate``, and bad settings are one-line errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from filter_support import SCENE_3D, SEED_3D, refine_scene_3d
from radiopose.errors import InputError
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.filtering.refine3d import PoseBand, refine_track
from radiopose.simulate.handheld import simulate_handheld
from radiopose.tracker import TrackerConfig, locate
from radiopose.tracker_settings import read_tracker_settings


@pytest.fixture(scope="module")
def scene():
    return refine_scene_3d()


def test_the_band_costs_its_formula_inside_the_objective(scene):
    """At a track below the height band and above the pitch band, the objective
    with the band exceeds the one without by exactly ``PoseBand.cost``
    (½ Σ dt/τ (d/sd)²); inside both bands the cost is 0."""
    sim, model, t, heard, prior = scene
    pos = sim.truth.position_m.copy()
    ori = sim.truth.orientation_deg.copy()
    lo_z = float(pos[:, 2].max()) + 0.2
    hi_p = float(ori[:, 1].min()) - 10.0
    band = PoseBand(height_m=(lo_z, lo_z + 0.5), pitch_deg=(hi_p - 30.0, hi_p), time_s=0.5)
    d_z = lo_z - pos[:, 2]
    d_p = ori[:, 1] - hi_p
    share = np.diff(np.concatenate([[t[0]], 0.5 * (t[1:] + t[:-1]), [t[-1]]]))
    by_hand = 0.5 * np.sum(share / 0.5 * ((d_z / 0.1) ** 2 + (d_p / 10.0) ** 2))
    assert band.cost(t, pos, ori) == pytest.approx(by_hand, rel=1e-12)
    assert by_hand > 1.0
    kw = {"max_nfev": 1}
    with_band = refine_track(model, t, heard, pos, ori, 0.0, 0.5, prior, band=band, **kw)
    without = refine_track(model, t, heard, pos, ori, 0.0, 0.5, prior, **kw)
    assert with_band.initial_cost - without.initial_cost == pytest.approx(by_hand, rel=1e-9)
    inside = PoseBand(height_m=(0.0, 5.0), pitch_deg=(-90.0, 90.0))
    assert inside.cost(t, pos, ori) == 0.0


def test_the_band_pulls_a_weakly_observed_track_and_leaves_one_inside(scene):
    """Readings weighed lightly (σ 20 dB) and a tight band (sd 0.02 m, 1°) 0.3 m
    above the true height and 15° below the true pitch: the refined track moves
    into reach of the band (height up by > 0.2 m, pitch down by > 10°); without
    the band, or with a band containing the truth, it stays at the truth
    (within 0.05 m and 2°). No motion prior (it would flatten a weakly
    observed height by itself). A band with the wrong sign of its pull, or no
    rows in the solve, breaks the first bound."""
    sim, model, t, heard, _ = scene
    pos, ori = sim.truth.position_m, sim.truth.orientation_deg
    z_top = float(pos[:, 2].max())
    p_low = float(ori[:, 1].min())
    above = PoseBand(height_m=(z_top + 0.3, z_top + 0.6), height_sd_m=0.02,
                     pitch_deg=(p_low - 45.0, p_low - 15.0), pitch_sd_deg=1.0)  # fmt: skip
    around = replace(above, height_m=(0.0, 3.0), pitch_deg=(-89.0, 89.0))
    run = {"max_nfev": 60}
    pulled = refine_track(model, t, heard, pos, ori, 0.0, 20.0, None, band=above, **run)
    assert np.all(pulled.position_m[:, 2] - pos[:, 2] > 0.2)
    assert np.all(ori[:, 1] - pulled.orientation_deg[:, 1] > 10.0)
    for band in (None, around):
        stay = refine_track(model, t, heard, pos, ori, 0.0, 20.0, None, band=band, **run)
        assert np.abs(stay.position_m[:, 2] - pos[:, 2]).max() < 0.05
        assert np.abs(stay.orientation_deg[:, 1] - ori[:, 1]).max() < 2.0


def test_locate_hands_the_band_to_every_solve(monkeypatch):
    """``hand_height_m`` / ``hand_pitch_deg`` (and their spreads, τ the heading
    prior's) reach every refinement solve and, with ``hand_band_filter``, the
    filter's weights at every packet; without a band neither sees one."""
    import radiopose.filtering.refine3d as r3

    assert Pose3dConfig().hand_band() is None
    sim = simulate_handheld(replace(SCENE_3D, n_receivers=6, duration_s=0.2), seed=SEED_3D)
    seen: list[PoseBand | None] = []
    real = r3.refine_track

    def spy(*args, **kwargs):
        seen.append(kwargs.get("band"))
        return real(*args, **kwargs)

    monkeypatch.setattr(r3, "refine_track", spy)
    import radiopose.filtering.particle3d as p3mod

    weighed: list[PoseBand] = []
    real_band = p3mod._band_prior

    def band_spy(S, logw, band, dt_s):
        weighed.append(band)
        real_band(S, logw, band, dt_s)

    monkeypatch.setattr(p3mod, "_band_prior", band_spy)
    cfg = TrackerConfig()
    cheap = replace(cfg.pose3d, refine_orientation_path=False, refine_reverse_pass=False,
                    refine_coarse_path=False, refine_escalate_ratio=0.0)  # fmt: skip
    p3 = replace(cheap, hand_height_m=(0.8, 1.6), hand_pitch_deg=(20, 70), hand_pitch_sd_deg=7.0,
                 heading_prior_time_s=2.0, hand_band_filter=True)  # fmt: skip
    locate(sim.site, sim.packets, "filter", replace(cfg, pose3d=p3))
    want = PoseBand(height_m=(0.8, 1.6), height_sd_m=0.1, pitch_deg=(20.0, 70.0),
                    pitch_sd_deg=7.0, time_s=2.0)  # fmt: skip
    assert len(seen) >= 2 and all(b == want for b in seen)
    assert len(weighed) > 100 and all(b == want for b in weighed)  # the filter's packets
    seen.clear()
    weighed.clear()
    p3 = replace(cheap, hand_pitch_deg=(20, 70), hand_band_filter=False)
    locate(sim.site, sim.packets, "filter", replace(cfg, pose3d=p3))
    assert seen and all(b is not None and b.height_m is None for b in seen)
    assert not weighed  # the refinement only
    seen.clear()
    locate(sim.site, sim.packets, "filter", replace(cfg, pose3d=cheap))
    assert seen and all(b is None for b in seen) and not weighed


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("hand_height_m", (1.6, 0.8)),
        ("hand_height_m", (0.8,)),
        ("hand_height_m", (0.8, float("nan"))),
        ("hand_pitch_deg", (20.0, 95.0)),
        ("hand_pitch_deg", (1.0, 2.0, 3.0)),
        ("hand_height_sd_m", 0.0),
        ("hand_pitch_sd_deg", float("inf")),
    ],
)
def test_bad_band_settings_are_one_line_errors(field, value):
    with pytest.raises(InputError, match=field) as err:
        Pose3dConfig(**{field: value})
    assert "\n" not in str(err.value)


def test_band_settings_read_from_tracker_toml(tmp_path: Path) -> None:
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\nhand_height_m = [0.8, 1.6]\nhand_pitch_deg = []\n")
    got = read_tracker_settings(p).pose3d()
    assert tuple(got.hand_height_m) == (0.8, 1.6) and got.hand_pitch_deg == ()
    band = got.hand_band()
    assert band is not None and band.height_m == (0.8, 1.6) and band.pitch_deg is None
    p.write_text("[filter.pose3d]\nhand_pitch_deg = [70, 20]\n")
    with pytest.raises(InputError, match="hand_pitch_deg") as err:
        read_tracker_settings(p)
    assert str(p) in str(err.value)
    with pytest.raises(InputError, match="height_m"):
        PoseBand(height_m=(2.0, 1.0))


def test_the_filter_weighs_the_band_per_packet():
    """``_band_prior``: ``−½ (dt/τ) (d/sd)²`` per particle outside the band
    (height in metres, pitch in radians inside the filter), nothing inside."""
    from radiopose.filtering import kernels as K  # noqa: N812
    from radiopose.filtering.particle3d import _band_prior

    band = PoseBand(height_m=(0.8, 1.6), height_sd_m=0.1, pitch_deg=(20.0, 70.0),
                    pitch_sd_deg=10.0, time_s=2.0)  # fmt: skip
    S = np.zeros((3, 9))
    S[:, K.Z_M] = [1.2, 0.6, 1.9]
    S[:, K.PITCH_RAD] = np.deg2rad([45.0, 45.0, 80.0])
    logw = np.full(3, -1.0)
    _band_prior(S, logw, band, 0.5)
    w = 0.5 / 2.0
    want = -1.0 - 0.5 * w * np.array([0.0, (0.2 / 0.1) ** 2, (0.3 / 0.1) ** 2 + 1.0])
    np.testing.assert_allclose(logw, want, rtol=1e-12)
