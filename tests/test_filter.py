"""The Bayesian tracker (method ``filter``): every packet answered, bounds with a
safety margin on seeded standard scenarios, and each part shown to matter
(removing the motion model, the re-entry of grid hypotheses or the power-offset
state breaks a test below; the motion kernel's own arithmetic is checked in
test_filter_kernels.py).

Seeds 4201–4203 are used here only (the filter was tuned on 7000–7011 and is
reported on 1000–1009, docs/filter.md).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from radiopose.cli import main as cli_main
from radiopose.errors import InputError
from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.filtering import FilterConfig, FilterModel, ParticleFilter
from radiopose.filtering import kernels as K  # noqa: N812
from radiopose.likelihood import HeardRss, candidate_space, make_scorer
from radiopose.packets import Packets, group_packets
from radiopose.patterns import Pattern
from radiopose.patterns.synthetic import isotropic
from radiopose.simulate import LogDistance, ScenarioConfig, link_rss_dbm, simulate
from radiopose.site import (
    AreaGrid,
    Device,
    OrientationGrid,
    Receiver,
    SurveyConfig,
    SurveyRows,
    assemble_site,
)
from radiopose.tracker import Tracker, TrackerConfig, locate

TX = "02:00:00:00:00:01"


@pytest.fixture(scope="module")
def sim_half_db():
    return simulate(ScenarioConfig(noise_db=0.5), 4201)


@pytest.fixture(scope="module")
def scorer(sim_half_db):
    return build_scorer(sim_half_db, "numba")


def _run(sim, scorer, cfg: TrackerConfig, offset_db: float = 0.0):
    if offset_db:
        p = sim.packets
        sim = replace(
            sim,
            packets=Packets(
                p.packet_id, p.timestamp_s, p.transmitter, p.receiver_id, p.rss_dbm + offset_db
            ),
        )
    return run_methods(sim, ("filter",), cfg, scorer)["filter"]


def test_every_packet_answered_within_bounds(sim_half_db, scorer):
    run = _run(sim_half_db, scorer, TrackerConfig())
    assert run.summary.coverage == 1.0
    # goals 0.15 m / 1.2° (mean of ten runs); one run with a margin
    assert run.position_error_m.mean() < 0.3
    assert run.orientation_error_deg.mean() < 3.0
    assert np.all(np.isfinite(run.estimates.position_std_m))
    assert np.all(run.estimates.azimuth_std_deg >= 0)


def test_causal_variant_answers_every_packet(sim_half_db, scorer):
    run = _run(sim_half_db, scorer, TrackerConfig(smoothing_lag_s=None))
    assert run.summary.coverage == 1.0
    assert run.position_error_m.mean() < 0.6
    assert run.orientation_error_deg.mean() < 6.0


def test_unknown_transmit_power_is_estimated(sim_half_db, scorer):
    """+6 dB above the enrolled power. With 4 receivers one packet cannot tell the
    offset from the pose, but the offset is a constant of the device and over
    seconds it is identified: after the first second the errors are within the
    issue's 1.3× (+0.1 m, +1°) of the matched run's, and the whole run stays
    within 0.6 m. Without the offset state (a prior of 0.01 dB) the +6 dB are
    explained by the pose and the track is far off."""
    matched = _run(sim_half_db, scorer, TrackerConfig())
    loud = _run(sim_half_db, scorer, TrackerConfig(), offset_db=6.0)
    late = matched.estimates.timestamp_s >= 1.0
    assert np.array_equal(late, loud.estimates.timestamp_s >= 1.0)
    pm, pl = matched.position_error_m[late].mean(), loud.position_error_m[late].mean()
    om, ol = matched.orientation_error_deg[late].mean(), loud.orientation_error_deg[late].mean()
    assert pl <= 1.3 * pm + 0.1
    assert ol <= 1.3 * om + 1.0
    assert loud.position_error_m.mean() < 0.6
    no_offset = TrackerConfig(
        filter=FilterConfig(offset_prior_sd_db=0.01, initial_offsets_db=(0.0,))
    )
    ablated = _run(sim_half_db, scorer, no_offset, offset_db=6.0)
    assert ablated.position_error_m[late].mean() > 3 * pl + 0.3


def test_motion_model_matters():
    """Without a motion model (white accelerations of 1000 m/s²/√Hz and 10⁶ °/s²/√Hz
    within a support of 1000 m/s and 10⁵ °/s: any jump is as likely as steady
    walking) the same causal run at σ = 3 dB is clearly worse."""
    sim = simulate(ScenarioConfig(noise_db=3.0), 4204)
    sc = build_scorer(sim, "numba")
    good = _run(sim, sc, TrackerConfig(smoothing_lag_s=None))
    wild = TrackerConfig(
        smoothing_lag_s=None,
        max_speed_mps=1000.0,
        max_rotation_deg=5e4,
        filter=FilterConfig(accel_noise_mps2=1000.0, angular_accel_noise_dps2=1e6),
    )
    bad = _run(sim, sc, wild)
    assert bad.position_error_m.mean() > 2.0 * good.position_error_m.mean()
    assert bad.orientation_error_deg.mean() > 2.0 * good.orientation_error_deg.mean()


# ----------------------------------------------------------------------------- mirror
_MIRROR_SIZE_M = 20.0
_MIRROR_RX = [(2.0, 10.0), (8.0, 10.0), (13.0, 10.0), (18.0, 10.0), (10.0, 3.0)]
"""Four receivers on the line y = 10 (the mirror: a pose and its reflection, azimuth
negated, are the same distance from each of them) and a fifth off it."""


def _mirror_site():
    """Isotropic receivers at ``_MIRROR_RX``, a device pattern symmetric about its
    boresight (``D(φ) = D(−φ)``), a noise-free 1 m survey: with only the four
    receivers on the line heard, a pose and its mirror image fit every packet equally."""
    z = 1.0
    az = np.arange(0.0, 360.0, 1.0)
    phi = np.deg2rad(az)
    pats = {
        "iso": isotropic("iso"),
        "device": Pattern(
            "device", az, [90.0], (7.0 * np.cos(phi) + 3.0 * np.cos(2 * phi))[:, None]
        ),
    }
    receivers = tuple(
        Receiver(f"rx{i}", x, y, z, 0.0, 0.0, 0.0, "iso") for i, (x, y) in enumerate(_MIRROR_RX)
    )
    axis = np.arange(0.0, _MIRROR_SIZE_M + 1e-9, 1.0)
    sx, sy = np.meshgrid(axis, axis, indexing="ij")
    pts = np.column_stack([sx.ravel(), sy.ravel(), np.full(sx.size, z)])
    rx_xyz = np.array([[x, y, z] for x, y in _MIRROR_RX])
    iso = (pats["iso"],) * len(receivers)
    rss = link_rss_dbm(
        LogDistance(),
        pts,
        np.zeros_like(pts),
        pats["iso"],
        20.0,
        rx_xyz,
        np.zeros_like(rx_xyz),
        iso,
    )
    k = len(receivers)
    rows = SurveyRows(
        xyz_m=np.repeat(pts, k, axis=0),
        receiver_id=np.array([r.receiver_id for r in receivers] * len(pts), dtype=object),
        rss_dbm=rss.reshape(-1),
        orientation_deg=np.zeros((len(pts) * k, 3)),
    )
    size = _MIRROR_SIZE_M
    site = assemble_site(
        "mirror",
        AreaGrid(0.0, size, 0.0, size, z, 0.2),
        OrientationGrid(2.0),
        SurveyConfig(20.0, "iso"),
        receivers,
        (Device(TX, "device", 15.0),),
        pats,
        rows,
    )
    return site, pats, rx_xyz


def _mirror_recovery_s(config: FilterConfig) -> tuple[bool, float]:
    """A device walks at y > 10 heard by the four receivers on the mirror line; at
    0.3 s the filter's particles are all put on the mirror pose (reflected through
    y = 10, azimuth and turn rate negated), which the data cannot tell from the
    truth; from 0.6 s the fifth receiver hears the device and contradicts it.

    Returns whether the estimate stayed on the mirror until 0.6 s, and how long
    after 0.6 s its estimate was last more than 1 m or 15° from the truth."""
    site, pats, rx_xyz = _mirror_site()
    space = candidate_space(site, TX)
    pf = ParticleFilter(FilterModel.build(site, space, make_scorer("numba", space)), config)
    st = pf.new_state(0)
    t = np.arange(240) * 0.005
    z = np.full(t.size, 1.0)
    pos = np.column_stack([6.0 + 0.5 * t, 13.0 + 0.3 * t, z])
    ori = np.column_stack([(30.0 + 40.0 * t) % 360.0, 0 * t, 0 * t])
    iso = (pats["iso"],) * len(_MIRROR_RX)
    rss = link_rss_dbm(
        LogDistance(), pos, ori, pats["device"], 15.0, rx_xyz, np.zeros_like(rx_xyz), iso
    )
    rss += np.random.default_rng(4301).normal(0.0, 0.5, rss.shape)
    t_flip, t_contra = 0.3, 0.6
    held, last_wrong, flipped = True, t_contra - 0.005, False
    for i, ti in enumerate(t):
        n_rx = 5 if ti >= t_contra else 4
        if ti >= t_flip and not flipped:
            flipped = True
            S = st.particles
            mirror_y = _MIRROR_SIZE_M - pos[i, 1]
            keep = S[np.abs(S[:, K.Y_M] - pos[i, 1]) < np.abs(S[:, K.Y_M] - mirror_y)]
            S[:] = keep[np.arange(S.shape[0]) % keep.shape[0]]
            S[:, K.Y_M] = _MIRROR_SIZE_M - S[:, K.Y_M]
            S[:, K.VY_MPS] *= -1.0
            S[:, K.AZIMUTH_RAD] = (-S[:, K.AZIMUTH_RAD]) % (2 * np.pi)
            S[:, K.RATE_RAD_S] *= -1.0
        est = pf.step(st, float(ti), HeardRss(np.arange(n_rx), rss[i, :n_rx]))
        assert est is not None
        d = np.hypot(est.position_m[0] - pos[i, 0], est.position_m[1] - pos[i, 1])
        a = abs((est.orientation_deg[0] - ori[i, 0] + 180.0) % 360.0 - 180.0)
        wrong = d > 1.0 or a > 15.0
        if flipped and ti < t_contra and not wrong:
            held = False
        if ti >= t_contra and wrong:
            last_wrong = ti
    return held, last_wrong + 0.005 - t_contra


def test_mirror_lock_is_left_within_half_a_second():
    """Re-entered grid hypotheses pull the filter off a mirror pose within 0.5 s of
    the first packet that contradicts it; with re-entry switched off (once a
    minute) it stays there. Before that packet the mirror is kept (the data
    cannot tell it from the truth), so the test starts from a genuine lock."""
    cfg = FilterConfig(n_particles=1000)
    held, recovery_s = _mirror_recovery_s(cfg)
    assert held and recovery_s <= 0.5
    held, recovery_s = _mirror_recovery_s(replace(cfg, reentry_interval_s=60.0))
    assert held and recovery_s >= 0.6  # wrong until the end of the trace


def test_packets_heard_by_one_or_two_receivers_get_estimates(sim_half_db, scorer):
    """Every third packet keeps only one receiver, every third two: the paper's
    methods skip them, the filter answers each."""
    p = sim_half_db.packets
    keep = np.ones(len(p), dtype=bool)
    for pid in np.unique(p.packet_id):
        rows = np.flatnonzero(p.packet_id == pid)
        n = int(pid) % 3
        if n:
            keep[rows[n:]] = False
    thin = Packets(
        p.packet_id[keep], p.timestamp_s[keep], p.transmitter[keep], p.receiver_id[keep],
        p.rss_dbm[keep],
    )  # fmt: skip
    sim = replace(sim_half_db, packets=thin)
    run = _run(sim, scorer, TrackerConfig())
    assert run.summary.coverage == 1.0
    assert run.position_error_m.mean() < 1.0
    full = run_methods(sim, ("full",), TrackerConfig(), scorer)["full"]
    assert len(full.estimates) < len(group_packets(thin)) / 3 + 1


def test_gap_reacquires(sim_half_db, scorer):
    """A silence longer than ``reacquire_gap_s`` restarts the track; estimates
    after it are good again."""
    p = sim_half_db.packets
    t = p.timestamp_s + np.where(p.timestamp_s >= 1.0, 120.0, 0.0)
    gapped = Packets(p.packet_id, t, p.transmitter, p.receiver_id, p.rss_dbm)
    sim = replace(sim_half_db, packets=gapped)
    est = locate(sim.site, gapped, "filter").estimates
    assert len(est) == len(group_packets(gapped))
    late = est.timestamp_s >= 121.2
    truth_idx = np.minimum(
        np.searchsorted(sim.truth.timestamp_s, est.timestamp_s[late] - 120.0 - 1e-9),
        len(sim.truth) - 1,
    )
    err = np.linalg.norm(est.position_m[late, :2] - sim.truth.position_m[truth_idx, :2], axis=1)
    assert err.mean() < 0.5


def test_streaming_tracker_gives_causal_estimates(sim_half_db, scorer):
    tx = sim_half_db.site.devices[0].transmitter
    tr = Tracker(sim_half_db.site, "filter", scorers={tx: scorer})
    obs = group_packets(sim_half_db.packets)
    outs = [tr.update(o) for o in obs[:40]]
    assert all(e is not None for e, _ in outs)
    assert outs[0][0].method == "filter"
    # out of time order: skipped, state unchanged
    e, reason = tr.update(obs[5])
    assert e is None and "before" in reason


def test_out_of_order_packets_are_a_line_error(sim_half_db):
    p = sim_half_db.packets
    t = p.timestamp_s.copy()
    t[p.packet_id == p.packet_id[-1]] = 0.0001
    bad = Packets(
        p.packet_id,
        t,
        p.transmitter,
        p.receiver_id,
        p.rss_dbm,
        lines=np.arange(len(p)) + 2,
        path="packets.csv",
    )
    with pytest.raises(InputError, match="earlier than"):
        locate(sim_half_db.site, bad, "filter")


def test_unknown_transmitter_is_skipped_and_counted(sim_half_db, scorer):
    p = sim_half_db.packets
    tx = p.transmitter.copy()
    tx[p.packet_id == p.packet_id[0]] = "stranger"
    mixed = Packets(p.packet_id, p.timestamp_s, tx, p.receiver_id, p.rss_dbm)
    res = locate(sim_half_db.site, mixed, "filter", scorers={p.transmitter[0]: scorer})
    assert dict(res.summary.skipped)["unknown transmitter"] == 1
    assert len(res.estimates) == len(group_packets(mixed)) - 1


@pytest.mark.parametrize(
    "field, value",
    [
        ("n_particles", 0),
        ("huber_c", -1.0),
        ("reentry_fraction", 1.5),
        ("sigma_prior_db", float("nan")),
    ],
)
def test_bad_filter_settings_are_one_line_errors(field, value):
    with pytest.raises(InputError, match=field):
        FilterConfig(**{field: value})


@pytest.mark.parametrize("causal", [False, True])
def test_heard_outliers_do_not_throw_the_track(sim_half_db, scorer, causal):
    """One receiver 15 dB off in one packet of five, offline and causal (what
    the live server runs). The offline passes alone absorb it (0.09 m / 0.61°
    with or without the outlier mixture); the causal filter needs the mixture:
    0.37 m / 4.4° with it, 1.22 m / 23.6° with a plain Gaussian (helper-65's
    mutant F13 survived the offline test alone)."""
    p = sim_half_db.packets
    rss = p.rss_dbm.copy()
    first_rows = np.unique(p.packet_id, return_index=True)[1]
    hit = first_rows[::5]
    rss[hit] += 15.0
    sim = replace(
        sim_half_db, packets=Packets(p.packet_id, p.timestamp_s, p.transmitter, p.receiver_id, rss)
    )
    run = _run(sim, scorer, TrackerConfig(smoothing_lag_s=None) if causal else TrackerConfig())
    assert run.position_error_m.mean() < (0.6 if causal else 0.4)
    assert run.orientation_error_deg.mean() < (8.0 if causal else 4.0)


def test_the_power_offset_is_carried_over_a_silence(sim_half_db):
    """A device 6 dB above its enrolled power, silent for 2 minutes after its
    first second: the track ends, and the filter re-acquires with the offset it
    had learnt as its prior (helper-65's mutant F14, which dropped it, survived
    every test; end to end the re-acquisition on this seed is chaotic — 0.07 m
    or 1.35 m after the gap depending on which side one packet at 1.0 s falls —
    so the state is what is checked)."""
    from radiopose.packets import PacketObservation, group_packets
    from radiopose.tracker import Tracker

    site = sim_half_db.site
    tracker = Tracker(site, "filter", TrackerConfig(smoothing_lag_s=None))
    t0 = float(sim_half_db.packets.timestamp_s.min())
    key = None
    for obs in group_packets(sim_half_db.packets):
        gap = obs.timestamp_s >= t0 + 1.0
        loud = PacketObservation(
            obs.packet_id, obs.timestamp_s + (120.0 if gap else 0.0), obs.transmitter,
            obs.receiver_ids, np.asarray(obs.rss_dbm) + 6.0,
        )  # fmt: skip
        tracker.update(loud)
        key = next(iter(tracker.states))
        if gap:
            break
    st = tracker.states[key]
    assert st.offset_prior_db == pytest.approx(6.0, abs=1.5)
    assert st.last_time_s == pytest.approx(t0 + 121.0, abs=0.01)


def test_a_smoothed_estimate_states_the_filters_own_uncertainty(sim_half_db):
    """The fixed-lag smoother's estimate reports the causal filter's spread at
    that packet (the genealogy collapses to a few ancestors: its own spread was
    45 times too small, 0.03 m against 1.39 m on a pinned run, and only a pin
    held the rule; helper-65's mutant F08): the same uncertainties as the causal
    run, a different (smoothed) position."""
    from radiopose.tracker import locate

    fc = replace(FilterConfig(), live_resolve_times_s=())
    runs = {
        lag: locate(sim_half_db.site, sim_half_db.packets, "filter",
                    TrackerConfig(smoothing_lag_s=lag, filter=fc)).estimates
        for lag in (None, 0.25)
    }  # fmt: skip
    causal, smoothed = runs[None], runs[0.25]
    assert list(causal.packet_id) == list(smoothed.packet_id)
    np.testing.assert_array_equal(smoothed.position_std_m, causal.position_std_m)
    np.testing.assert_array_equal(smoothed.azimuth_std_deg, causal.azimuth_std_deg)
    assert np.abs(smoothed.position_m - causal.position_m).max() > 0.01
    assert np.median(smoothed.position_std_m) > 0.05


def test_sigma_from_the_packets_own_differences(sim_half_db):
    """σ is never told: with the filter's fit 5 dB off (a wrong lock inflates
    it), the packets' own estimate — successive readings of a receiver 5 ms
    apart, ``median(d²) / (2 · 0.4549)`` — gives the noise, 1 dB here, within
    10 % after 200 packets (helper-65's mutant F06, ``/ 0.4549``, which reads
    σ² twice too large, changed no test)."""
    space = candidate_space(sim_half_db.site, sim_half_db.site.devices[0].transmitter)
    pf = ParticleFilter(FilterModel.build(sim_half_db.site, space, None), FilterConfig())
    st = pf.new_state(0)
    rng = np.random.default_rng(77)
    n, h = 50, 4
    S = np.zeros((n, K.N_COLUMNS))
    mean = np.array([-60.0, -55.0, -70.0, -65.0])
    pred = np.tile(mean + 5.0, (n, 1))  # the fit's pose 5 dB off at every receiver
    w = np.full(n, 1.0 / n)
    for k in range(200):
        heard = HeardRss(np.arange(h), mean + rng.normal(0.0, 1.0, h))
        pf._update_sigma(st, S, pred, heard, w, 0.005 * k)
    assert np.sqrt(st.fit2_db2) > 3.0  # the fit alone would say several dB
    assert np.sqrt(st.sigma2_db2) == pytest.approx(1.0, rel=0.1)


def test_heard_rss_kernel_matches_the_likelihood_model(sim_half_db):
    """Off-grid expected RSS at a grid candidate equals the likelihood's exact value."""
    from radiopose.likelihood import expected_rss_dbm

    space = candidate_space(sim_half_db.site, sim_half_db.site.devices[0].transmitter)
    model = FilterModel.build(sim_half_db.site, space, None)
    rng = np.random.default_rng(0)
    pos = rng.integers(0, space.n_positions, 50)
    ori = rng.integers(0, space.n_orientations, 50)
    S = np.zeros((50, K.N_COLUMNS))
    S[:, K.X_M : K.Z_M + 1] = space.positions_m[pos]
    S[:, K.AZIMUTH_RAD] = np.deg2rad(space.orientations_deg[ori, 0])
    heard = HeardRss(np.arange(space.n_receivers), np.zeros(space.n_receivers))
    got = model.expected(S, heard.receiver_index)
    want = expected_rss_dbm(space, pos, ori)
    np.testing.assert_allclose(got, want, atol=1e-9)


