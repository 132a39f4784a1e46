"""3-D pose: conventions at the gimbal and roll wrap, the height model, the
hand-held simulation, the 3-D filter (a known pose recovered; stages removed
break it) and its dispatch from the ``filter`` method (docs/pose3d.md)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radiopose.errors import InputError
from radiopose.filtering import FilterConfig
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.filtering.kernels3d import tilt_height_step
from radiopose.filtering.particle3d import (
    FilterModel3d,
    ParticleFilter3d,
    Pose3dConfig,
    roll_support_deg,
)
from radiopose.geometry import relative_rotation_angle_deg
from radiopose.likelihood import HeardRss, candidate_space
from radiopose.packets import Packets, Truth, group_packets
from radiopose.patterns import isotropic
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.simulate.channel import link_rss_dbm
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.survey_height import build_height_model

POS_BOUND_M = 0.3
ROT_BOUND_DEG = 10.0
SMALL = HandheldConfig(
    size_m=10.0, step_m=0.5, n_receivers=6, duration_s=1.0, noise_db=0.0,
    min_receiver_spacing_m=3.0, survey_step_m=1.0,
)  # fmt: skip


def rot(az: float, pitch: float, roll: float) -> Rotation:
    return Rotation.from_euler("ZXY", [az, pitch, roll], degrees=True)


# ----------------------------------------------------------------------------- conventions
@pytest.mark.parametrize("seed", range(5))
def test_pole_identity(seed):
    """(az, p, r) and (az + 180, 180 − p, r + 180) are one rotation (the gimbal step)."""
    az, p, r = np.random.default_rng(seed).uniform([-180, -90, -180], [180, 90, 180])
    a = rot(az, p, r).as_matrix()
    b = rot(az + 180.0, 180.0 - p, r + 180.0).as_matrix()
    np.testing.assert_allclose(a, b, atol=1e-12)


def _particles(az_deg, pitch_deg, roll_deg, z_m=1.0):
    S = np.zeros((len(az_deg), K.N_COLUMNS))
    S[:, K.Z_M] = z_m
    S[:, K.AZIMUTH_RAD] = np.deg2rad(az_deg)
    S[:, K.PITCH_RAD] = np.deg2rad(pitch_deg)
    S[:, K.ROLL_RAD] = np.deg2rad(roll_deg)
    return S


@pytest.mark.parametrize(("pitch0", "step"), [(89.0, 3.0), (-89.0, -3.0), (90.0, 0.5)])
def test_pitch_over_the_pole_keeps_the_rotation(pitch0, step):
    """A pitch step past ±90° lands back in range as the same rotation."""
    S = _particles([30.0], [pitch0], [10.0])
    tilt = np.deg2rad([-90.0, 90.0, 0.0, 180.0])  # full pitch range, rolls wrap
    noise = np.array([[step, 0.0]])  # q_tilt = 1 rad/√s, dt = (1°)²: a step of `step` degrees
    tilt_height_step(S, noise, np.zeros(1), math.radians(1.0) ** 2, 1.0, 0.0, tilt, np.zeros(2))
    p = math.degrees(S[0, K.PITCH_RAD])
    assert -90.0 <= p <= 90.0
    got = [math.degrees(S[0, c]) for c in (K.AZIMUTH_RAD, K.PITCH_RAD, K.ROLL_RAD)]
    angle = relative_rotation_angle_deg(got, [30.0, pitch0 + step, 10.0])[0]
    assert angle == pytest.approx(0.0, abs=1e-9)
    assert abs(p) < abs(pitch0 + step)  # it was folded, not clipped


def test_pitch_reflects_inside_a_partial_range():
    S = _particles([0.0], [70.0], [0.0])
    tilt = np.deg2rad([0.0, 75.0, 0.0, 0.0])
    noise = np.array([[10.0, 0.0]])
    tilt_height_step(S, noise, np.zeros(1), math.radians(1.0) ** 2, 1.0, 0.0, tilt, np.zeros(2))
    assert math.degrees(S[0, K.PITCH_RAD]) == pytest.approx(70.0)  # 80 reflected at 75
    assert S[0, K.AZIMUTH_RAD] == 0.0


@pytest.mark.parametrize(
    ("rolls", "centre", "half"),
    [
        ((-45.0, -15.0, 15.0, 45.0), 0.0, 60.0),
        ((170.0, -170.0), 180.0, 20.0),  # the arc across ±180, not the long way round
        ((0.0, 90.0, 180.0, 270.0), 0.0, 180.0),  # covers the circle: wraps
        ((30.0,), 30.0, 0.0),
    ],
)
def test_roll_support(rolls, centre, half):
    c, h = roll_support_deg(rolls)
    assert abs((c - centre + 180.0) % 360.0 - 180.0) < 1e-9
    assert h == pytest.approx(half)


@pytest.mark.parametrize(
    ("roll0", "step", "tilt_deg", "expect"),
    [
        (179.0, 3.0, [0.0, 0.0, 0.0, 180.0], -178.0),  # whole circle: wraps
        (175.0, 10.0, [0.0, 0.0, 180.0, 20.0], -175.0),  # arc across ±180: wraps inside it
        (-165.0, 10.0, [0.0, 0.0, 180.0, 20.0], -165.0),  # -155 is 25 from 180: reflected at 20
        (-170.0, -15.0, [0.0, 0.0, 180.0, 20.0], 175.0),  # across ±180 inside the arc
        (15.0, 10.0, [0.0, 0.0, 0.0, 20.0], 15.0),  # 25 reflected at 20
    ],
)
def test_roll_steps_wrap_and_reflect(roll0, step, tilt_deg, expect):
    S = _particles([0.0], [0.0], [roll0])
    noise = np.array([[0.0, step]])
    tilt_height_step(
        S, noise, np.zeros(1), math.radians(1.0) ** 2, 1.0, 0.0, np.deg2rad(tilt_deg), np.zeros(2)
    )
    got = math.degrees(S[0, K.ROLL_RAD])
    assert -180.0 <= got < 180.0
    assert abs((got - expect + 180.0) % 360.0 - 180.0) < 1e-9


# ----------------------------------------------------------------------------- simulation
@pytest.fixture(scope="module")
def clean_sim():
    return simulate_handheld(SMALL, seed=424242)


def test_handheld_motion_in_human_ranges(clean_sim):
    t = clean_sim.truth
    assert t.position_m[:, 2].min() >= 0.8 - 1e-9 and t.position_m[:, 2].max() <= 1.6 + 1e-9
    assert t.orientation_deg[:, 1].min() >= 20.0 - 1e-9
    assert t.orientation_deg[:, 1].max() <= 70.0 + 1e-9
    roll = (t.orientation_deg[:, 2] + 180.0) % 360.0 - 180.0
    assert np.abs(roll).max() <= 25.0 + 1e-9
    z_rx = np.array([r.z_m for r in clean_sim.site.receivers])
    assert np.all((z_rx[::2] >= 2.5) & (z_rx[::2] <= 3.0))  # ceiling
    assert np.all(z_rx[1::2] < 2.5)
    assert clean_sim.site.area.has_height_range
    assert not clean_sim.site.device_pattern(clean_sim.truth.transmitter[0]).is_slice


def test_handheld_is_deterministic(tmp_path):
    cfg = replace(SMALL, duration_s=0.05)
    simulate_handheld(cfg, seed=5).write(tmp_path / "a")
    simulate_handheld(cfg, seed=5).write(tmp_path / "b")
    for f in ("packets.csv", "truth.csv", "site/survey.csv", "site/receivers.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()


def test_handheld_rejects_bad_settings():
    with pytest.raises(InputError, match="pitch_range_deg"):
        simulate_handheld(replace(SMALL, pitch_range_deg=(20.0, 100.0)))
    with pytest.raises(InputError, match="z_step_m"):
        simulate_handheld(replace(SMALL, z_step_m=0.25))


# ----------------------------------------------------------------------------- height model
def test_parallel_kernels_do_not_depend_on_the_threads(clean_sim):
    """The expected RSS and the coarse costs run over numba's threads; one thread
    and two give the same numbers, bit for bit (one row is one thread's work)."""
    import numba

    from radiopose.filtering.kernels3d import coarse_costs

    site = clean_sim.site
    model = FilterModel3d.build3d(
        site, candidate_space(site, site.devices[0].transmitter),
        Pose3dConfig(acquisition_step_m=2.0, acquisition_tilts=2),
    )  # fmt: skip
    rng = np.random.default_rng(11)
    n = 3001  # not a multiple of the thread count
    S = _particles(rng.uniform(0, 360, n), rng.uniform(-80, 80, n), rng.uniform(-180, 180, n))
    S[:, K.X_M], S[:, K.Y_M] = rng.uniform(0, 10, n), rng.uniform(0, 10, n)
    S[:, K.Z_M] = rng.uniform(0.8, 1.6, n)
    heard = np.array([0, 2, 3], dtype=np.int64)
    table = model.coarse.table_dbm
    rss = np.array([-60.0, -55.0, -70.0])
    before = numba.get_num_threads()
    results = []
    try:
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}, reverse=True):
            numba.set_num_threads(threads)
            cost = np.empty(table.shape[0])
            coarse_costs(table, heard, rss, 3.0, 1.0, 6.0, cost)
            results.append((model.expected(S, heard), cost))
    finally:
        numba.set_num_threads(before)
    assert np.isfinite(results[0][0]).all() and np.isfinite(results[0][1]).all()
    for expected, cost in results[1:]:
        assert np.array_equal(expected, results[0][0]) and np.array_equal(cost, results[0][1])


