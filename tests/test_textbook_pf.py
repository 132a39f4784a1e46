"""Issue 15's anchor, the textbook particle filter told σ and the power
(``radiopose.evaluate.textbook_pf``): it tracks, each part of it matters, and
bad settings are one-line errors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.evaluate.textbook_pf import NAME, TextbookConfig, registered_textbook
from radiopose.packets import PacketObservation, group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import METHOD_NAMES, METHODS, Tracker, TrackerConfig
from radiopose.tracker.reasons import SKIP_OUT_OF_ORDER

SCENE = ScenarioConfig(size_m=10.0, step_m=0.25, duration_s=1.0, min_receiver_spacing_m=3.0)


@pytest.fixture(scope="module")
def sims():
    """Three small scenes at σ = 1 dB (seeds no accuracy table uses)."""
    out = []
    for seed in (31, 32, 33):
        sim = simulate(replace(SCENE, noise_db=1.0), seed)
        out.append((sim, build_scorer(sim, "numba")))
    return out


def _errors(sims, sigma_db: float = 1.0, **settings) -> tuple[float, float]:
    with registered_textbook(sigma_db, **settings):
        runs = [run_methods(sim, (NAME,), TrackerConfig(), sc)[NAME] for sim, sc in sims]
    assert all(len(r.estimates) == r.n_packets for r in runs)  # every packet answered
    pos = float(np.mean([r.position_error_m.mean() for r in runs]))
    ori = float(np.mean([r.orientation_error_deg.mean() for r in runs]))
    return pos, ori


def test_it_tracks_and_its_parts_matter(sims) -> None:
    pos, ori = _errors(sims)
    assert pos < 0.4 and ori < 6.0, (pos, ori)
    # without motion noise the cloud cannot follow the device; told a σ ten
    # times too small, the likelihood collapses onto a few (wrong) particles
    still = _errors(sims, accel_noise_mps2=0.0, angular_accel_noise_dps2=0.0)
    assert still[1] > ori + 5.0, (still, ori)
    assert _errors(sims, sigma_db=0.1)[1] > ori + 10.0


def test_re_drawn_particles_leave_a_decoy_start(sims) -> None:
    """The first 0.1 s carry the readings of the trace's last packet (the device
    1.2-1.4 m away): re-drawn particles find the device, a filter without them
    stays behind."""
    late: dict[float, list[float]] = {0.05: [], 0.0: []}
    for sim, _ in sims:
        obs = group_packets(sim.packets)
        far, t0 = obs[-1], obs[0].timestamp_s
        fed = [
            replace(o, receiver_ids=far.receiver_ids, rss_dbm=far.rss_dbm)
            if o.timestamp_s - t0 < 0.1
            else o
            for o in obs
        ]
        t_s, xy = sim.truth.timestamp_s, sim.truth.position_m[:, :2]
        for frac, errors in late.items():
            with registered_textbook(1.0, reentry_fraction=frac):
                tracker = Tracker(sim.site, NAME)
            for o in fed:  # (the tracker keeps its method object)
                est, _ = tracker.update(o)
                if o.timestamp_s - t0 >= 0.5:
                    j = int(np.argmin(np.abs(t_s - o.timestamp_s)))
                    errors.append(float(np.hypot(*(np.array(est.position_m[:2]) - xy[j]))))
    with_redraw, without = float(np.mean(late[0.05])), float(np.mean(late[0.0]))
    assert with_redraw < 0.35 and without > 2.0 * with_redraw + 0.15, (with_redraw, without)


def test_registered_only_inside_its_block_and_deterministic(sims) -> None:
    assert NAME not in METHOD_NAMES and NAME not in METHODS
    sim, sc = sims[0]
    with registered_textbook(1.0) as a:
        assert METHODS[NAME] is a and not a.lagged and a.estimates_orientation
        first = run_methods(sim, (NAME,), TrackerConfig(), sc)[NAME]
        second = run_methods(sim, (NAME,), TrackerConfig(), sc)[NAME]
        with registered_textbook(2.0) as b:  # nested: replaced, then restored
            assert METHODS[NAME] is b and b.config.sigma_db == 2.0
        assert METHODS[NAME] is a
    assert NAME not in METHODS  # gone after the block (the demo lists METHODS)
    np.testing.assert_array_equal(first.position_error_m, second.position_error_m)
    est = first.estimates
    assert np.all(est.position_std_m >= 0) and np.all(est.azimuth_std_deg >= 0)
    with pytest.raises(InputError), registered_textbook(-1.0):
        pass
    assert NAME not in METHODS


def test_a_packet_out_of_time_order_is_skipped(sims) -> None:
    sim = sims[0][0]
    with registered_textbook(1.0):
        tracker = Tracker(sim.site, NAME)
    tx = sim.site.devices[0].transmitter
    ids = tuple(r.receiver_id for r in sim.site.receivers)
    rss = np.full(len(ids), -60.0)
    assert tracker.update(PacketObservation("p1", 1.0, tx, ids, rss))[0] is not None
    est, reason = tracker.update(PacketObservation("p0", 0.5, tx, ids, rss))
    assert est is None and reason == SKIP_OUT_OF_ORDER


@pytest.mark.parametrize(
    ("settings", "said"),
    [
        ({"sigma_db": 0.0}, "sigma_db = 0.0 must be in [0.01, 30.0]"),
        ({"sigma_db": float("nan")}, "sigma_db = nan must be a finite number"),
        ({"n_particles": 10.5}, "n_particles = 10.5 must be an integer"),
        ({"reentry_fraction": 1.5}, "reentry_fraction = 1.5 must be in [0.0, 1.0]"),
        ({"k": 0}, "k = 0 must be in [1, 1000]"),
    ],
)
def test_bad_settings_are_one_line_errors(settings, said) -> None:
    with pytest.raises(InputError) as exc:
        TextbookConfig(**settings)
    assert said in str(exc.value) and "\n" not in str(exc.value)