# ----------------------------------------------------------------------------- bad input (CLI)
def _edit_packets(src: Path, dst: Path, edit) -> Path:
    """Copy ``packets.csv`` with ``edit(rows, header)`` applied to its data rows."""
    lines = src.read_text().splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:]]
    edit(rows, header)
    dst.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    return dst


def _nan_rss(rows, header):
    rows[1][header.index("rss_dbm")] = "nan"


def _out_of_order(rows, header):
    last = rows[-1][header.index("packet_id")]
    for r in rows:
        if r[header.index("packet_id")] == last:
            r[header.index("timestamp_s")] = "0.0001"


def _stranger(rows, header):
    first = rows[0][header.index("packet_id")]
    for r in rows:
        if r[header.index("packet_id")] == first:
            r[header.index("transmitter")] = "stranger"


@pytest.mark.parametrize("method", ["full", "filter"])
@pytest.mark.parametrize(
    "edit, expect",
    [
        (_nan_rss, "bad.csv:3, column 'rss_dbm': not a finite number: 'nan'"),
        (_out_of_order, "column 'timestamp_s': timestamp 0.0001 s of packet"),
        (_stranger, "skipped 1: unknown transmitter"),
    ],
)
def test_locate_bad_input_same_answer_as_the_paper_methods(
    small_sim, tmp_path, capsys, method, edit, expect
):
    """``radiopose locate --method filter`` meets bad packets as ``full`` does: NaN RSS
    and packets out of time order are one-line errors naming file, line and column;
    a transmitter without an enrolled pattern is a counted skip."""
    small_sim.write(tmp_path / "sim")
    bad = _edit_packets(tmp_path / "sim" / "packets.csv", tmp_path / "bad.csv", edit)
    out = tmp_path / f"est_{method}.csv"
    site = str(tmp_path / "sim" / "site")
    code = cli_main(["locate", site, str(bad), "-o", str(out), "--method", method])
    err = capsys.readouterr().err
    assert expect in err
    if edit is _stranger:
        assert code == 0 and out.exists()
    else:
        assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
        assert not out.exists()