def test_height_model_reproduces_the_channel(clean_sim):
    """Noise-free: the 3-D expected RSS at the true poses is the simulated RSS, and
    at heights far from the surveyed one (0.6 m, 1.8 m; survey at 1.2 m) the
    channel recomputed there; without the height correction (exponent 0) it is not."""
    site = clean_sim.site
    hm = build_height_model(site, detrend=False)
    assert hm.exponent == pytest.approx(3.0, abs=0.2)  # LogDistance's exponent, fitted
    model = FilterModel3d.build3d(
        site, candidate_space(site, site.devices[0].transmitter),
        Pose3dConfig(acquisition_step_m=5.0, acquisition_tilts=2),
    )  # fmt: skip
    t = clean_sim.truth
    S = _particles(*t.orientation_deg.T)
    S[:, :3] = t.position_m
    heard = np.arange(len(site.receivers))
    rss = clean_sim.packets.rss_dbm.reshape(-1, heard.size)
    err = np.abs(model.expected(S, heard) - rss)
    # what remains is the bilinear lookup on the 0.5 m map grid (largest near a receiver)
    assert err.mean() < 0.05 and np.percentile(err, 99) < 0.5
    rx = site.receiver_positions_m()
    rx_o = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in site.receivers])
    pats = tuple(site.patterns[r.pattern] for r in site.receivers)
    flat = replace(model, exponent=0.0)
    for z in (0.6, 1.8):
        S[:, K.Z_M] = z
        pos = t.position_m.copy()
        pos[:, 2] = z
        true = link_rss_dbm(
            SMALL.channel, pos, t.orientation_deg, site.device_pattern(t.transmitter[0]),
            SMALL.tx_power_dbm, rx, rx_o, pats,
        )  # fmt: skip
        moved = np.abs(model.expected(S, heard) - true).mean()
        assert moved < 0.1
        assert np.abs(flat.expected(S, heard) - true).mean() > 3 * moved


