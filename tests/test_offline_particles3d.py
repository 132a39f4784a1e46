"""The 3-D filter's offline particle count (``Pose3dConfig.offline_n_particles``;
docs/pose3d.md, "Offline particles, 2026-11-27"): which passes use it (only the
offline ones: batch ``locate`` with a smoothing lag — forward, reversed pass,
mid-track restarts), that the causal filter, the streaming ``Tracker`` and the
live path never do, that the setting is validated, and end to end on a tuning
seed where the default ends in a wrong mode.

Seeds: 18018's small scene; the end-to-end check uses tuning seed SEED_FIXED only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from filter_support import require_wrong_mode
from radiopose.errors import InputError
from radiopose.evaluate.pose3d import axis_errors
from radiopose.filtering import particle3d
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import Tracker, TrackerConfig, locate
from radiopose.tracker.batch import _check_packets as check_packets
from radiopose.tracker_settings import read_tracker_settings, write_tracker_toml

SEED_FIXED = 7407
"""A tuning seed (6 receivers, σ 1 dB, 4 s) whose default track ends in a wrong
mode (1.44 m / 46.4°) that four times the offline particles fix (0.17 m / 3.3°;
docs/pose3d.md, "Offline particles, 2026-11-27")."""

OFFLINE_PARTICLES_FIXED = 8000
"""The offline particle count of the end-to-end check (4 × ``n_particles``)."""


@pytest.fixture()
def built(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The particle count of every whole 3-D filter built (offset-bank members,
    which have no bank of their own, are left out)."""
    sizes: list[int] = []
    real = particle3d.ParticleFilter3d.__init__

    def spy(self, model, config, lag_s=None, pose3d=None):  # type: ignore[no-untyped-def]
        if pose3d is not None and pose3d.offset_bank_db:
            sizes.append(pose3d.n_particles)
        real(self, model, config, lag_s, pose3d)

    monkeypatch.setattr(particle3d.ParticleFilter3d, "__init__", spy)
    return sizes


@pytest.mark.slow  # ~20 s for an option that is off (offline_n_particles = 0)
def test_only_the_offline_passes_use_it(built: list[int]):
    """Offline (batch ``locate`` with the smoothing lag) the forward pass, the
    reversed pass and each restart's two halves get ``offline_n_particles``
    (their members a fifth each); off (0, the default), causal ``locate`` and
    the streaming ``Tracker`` (the live server's) keep ``n_particles``."""
    sim = simulate_handheld(replace(HandheldConfig(), n_receivers=6, duration_s=0.3), seed=18018)
    base = TrackerConfig()
    assert base.pose3d.offline_n_particles == 0  # off by default
    assert base.pose3d.refine_reverse_pass  # the default runs the reversed pass
    n = base.pose3d.n_particles
    locate(sim.site, sim.packets, "filter", base)
    n_built = len(built)  # the forward pass's filter and the reversed pass's
    assert n_built >= 2 and set(built) == {n}
    on = replace(base, pose3d=replace(base.pose3d, offline_n_particles=3000))
    built.clear()
    locate(sim.site, sim.packets, "filter", on)
    assert built == [3000] * n_built
    built.clear()
    restarts = replace(on, pose3d=replace(on.pose3d, refine_restarts=1))
    locate(sim.site, sim.packets, "filter", restarts)
    assert len(built) > n_built and set(built) == {3000}  # + the restart's two halves
    built.clear()
    locate(sim.site, sim.packets, "filter", replace(on, smoothing_lag_s=None))
    assert built == [n]  # the causal filter
    built.clear()
    tracker = Tracker(sim.site, "filter", on, lag_s=on.smoothing_lag_s)  # streaming, as live
    for obs in check_packets(sim.site, sim.packets)[:20]:
        tracker.update(obs)
    assert built == [n]
    engine = next(iter(tracker._devices.values())).engine
    assert engine.config.n_particles == n
    assert [m.config.n_particles for m in engine._members] == [n // 5] * 5


def test_the_members_share_the_offline_count():
    """The offset bank splits ``offline_n_particles`` as it splits ``n_particles``."""
    p3 = Pose3dConfig(offline_n_particles=4000)
    assert p3.offline().n_particles == 4000
    assert p3.offline().offline_n_particles == 4000
    assert Pose3dConfig().offline() == Pose3dConfig()  # 0: unchanged


def test_the_setting_is_validated(tmp_path: Path):
    """``offline_n_particles`` (integer, 0 or 10 … 1,000,000; at least 10 per
    bank member) reads from ``[filter.pose3d]`` and round-trips; a wrong type
    or value is a one-line error naming the key."""
    p = tmp_path / "tracker.toml"
    p.write_text("[filter.pose3d]\noffline_n_particles = 4000\n")
    assert read_tracker_settings(p).pose3d().offline_n_particles == 4000
    p.write_text("[filter.pose3d]\noffline_n_particles = 0\n")
    assert read_tracker_settings(p).pose3d().offline_n_particles == 0
    q = tmp_path / "written.toml"
    write_tracker_toml(q, {}, None, "written by a test", pose3d={"offline_n_particles": 8000})
    assert read_tracker_settings(q).pose3d().offline_n_particles == 8000
    for value in ("-1", "1000001", "2.5", "true", '"many"'):
        p.write_text(f"[filter.pose3d]\noffline_n_particles = {value}\n")
        with pytest.raises(InputError) as exc:
            read_tracker_settings(p)
        assert exc.value.column == "filter.pose3d.offline_n_particles"
        assert "\n" not in str(exc.value)
    for value in ("5", "40"):  # below 10, or below 10 per member of the 5-member bank
        p.write_text(f"[filter.pose3d]\noffline_n_particles = {value}\n")
        with pytest.raises(InputError) as exc:
            read_tracker_settings(p)
        assert "\n" not in str(exc.value)
    for n in (-1, 5, 2_000_000):
        with pytest.raises(InputError) as exc2:
            Pose3dConfig(offline_n_particles=n)
        assert "offline_n_particles" in str(exc2.value) and "\n" not in str(exc2.value)
    assert Pose3dConfig(offline_n_particles=40, offset_bank_db=()).offline().n_particles == 40


@pytest.mark.slow  # ~60 s for an option that is off (offline_n_particles = 0)
def test_more_offline_particles_leave_a_wrong_mode():
    """Tuning seed SEED_FIXED (6 receivers, σ 1 dB, 4 s, offline): with 2,000
    particles (``offline_n_particles = 0``) the track ends in a wrong mode; with
    OFFLINE_PARTICLES_FIXED offline particles it refines into the right one.
    Removing the offline count breaks the second bound."""
    cfg = replace(HandheldConfig(), n_receivers=6, noise_db=1.0, duration_s=4.0)
    sim = simulate_handheld(cfg, seed=SEED_FIXED)
    base = TrackerConfig()
    off = replace(base, pose3d=replace(base.pose3d, offline_n_particles=0))
    on = replace(base, pose3d=replace(base.pose3d, offline_n_particles=OFFLINE_PARTICLES_FIXED))
    e_off = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", off).estimates)
    require_wrong_mode(
        e_off.rotation_deg.mean(), 20.0, f"seed {SEED_FIXED} with 2,000 offline particles"
    )
    assert e_off.position_m.mean() > 0.8
    e_on = axis_errors(sim.truth, locate(sim.site, sim.packets, "filter", on).estimates)
    assert e_on.rotation_deg.mean() < 6.0 and e_on.position_m.mean() < 0.3
    assert e_on.coverage == 1.0
