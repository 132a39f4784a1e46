"""Issue 15, +6 dB at σ = 3 dB: the offline offset profile over a coarse pose grid
(:mod:`radiopose.filtering.offset_profile`; ``FilterConfig.offline_offset_profile``,
off by default; docs/filter.md "Accuracy round 8").

* the window kernel against a brute-force sum over a small table;
* the profile is shift-equivariant (readings ``d`` dB louder move it by ``d``)
  and finds the offset of the small site's noise-light file within 1 dB;
* the windows' medians and counts; the coarse grid's poses and table;
* the profile's offset joins the selection's candidates only away from all of
  them; the settings' one-line errors and the ``tracker.toml`` key;
* end to end on tuning seed 7320 (σ = 3 dB, +6 dB): the default's tight passes
  run at 0 and +4.1 dB only and the arbiter keeps a wrong lock (69.6°, 3.1 m);
  with the option the profile's +6.0 dB pass is run and wins (0.90°, 0.13 m).
  The part removed (the option off) leaves the wrong lock. On 7301 a losing
  profile pass would win a tie of the arbiter (``offset_profile_track =
  "always"``, 0.60 m); as it is (``"winner"``) the run stays at 0.32 m.

Tuning seeds only (7300–7349 chose the option; 7350–7399 checked it).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from filter_support import loud_run, small_site, tracker_before_angular_noise
from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.offset import with_offsets_apart
from radiopose.filtering.offset_profile import (
    CoarseTable,
    data_offset_db,
    offset_profile,
    window_medians,
    window_offset_costs,
)
from radiopose.likelihood import HeardRss
from radiopose.tracker_settings import read_tracker_settings


def _shifted(records: list, d_db: float) -> list:
    return [(t, HeardRss(h.receiver_index, h.rss_dbm + d_db), k) for t, h, k in records]


def test_window_kernel_is_the_brute_force_sum() -> None:
    rng = np.random.default_rng(3)
    table = rng.normal(-60.0, 8.0, (50, 4))
    table[7, 2] = math.nan  # a pose without a map value at a heard receiver is left out
    heard = np.array([0, 2, 3], dtype=np.int64)
    rss = np.array([-58.0, -63.0, -61.5])
    w = np.array([2.0, 1.0, 0.5])
    offs = np.array([-3.0, 0.0, 2.5])
    marg, prof = np.zeros(3), np.zeros(3)
    window_offset_costs(table, heard, rss, w, offs, marg, prof)
    ok = np.isfinite(table[:, heard]).all(axis=1)
    e = rss[None, :] - table[ok][:, heard]
    c = 0.5 * (w * (e[:, None, :] - offs[None, :, None]) ** 2).sum(axis=2)  # (pose, offset)
    np.testing.assert_allclose(prof, -c.min(axis=0), rtol=1e-12)
    np.testing.assert_allclose(marg, np.log(np.exp(-c).sum(axis=0)), rtol=1e-10)


def test_profile_moves_with_the_readings_and_finds_the_offset() -> None:
    site = small_site()
    table = CoarseTable.build(site.model, 1.0, 15.0)
    offs = np.arange(-6.0, 6.01, 0.5)
    base = offset_profile(table, site.records, 0.5, offs, 0.1, 0.5)
    up = offset_profile(table, _shifted(site.records, 2.0), 0.5, offs + 2.0, 0.1, 0.5)
    np.testing.assert_allclose(up.marginal, base.marginal, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(up.profile, base.profile, rtol=1e-9, atol=1e-6)
    assert base.n_windows == 5  # 0.5 s in windows of 0.1 s
    for d in (0.0, 6.0, -4.0):  # σ = 0.5 dB: the argmax within 1 dB of the device's offset
        assert abs(data_offset_db(site.model, _shifted(site.records, d), 0.5) - d) <= 1.0
    assert math.isnan(offset_profile(table, [], 0.5, offs).best_db())
    with pytest.raises(ValueError, match="sigma_db"):
        offset_profile(table, site.records, 0.0, offs)


def test_windows_are_medians_with_counts() -> None:
    def rec(t: float, rx: list[int], rss: list[float]) -> tuple:
        return (t, HeardRss(np.array(rx, dtype=np.int64), np.array(rss)), t)

    records = [
        rec(0.00, [0, 1], [-50.0, -60.0]),
        rec(0.05, [0, 1], [-52.0, -70.0]),
        rec(0.08, [0], [-51.0]),
        rec(0.25, [1, 2], [-40.0, -45.0]),
    ]
    w = window_medians(records, 0.1)
    assert len(w) == 2  # the empty window 0.1–0.2 s is skipped
    (h0, n0), (h1, n1) = w
    assert h0.receiver_index.tolist() == [0, 1] and h0.rss_dbm.tolist() == [-51.0, -65.0]
    assert n0.tolist() == [3.0, 2.0]
    assert h1.receiver_index.tolist() == [1, 2] and n1.tolist() == [1.0, 1.0]
    with pytest.raises(ValueError, match="window_s"):
        window_medians(records, 0.0)


def test_coarse_grid_covers_the_map_and_is_the_models_expected_rss() -> None:
    site = small_site()
    table = CoarseTable.build(site.model, 1.0, 15.0)
    x_lo, x_hi = site.model.box_m[:2]
    n_side = round(float(x_hi - x_lo) / 1.0) + 1
    assert table.poses.shape == (n_side * n_side * 24, 3)
    assert table.poses[:, 0].min() == x_lo and table.poses[:, 0].max() == x_hi
    assert sorted(set(table.poses[:, 2].tolist()))[:3] == [0.0, 15.0, 30.0]
    assert table.table_dbm.shape == (table.poses.shape[0], site.model.receivers_m.shape[0])
    i = 1234  # one pose's row is the model's expected RSS at that pose
    S = np.zeros((1, K.N_COLUMNS))
    S[0, K.X_M], S[0, K.Y_M] = table.poses[i, :2]
    S[0, K.Z_M] = site.model.space.positions_m[0, 2]
    S[0, K.AZIMUTH_RAD] = np.deg2rad(table.poses[i, 2])
    n_rx = site.model.receivers_m.shape[0]
    np.testing.assert_allclose(table.table_dbm[i], site.model.expected(S, np.arange(n_rx))[0])
    with pytest.raises(ValueError, match="positive"):
        CoarseTable.build(site.model, 0.0, 15.0)


def test_profile_offset_joins_the_candidates_only_away_from_them() -> None:
    assert with_offsets_apart([0.0, 4.09], [6.0], 1.5) == [0.0, 4.09, 6.0]
    assert with_offsets_apart([0.0, 4.9], [6.0], 1.5) == [0.0, 4.9]  # within 1.5 dB of +4.9
    assert with_offsets_apart([0.0, 3.0], [math.nan], 1.5) == [0.0, 3.0]
    assert with_offsets_apart([0.0], [1.0], 1.5) == [0.0]


def test_settings_are_checked(tmp_path: Path) -> None:
    assert not FilterConfig().offline_offset_profile  # off by default
    with pytest.raises(InputError, match="offset_profile_tolerance_db"):
        FilterConfig(offset_profile_tolerance_db=0.0)
    assert FilterConfig().offset_profile_track == "winner"
    with pytest.raises(InputError, match="offset_profile_track"):
        FilterConfig(offset_profile_track="sometimes")
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\noffline_offset_profile = true\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides == {"offline_offset_profile": True}
    p.write_text('[filter]\noffline_offset_profile = "yes"\n', encoding="utf-8")
    with pytest.raises(InputError, match="offline_offset_profile"):
        read_tracker_settings(p)


# ------------------------------------------------- end to end: tuning seed 7320
def _loud_run(
    seed: int, sigma_db: float, profile: bool, track: str = "winner"
) -> tuple[float, float]:
    base = tracker_before_angular_noise()  # the case's wrong lock (filter_support)
    return loud_run(
        seed, sigma_db, base, offline_offset_profile=profile, offset_profile_track=track
    )


@pytest.mark.slow  # an option off by default (offline_offset_profile = false): session 14's cut
def test_round8_profile_pass_leaves_the_wrong_lock() -> None:
    """Tuning seed 7320, σ = 3 dB, device +6 dB: the default's tight passes ran at
    0 and +4.1 dB (pass 1's beliefs) and every arbiter candidate is metres off
    (69.6°, 3.14 m; the truth's refined objective 726.5 against the chosen
    1408.4: a search failure); the profile's pass at +6.0 dB wins the evidence
    and the arbiter (0.90°, 0.13 m, as the matched run)."""
    pos_m, ori_deg = _loud_run(7320, 3.0, profile=False)
    assert ori_deg > 40.0 and pos_m > 1.5  # the part removed: the wrong lock stays
    pos_m, ori_deg = _loud_run(7320, 3.0, profile=True)
    assert ori_deg < 5.0 and pos_m < 0.5


@pytest.mark.slow  # an option off by default (offline_offset_profile = false): session 14's cut
def test_round8_losing_profile_pass_is_no_arbiter_candidate() -> None:
    """Tuning seed 7301, σ = 3 dB, device +6 dB: the default is right (0.32 m,
    2.0°, the combined track); the profile's pass at +6.0 dB loses the evidence
    test to pass 1 by 0.1 nat, and as an arbiter candidate (``"always"``, the
    first version) its track wins a tie of the objective (714.5 against 714.6)
    at 0.60 m. With ``"winner"`` (the default of the option) a losing profile
    pass is not a candidate and the run stays as it was."""
    winner_m, winner_deg = _loud_run(7301, 3.0, profile=True)
    assert winner_m < 0.45 and winner_deg < 2.5
    always_m, _ = _loud_run(7301, 3.0, profile=True, track="always")
    assert always_m > 0.5  # the part removed: the losing pass's track wins the tie