def _accuracy_script():
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "scripts" / "filter_accuracy.py"
    spec = importlib.util.spec_from_file_location("filter_accuracy_script", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclass looks its module up there
    spec.loader.exec_module(mod)
    return mod


def test_accuracy_script_tables_each_seed_set_and_counts_bad_runs():
    """``scripts/filter_accuracy.py`` (the held-out table): seed sets parse as
    inclusive ranges (bad ones are argparse errors, not tracebacks), each set
    gets its own rows, and runs whose mean orientation error exceeds 15° are
    counted."""
    import argparse

    fa = _accuracy_script()
    assert fa.seed_range("1010-1029") == range(1010, 1030)
    assert fa.seed_range("7") == range(7, 8)
    for bad in ("x", "5-3", "1-b"):
        with pytest.raises(argparse.ArgumentTypeError, match="seed set"):
            fa.seed_range(bad)

    def run(ori_deg: float) -> object:
        return fa.RunResult(np.full(4, 0.5), np.full(4, ori_deg), 4, 4, 1.0)

    done = [
        (3.0, 1000, {"filter": run(2.0)}),
        (3.0, 1001, {"filter": run(20.0)}),
        (3.0, 1010, {"filter": run(1.0)}),
    ]
    first = fa._table(done, [3.0], ["filter"], range(1000, 1002))
    fresh = fa._table(done, [3.0], ["filter"], range(1010, 1011))
    cells = [c.strip() for c in first[2].split("|")[1:-1]]
    assert cells[1] == "filter" and cells[9] == "11.00" and cells[10] == "20.0"
    assert cells[11] == "1"  # one run above 15°
    assert [c.strip() for c in fresh[2].split("|")[1:-1]][11] == "0"