def _true_rss_random_tilt(sim, points: np.ndarray, rng: np.random.Generator):
    """Particles at ``points`` in random hand-held orientations and the noise-free
    simulated RSS ``(n, n_rx)`` of the device there."""
    site = sim.site
    ori = np.column_stack([rng.uniform(0, 360, len(points)), rng.uniform(20, 70, len(points)),
                           rng.uniform(-25, 25, len(points))])  # fmt: skip
    rx_o = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in site.receivers])
    true = link_rss_dbm(
        SMALL.channel, points, ori, site.device_pattern(sim.truth.transmitter[0]),
        SMALL.tx_power_dbm, site.receiver_positions_m(), rx_o,
        tuple(site.patterns[r.pattern] for r in site.receivers),
    )  # fmt: skip
    S = _particles(*ori.T)
    S[:, :3] = points
    return S, true


def test_detrended_maps_follow_the_channel_near_a_receiver(clean_sim):
    """Within 1–2 m of a receiver the log-distance law bends faster than the 1 m
    survey grid follows: the survey's own map misses the channel there by tenths
    of a dB, the detrended maps (path loss removed before interpolating, added
    back at the exact 3-D distance) by much less; far from every receiver both
    agree with the channel; the kernels and ``HeightModel.channel_db`` compute
    the same detrended channel."""
    site = clean_sim.site
    space = candidate_space(site, site.devices[0].transmitter)
    cfg = Pose3dConfig(acquisition_step_m=5.0, acquisition_tilts=2)
    plain = FilterModel3d.build3d(site, space, replace(cfg, survey_detrend=False))
    det = FilterModel3d.build3d(site, space, cfg)  # the default
    assert det.detrended and not plain.detrended
    rx = site.receiver_positions_m()
    rng = np.random.default_rng(5)
    heard = np.arange(len(site.receivers))

    def errors(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        S, true = _true_rss_random_tilt(clean_sim, points, rng)
        return np.abs(plain.expected(S, heard) - true), np.abs(det.expected(S, heard) - true)

    # rings 1.2–2 m around each receiver, at the surveyed height and off it
    ang = rng.uniform(0, 2 * np.pi, 40)
    near, rows = [], []
    for r, (x, y, _) in enumerate(rx):
        d = rng.uniform(1.2, 2.0, ang.size)
        z = rng.uniform(0.8, 1.6, ang.size)
        p = np.column_stack([x + d * np.cos(ang), y + d * np.sin(ang), z])
        keep = (p[:, :2] >= 0).all(axis=1) & (p[:, :2] <= SMALL.size_m).all(axis=1)
        near.append(p[keep])
        rows.append(np.full(keep.sum(), r))
    pts, own = np.concatenate(near), np.concatenate(rows)
    e_plain, e_det = errors(pts)
    at_own = np.arange(len(pts))
    assert e_plain[at_own, own].mean() > 0.15  # the survey map's error next to its receiver
    assert e_det[at_own, own].mean() < 0.7 * e_plain[at_own, own].mean()
    # far from that receiver both are within the lookup's error
    far = np.linalg.norm(pts[:, None, :2] - rx[None, :, :2], axis=2) > 3.0
    assert e_det[far].mean() < 0.05 and e_plain[far].mean() < 0.05
    # the compiled kernel and the height model's own channel agree (detrended)
    hm = build_height_model(site, detrend=True)
    assert hm.detrended
    S = _particles(*np.zeros((len(pts), 3)).T)
    S[:, :3] = pts
    gain_det = det.expected(S, heard) - hm.channel_db(pts)  # tx power + pattern
    gain_plain = plain.expected(S, heard) - build_height_model(site, detrend=False).channel_db(pts)
    assert np.allclose(gain_det, gain_plain, atol=1e-6)


def test_receiver_gain_follows_the_channel_next_to_a_receiver(clean_sim):
    """Within 1.5 m of a receiver mounted above the phone the direction from the
    receiver turns fast with position and height, and the survey map at one
    height (detrended or not) carries the receiver's pattern only as surveyed:
    the maps with the receiver's enrolled gain removed before interpolating and
    added back toward each point follow the channel to a few hundredths of a
    dB; the kernel and ``HeightModel.channel_db`` compute the same gain term;
    a site whose receivers all have constant patterns gets no term."""
    site = clean_sim.site
    space = candidate_space(site, site.devices[0].transmitter)
    cfg = Pose3dConfig(acquisition_step_m=5.0, acquisition_tilts=2)
    det = FilterModel3d.build3d(site, space, cfg)
    rxg = FilterModel3d.build3d(site, space, replace(cfg, survey_receiver_gain=True))
    assert rxg.receiver_gain[0].shape == (len(site.receivers), 9)
    assert det.receiver_gain[0].shape[0] == 0
    rx = site.receiver_positions_m()
    rng = np.random.default_rng(11)
    pts, own = [], []
    for r, (x, y, _) in enumerate(rx):
        ang = rng.uniform(0, 2 * np.pi, 40)
        d = rng.uniform(0.2, 1.5, ang.size)
        p = np.column_stack([x + d * np.cos(ang), y + d * np.sin(ang), rng.uniform(0.8, 1.6, 40)])
        keep = (p[:, :2] >= 0).all(axis=1) & (p[:, :2] <= SMALL.size_m).all(axis=1)
        pts.append(p[keep])
        own.append(np.full(keep.sum(), r))
    p, o = np.concatenate(pts), np.concatenate(own)
    S, true = _true_rss_random_tilt(clean_sim, p, rng)
    heard = np.arange(len(site.receivers))
    at = np.arange(len(p))
    e_det = np.abs(det.expected(S, heard) - true)[at, o]
    e_rxg = np.abs(rxg.expected(S, heard) - true)[at, o]
    assert e_det.mean() > 0.3  # the receiver's pattern as surveyed, at another height
    assert e_rxg.mean() < 0.1 and e_rxg.mean() < 0.2 * e_det.mean()
    # the kernel's gain term is the height model's (numpy) one
    hm = build_height_model(site, detrend=True, receiver_gain=True)
    S0 = _particles(*np.zeros((len(p), 3)).T)
    S0[:, :3] = p
    base = det.expected(S0, heard) - build_height_model(site, detrend=True).channel_db(p)
    assert np.allclose(rxg.expected(S0, heard) - hm.channel_db(p), base, atol=1e-6)
    # each point's own receiver's gain is that receiver's column of the full table
    assert hm.receiver_gain is not None
    full = hm.receiver_gain.gain_dbi(p)
    assert np.array_equal(hm.receiver_gain.gain_dbi(p, o), full[at, o])
    # constant receiver patterns: no term (nothing to remove or add back)
    flat = {r.pattern: isotropic(r.pattern) for r in site.receivers}
    iso = replace(site, patterns={**site.patterns, **flat})
    assert build_height_model(iso, detrend=True, receiver_gain=True).receiver_gain is None


# ----------------------------------------------------------------------------- the filter
def run_filter(sim, pose3d: Pose3dConfig, model=None, seed: int = 3, config=None):
    site = sim.site
    space = candidate_space(site, site.devices[0].transmitter)
    model = model or FilterModel3d.build3d(site, space, pose3d)
    pf = ParticleFilter3d(model, config or FilterConfig(), None, pose3d)
    st = pf.new_state(seed)
    ids = list(site.receiver_ids)
    out = []
    for o in group_packets(sim.packets):
        idx = np.array([ids.index(r) for r in o.receiver_ids])
        out.append(pf.step(st, o.timestamp_s, HeardRss(idx, np.asarray(o.rss_dbm, float))))
    pos = np.array([e.position_m for e in out])
    ori = np.array([e.orientation_deg for e in out])
    half = len(out) // 2  # the second half
    pe = np.linalg.norm(pos - sim.truth.position_m, axis=1)[half:]
    oe = relative_rotation_angle_deg(ori, sim.truth.orientation_deg)[half:]
    return float(pe.mean()), float(oe.mean())


def static_scene(seed: int, **changes):
    """A noise-free scene with the phone held still at the walk's first pose
    (8 receivers, 4 on the ceiling, 0.5 s): one pose to recover."""
    sim = simulate_handheld(replace(SMALL, n_receivers=8, duration_s=0.5, **changes), seed=seed)
    n, k = len(sim.truth), len(sim.site.receivers)
    p = sim.packets
    packets = Packets(p.packet_id, p.timestamp_s, p.transmitter, p.receiver_id,
                      np.tile(p.rss_dbm[:k], n))  # fmt: skip
    t = sim.truth
    truth = Truth(t.timestamp_s, t.transmitter, np.tile(t.position_m[0], (n, 1)),
                  np.tile(t.orientation_deg[0], (n, 1)))  # fmt: skip
    return replace(sim, packets=packets, truth=truth)


STATIC_SEED = 424242


@pytest.fixture(scope="module")
def static_sim():
    return static_scene(STATIC_SEED)


def test_known_pose_recovered_noise_free(static_sim):
    """Noise-free, 8 receivers: the coarse acquisition and the local refinement
    find the one pose (after the first 0.25 s)."""
    pos_m, rot_deg = run_filter(static_sim, Pose3dConfig())
    assert pos_m < POS_BOUND_M
    assert rot_deg < ROT_BOUND_DEG


def test_without_pitch_in_the_state_the_bound_fails(static_sim):
    """The same data with pitch frozen at 0 (one candidate pitch): the phone's
    tilt cannot be represented and the error bound breaks."""
    flat = static_scene(STATIC_SEED, pitch_deg=(0.0,))
    np.testing.assert_array_equal(flat.packets.rss_dbm, static_sim.packets.rss_dbm)
    pos_m, rot_deg = run_filter(flat, Pose3dConfig())
    assert pos_m >= POS_BOUND_M or rot_deg >= ROT_BOUND_DEG


def test_without_coarse_acquisition_the_bound_fails(static_sim):
    """The coarse grid's scores replaced by a constant: particles start from
    arbitrary cells (the first ones of the table) and the bound breaks."""
    site = static_sim.site
    p3 = Pose3dConfig()
    model = FilterModel3d.build3d(site, candidate_space(site, site.devices[0].transmitter), p3)
    assert model.coarse is not None
    table = np.zeros_like(model.coarse.table_dbm)
    blind = replace(model, coarse=replace(model.coarse, table_dbm=table))
    pos_m, rot_deg = run_filter(static_sim, p3, model=blind)
    assert pos_m >= POS_BOUND_M or rot_deg >= ROT_BOUND_DEG


def test_filter_dispatch_at_a_3d_site(static_sim):
    """The registry's ``filter`` runs the 3-D filter at a 3-D site, builds no site
    scorer there, and keeps the 2-D filter at a 2-D site."""
    from radiopose.filtering import ParticleFilter
    from radiopose.tracker import Tracker

    sim = replace(static_sim, packets=static_sim.packets)
    tracker = Tracker(sim.site, "filter")
    obs = group_packets(sim.packets)
    tracker.update(obs[0])
    dev = next(iter(tracker._devices.values()))
    assert isinstance(dev.engine, ParticleFilter3d)
    assert dev.scorer is None
    flat2d = simulate(ScenarioConfig(size_m=6.0, step_m=0.5, duration_s=0.02, azimuth_step_deg=10.0,
                                     min_receiver_spacing_m=2.0), seed=9)  # fmt: skip
    tracker2 = Tracker(flat2d.site, "filter")
    tracker2.update(group_packets(flat2d.packets)[0])
    dev2 = next(iter(tracker2._devices.values()))
    assert type(dev2.engine) is ParticleFilter


def test_live_lag_at_a_3d_site_replays_in_batch():
    """The live server's 3-D filter (the streaming ``Tracker`` with a 0.25 s lag)
    gives exactly batch ``locate`` with that smoothing lag and the 3-D
    refinement off — the replay that ``radiopose demo --pose 3d`` reports as
    ``live``."""
    from radiopose.tracker import Tracker, TrackerConfig, locate

    sim = simulate_handheld(replace(SMALL, duration_s=0.5, interval_ms=20.0), seed=11)
    streamed = {}
    tracker = Tracker(sim.site, "filter", TrackerConfig(), lag_s=0.25)
    for o in group_packets(sim.packets):
        tracker.update(o)
        streamed.update({d.packet_id: d for d in tracker.take_delayed()})
    streamed.update({d.packet_id: d for d in tracker.flush()})
    base = TrackerConfig()
    replay = replace(base, smoothing_lag_s=0.25, pose3d=replace(base.pose3d, refine=False))
    batch = locate(sim.site, sim.packets, "filter", replay).estimates
    assert len(batch) == len(streamed) == 25
    got = [streamed[p] for p in batch.packet_id]
    np.testing.assert_array_equal([e.position_m for e in got], batch.position_m)
    np.testing.assert_array_equal([e.orientation_deg for e in got], batch.orientation_deg)
    # and the refinement is what the offline default adds on top
    offline = locate(sim.site, sim.packets, "filter", base).estimates
    assert not np.array_equal(offline.position_m, batch.position_m)


# ----------------------------------------------------------------------------- CLI, experiment
def test_cli_simulate_pose_3d(tmp_path, capsys):
    from radiopose.cli import main
    from radiopose.site import load_site, site_is_3d

    out = tmp_path / "sim"
    args = ["simulate", "-o", str(out), "--pose", "3d", "--duration-s", "0.02", "--receivers", "4"]
    assert main(args) == 0
    site = load_site(out / "site")
    assert site_is_3d(site) and site.area.has_height_range
    assert "z_min_m" in (out / "site" / "site.toml").read_text()
    capsys.readouterr()
    assert main([*args[:2], str(tmp_path / "x"), *args[3:], "--size-m", "10"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "radiopose: --size-m applies only with --pose 2d"
    assert main(["simulate", "-o", str(tmp_path / "y"), "--pose", "4d"]) == 2
    assert "--pose must be 2d or 3d" in capsys.readouterr().err


def test_scenario_pose_3d_is_the_handheld_scenario():
    cfg = ScenarioConfig(pose="3d", duration_s=0.02, n_receivers=4, noise_db=0.5)
    a = simulate(cfg, seed=11)
    b = simulate_handheld(HandheldConfig.from_scenario(cfg), seed=11)
    np.testing.assert_array_equal(a.packets.rss_dbm, b.packets.rss_dbm)
    assert a.config is cfg and a.site.area.has_height_range
    assert not simulate(replace(cfg, pose="2d"), seed=11).site.area.has_height_range


def test_3d_experiment_ships():
    from radiopose.evaluate.experiments import SHIPPED, load_experiment

    assert "3d" not in SHIPPED  # not run by default: the paper's five are
    exp = load_experiment("3d")
    assert exp.methods == ("filter",)
    assert {dict(c.params)["n_receivers"] for c in exp.conditions} == {4, 6, 8}
    assert {dict(c.params)["noise_db"] for c in exp.conditions} == {0.5, 1.0, 2.0, 3.0}
    assert all(c.scenario.pose == "3d" for c in exp.conditions)


def test_axis_errors():
    from radiopose.estimates import Estimates
    from radiopose.evaluate.pose3d import axis_errors, axis_errors_of

    e = axis_errors_of([[0, 0, 1.5]], [[359.0, 40.0, 1.0]], [[3, 4, 1.0]], [[1.0, 30.0, 359.0]])
    np.testing.assert_allclose(
        [e.position_m[0], e.height_m[0], e.azimuth_deg[0], e.pitch_deg[0], e.roll_deg[0]],
        [math.sqrt(25.25), 0.5, 2.0, 10.0, 2.0],
    )
    assert e.rotation_deg[0] == pytest.approx(
        relative_rotation_angle_deg([359.0, 40.0, 1.0], [1.0, 30.0, 359.0])[0]
    )
    truth = Truth(np.array([0.0, 0.1]), np.array(["tx", "tx"], dtype=object),
                  np.zeros((2, 3)), np.zeros((2, 3)))  # fmt: skip
    est = Estimates(np.array([0.1]), np.array(["tx"], dtype=object), np.array(["1"], dtype=object),
                    np.array([[0.0, 0.0, 0.3]]), np.array([[0.0, 0.0, 0.0]]),
                    np.array(["filter"], dtype=object))  # fmt: skip
    got = axis_errors(truth, est)
    assert got.coverage == 0.5 and got.height_m[0] == pytest.approx(0.3)


# ----------------------------------------------------------------------------- the mode estimate
def _rows(pos_m: np.ndarray, ori_deg: np.ndarray) -> np.ndarray:
    """Pose rows (x, y, z, cos a, sin a, pitch, cos r, sin r) of poses."""
    a, p, r = np.deg2rad(ori_deg).T
    return np.column_stack([pos_m, np.cos(a), np.sin(a), p, np.cos(r), np.sin(r)])


def _mode(rows: np.ndarray, w: np.ndarray, radius_deg: float = 30.0) -> np.ndarray:
    from radiopose.filtering.kernels3d import mode_pose

    out = np.empty(7)
    mode_pose(rows, w, 32, 1.0, math.cos(math.radians(0.5 * radius_deg)), 2, out)
    return out


def test_mode_of_one_pose_is_that_pose():
    """The matrix → (azimuth, pitch, roll) conversion inverts the contract's
    ``R = Rz(a)·Rx(p)·Ry(r)`` (azimuth and roll in [0, 360), pitch in [−90, 90])."""
    rng = np.random.default_rng(77)
    for _ in range(20):
        ori = rng.uniform([0.0, -85.0, -180.0], [360.0, 85.0, 180.0])
        out = _mode(_rows(np.array([[1.0, 2.0, 1.2]]), ori[None, :]), np.ones(1))
        np.testing.assert_allclose(out[:3], [1.0, 2.0, 1.2])
        got = np.degrees(out[3:6])
        assert relative_rotation_angle_deg(got, ori)[0] < 1e-6
        assert 0.0 <= got[0] < 360.0 and 0.0 <= got[2] < 360.0 and out[6] == 1.0


def test_mode_takes_the_heavier_of_two_modes():
    """A bimodal cloud (60 % at one pose, 40 % at a pose 180° of azimuth and 40°
    of roll away, 0.5 m apart): the per-axis mean lands between the modes, the
    mode estimate on the heavier one, its rotation the chordal mean of that
    mode's rotations (scipy's ``Rotation.mean``)."""
    rng = np.random.default_rng(5)
    n_a, n_b = 600, 400
    ori_a = np.array([30.0, 40.0, 20.0]) + rng.normal(0.0, 4.0, (n_a, 3))
    ori_b = np.array([210.0, 40.0, -20.0]) + rng.normal(0.0, 4.0, (n_b, 3))
    pos = np.concatenate([rng.normal([5.0, 5.0, 1.2], 0.1, (n_a, 3)),
                          rng.normal([5.5, 5.0, 1.2], 0.1, (n_b, 3))])  # fmt: skip
    ori = np.concatenate([ori_a, ori_b])
    w = rng.uniform(0.5, 1.5, n_a + n_b)
    out = _mode(_rows(pos, ori), w)
    assert out[6] == pytest.approx(w[:n_a].sum() / w.sum())
    np.testing.assert_allclose(out[:3], np.average(pos[:n_a], axis=0, weights=w[:n_a]))
    want = Rotation.from_euler("ZXY", ori_a, degrees=True).mean(weights=w[:n_a])
    got = Rotation.from_euler("ZXY", np.degrees(out[3:6]), degrees=True)
    assert (want.inv() * got).magnitude() < 1e-6
    # the per-axis mean (circular azimuth and roll, linear pitch) lands between
    a, p, r = np.deg2rad(ori).T
    mean = [math.degrees(math.atan2(np.sum(w * np.sin(a)), np.sum(w * np.cos(a)))),
            math.degrees(np.sum(w * p) / w.sum()),
            math.degrees(math.atan2(np.sum(w * np.sin(r)), np.sum(w * np.cos(r))))]  # fmt: skip
    truth_a = [30.0, 40.0, 20.0]
    assert relative_rotation_angle_deg(mean, truth_a)[0] > 10.0  # 15.6°: roll pulled to 4°
    assert relative_rotation_angle_deg(np.degrees(out[3:6]), truth_a)[0] < 2.0


# ----------------------------------------------------------------------------- the offset bank
def test_offset_bank_picks_the_member_the_data_favour(static_sim):
    """Members at −8, 0 and +8 dB (σ 1 dB each) on the noise-free static scene
    (true offset 0): the 0 dB member has the largest marginal likelihood by far,
    its estimate is the filter's and meets the bound; the −8 dB member's own
    estimate does not (so picking the member matters)."""
    from radiopose.filtering.particle3d import FilterState3d

    site = static_sim.site
    p3 = Pose3dConfig(offset_bank_db=(-8.0, 0.0, 8.0), offset_bank_sd_db=1.0, n_particles=6000)
    model = FilterModel3d.build3d(site, candidate_space(site, site.devices[0].transmitter), p3)
    pf = ParticleFilter3d(model, FilterConfig(), None, p3)
    st = pf.new_state(3)
    assert isinstance(st, FilterState3d) and len(st.bank) == 3
    assert [m.offset_prior_db for m in st.bank] == [-8.0, 0.0, 8.0]
    # the −8 dB member on its own
    alone = ParticleFilter3d(
        model, replace(FilterConfig(), offset_prior_sd_db=1.0), None,
        replace(p3, offset_bank_db=(), n_particles=2000),
    )  # fmt: skip
    st_alone = alone.new_state(3)
    st_alone.offset_prior_db = -8.0
    ids = list(site.receiver_ids)
    picked, wrong = [], []
    for o in group_packets(static_sim.packets):
        idx = np.array([ids.index(r) for r in o.receiver_ids])
        heard = HeardRss(idx, np.asarray(o.rss_dbm, float))
        picked.append(pf.step(st, o.timestamp_s, heard))
        wrong.append(alone.step(st_alone, o.timestamp_s, heard))
    ev = st.bank_log_evidence
    assert int(np.argmax(ev)) == 1 and ev[1] - max(ev[0], ev[2]) > 50.0
    half = len(picked) // 2
    truth = static_sim.truth

    def errors(ests):
        pos = np.array([e.position_m for e in ests])[half:]
        ori = np.array([e.orientation_deg for e in ests])[half:]
        pe = np.linalg.norm(pos - truth.position_m[half:], axis=1).mean()
        return pe, relative_rotation_angle_deg(ori, truth.orientation_deg[half:]).mean()

    pos_m, rot_deg = errors(picked)
    assert pos_m < POS_BOUND_M and rot_deg < ROT_BOUND_DEG
    pos_m, rot_deg = errors(wrong)
    assert pos_m >= POS_BOUND_M or rot_deg >= ROT_BOUND_DEG


# ------------------------------------------------------------------- heading prior, settings
def test_heading_prior_penalises_a_phone_not_facing_its_walk():
    """Walking along +x (walking azimuth −90°: the top, body +y, points along
    the velocity): a particle facing its walk keeps its weight, one turned 90°
    loses ``weight · κ · v²/(v² + v0²)``, one at rest nothing."""
    from radiopose.filtering.kernels3d import heading_prior

    S = _particles([-90.0, 0.0, 0.0], [40.0] * 3, [0.0] * 3)
    S[:2, K.VX_MPS] = 1.0  # the third stands still
    logw = np.zeros(3)
    kappa = 1.0 / math.radians(30.0) ** 2
    heading_prior(S, logw, 0.5, kappa, 0.3)
    assert logw[0] == pytest.approx(0.0, abs=1e-12)
    assert logw[1] == pytest.approx(-0.5 * kappa * 1.0 / (1.0 + 0.09))
    assert logw[2] == 0.0


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"estimate": "median"}, "estimate"),
        ({"offset_bank_db": (0.0, math.nan)}, "offset_bank_db"),
        ({"offset_bank_db": tuple(range(300))}, "offset_bank_db"),
        ({"heading_prior_deg": -1.0}, "heading_prior_deg"),
        ({"offset_bank_sd_db": 0.0}, "offset_bank_sd_db"),
    ],
)
def test_bad_pose3d_settings_are_one_line_errors(changes, match):
    with pytest.raises(InputError, match=match):
        Pose3dConfig(**changes)


@pytest.mark.parametrize("key", ["survey_detrend", "survey_receiver_gain"])
def test_survey_switches_read_from_tracker_toml(tmp_path, key):
    from radiopose.tracker_settings import read_tracker_settings

    p = tmp_path / "tracker.toml"
    for value in (False, True):
        p.write_text(f"[filter.pose3d]\n{key} = {str(value).lower()}\n")
        assert getattr(read_tracker_settings(p).pose3d(), key) is value
    p.write_text(f'[filter.pose3d]\n{key} = "yes"\n')
    with pytest.raises(InputError, match=key) as err:
        read_tracker_settings(p)
    assert "\n" not in str(err.value)


def test_between_surveyed_heights_the_layers_blend_linearly_in_height():
    """Two surveyed heights, 1.2 m and 2.5 m: at 1.59 m (30 % of the way) the
    channel is 0.7 of the lower layer's map carried to that height plus 0.3 of
    the upper one's, each with the path-loss correction from its own height
    (a mutant swapping the weights survived every test: about 2.4 dB off)."""
    from radiopose.survey_height import HeightModel

    x = np.arange(0.0, 5.0)
    y = np.arange(0.0, 4.0)
    rng = np.random.default_rng(12)
    maps = rng.normal(-50.0, 3.0, (2, 2, x.size, y.size))  # (layer, receiver, x, y)
    maps[1] += 6.0  # the upper layer 6 dB stronger
    hm = HeightModel(
        exponent=2.0, layers_z_m=np.array([1.2, 2.5]), maps_db=maps, x_m=x, y_m=y,
        receivers_m=np.array([[0.0, 0.0, 2.8], [4.0, 3.0, 0.5]]),
    )  # fmt: skip
    p = np.array([[1.0, 2.0, 1.59], [3.5, 0.5, 1.59]])  # on grid nodes and between them
    from radiopose.survey_height import _bilinear_all

    lower = _bilinear_all(maps[0], x, y, p) + hm.correction_db(p, 1.2)
    upper = _bilinear_all(maps[1], x, y, p) + hm.correction_db(p, 2.5)
    np.testing.assert_allclose(hm.channel_db(p), 0.7 * lower + 0.3 * upper, atol=1e-9)
    # at a surveyed height the layer itself; outside the range the nearest layer, carried
    at = p.copy()
    at[:, 2] = 2.5
    np.testing.assert_allclose(hm.channel_db(at), _bilinear_all(maps[1], x, y, at), atol=1e-9)
    high = p.copy()
    high[:, 2] = 3.0
    expect = _bilinear_all(maps[1], x, y, high) + hm.correction_db(high, 2.5)
    np.testing.assert_allclose(hm.channel_db(high), expect, atol=1e-9)
    # the compiled kernel the 3-D filter scores with blends the same way
    from radiopose.filtering.kernels3d import _channel_db

    g = np.array([x[0], x[1] - x[0], x.size, y[0], y[1] - y[0], y.size], float)
    for pts in (p, at, high):
        model = hm.channel_db(pts)
        for i, (px, py, pz) in enumerate(pts):
            for r, (rx, ry, rz) in enumerate(hm.receivers_m):
                h2 = (px - rx) ** 2 + (py - ry) ** 2
                k = _channel_db(maps, hm.layers_z_m, 2.0, False, r, px, py, pz, h2, rz, g)
                assert k == pytest.approx(model[i, r], abs=1e-9)
