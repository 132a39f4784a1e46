"""Pattern enrolment: analytic references, recovery of known patterns, troughs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.patterns import smartphone_like
from radiopose.patterns.enrol import (
    FILL_GAP_SLACK_DEG,
    MAX_FILL_GAP_DEG,
    CoverageGapError,
    EnrolConfig,
    Measurements,
    average_per_direction,
    enrol,
    enrol_csv,
    fill_periodic,
    largest_circular_gap,
    motor_to_pattern_deg,
    pattern_to_motor_deg,
    simulate_positioner_measurements,
    smooth_circular,
    smooth_rows,
)
from radiopose.patterns.pattern import mean_intensity
from radiopose.patterns.synthetic import from_linear
from radiopose.units import db_to_linear, dbm_to_mw, mw_to_dbm

AZ = np.arange(360.0)
SLICE = np.array([90.0])


def _noise_free(pattern, **kw):
    kw.setdefault("samples_per_direction", 1)
    return simulate_positioner_measurements(pattern, np.random.default_rng(0), noise_db=0.0, **kw)


# ---------------------------------------------------------------- analytic references
def test_constant_rss_gives_isotropic_slice():
    m = Measurements(np.arange(0.0, 360.0, 10.0), np.full(36, 90.0), np.full(36, -55.0))
    p = enrol(m)
    assert p.is_slice and p.polar_deg[0] == 90.0 and p.azimuth_deg.size == 360
    np.testing.assert_allclose(p.directivity_dbi, 0.0, atol=1e-12)


def test_motor_azimuth_maps_to_360_minus():
    phi, theta = motor_to_pattern_deg([0.0, 90.0, 360.0, 359.0], [90.0, 45.0, 0.0, 180.0])
    np.testing.assert_allclose(phi, [0.0, 270.0, 0.0, 1.0])
    np.testing.assert_allclose(theta, [90.0, 45.0, 0.0, 180.0])
    back = pattern_to_motor_deg(phi, theta)
    np.testing.assert_allclose(back[0], [0.0, 90.0, 0.0, 359.0])


def test_peak_at_motor_90_is_pattern_270():
    motor = np.arange(0.0, 360.0, 1.0)
    rss = np.where(motor == 90.0, -40.0, -60.0)
    p = enrol(Measurements(motor, np.full(motor.size, 90.0), rss), EnrolConfig(smooth_deg=0))
    assert p.azimuth_deg[np.argmax(p.directivity_dbi[:, 0])] == 270.0


def test_repeated_samples_average_in_mw_not_dbm():
    phi, _, p_mw = average_per_direction([10.0, 10.0, 20.0], [90.0, 90.0, 90.0], [-10, -20, -30])
    np.testing.assert_allclose(phi, [10.0, 20.0])
    np.testing.assert_allclose(p_mw, [(0.1 + 0.01) / 2, 1e-3])
    assert mw_to_dbm(p_mw[0]) == pytest.approx(-12.596, abs=1e-3)  # not -15 dBm


def test_smooth_circular_is_a_centred_wrapping_boxcar():
    v = np.zeros(12)
    v[0] = 12.0
    out = smooth_circular(v, 2)
    np.testing.assert_allclose(out[[10, 11, 0, 1, 2]], 12.0 / 5)
    np.testing.assert_allclose(out[3:10], 0.0)
    assert out.sum() == pytest.approx(v.sum())


def test_linear_smoothing_keeps_row_power_db_smoothing_does_not():
    rng = np.random.default_rng(5)
    p_mw = dbm_to_mw(rng.normal(-50.0, 6.0, (360, 1)))
    lin = smooth_rows(p_mw, 1.0, 5.0, "linear")
    dbs = smooth_rows(p_mw, 1.0, 5.0, "db")
    assert lin.mean() == pytest.approx(p_mw.mean(), rel=1e-12)
    assert dbs.mean() < 0.9 * p_mw.mean()  # the geometric mean loses power


def test_fill_periodic_interpolates_through_samples_and_wraps():
    x = np.array([0.0, 90.0, 180.0, 270.0])
    y = np.cos(np.deg2rad(x))
    g = np.arange(360.0)
    for method in ("spline", "linear"):
        out = fill_periodic(x, y, g, method)
        np.testing.assert_allclose(out[x.astype(int)], y, atol=1e-12)
        assert out[359] == pytest.approx(out[1], abs=1e-9)  # symmetric about 0 across the wrap
    np.testing.assert_allclose(fill_periodic([33.0], [2.5], g), 2.5)


# ---------------------------------------------------------------- recovery
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_known_slice_recovered_within_half_db(seed):
    rng = np.random.default_rng(seed)
    true = smartphone_like(rng, range_db=17.35)  # the paper's A50 span
    m = simulate_positioner_measurements(true, rng, samples_per_direction=20, noise_db=1.0)
    p = enrol(m)
    err = np.abs(p.directivity_dbi - true.directivity_dbi)
    assert err.max() < 0.5, f"max error {err.max():.3f} dB"
    assert mean_intensity(p) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_sparse_15_degree_measurement_recovered(seed):
    true = smartphone_like(np.random.default_rng(seed), range_db=17.35)
    p = enrol(_noise_free(true, azimuth_step_deg=15.0))
    assert np.abs(p.directivity_dbi - true.directivity_dbi).max() < 0.5


def test_sparse_45_degree_spline_beats_linear():
    errs = {"spline": [], "linear": []}
    for seed in range(6):
        true = smartphone_like(np.random.default_rng(seed), range_db=17.35)
        m = _noise_free(true, azimuth_step_deg=45.0)
        for method in errs:
            p = enrol(m, EnrolConfig(interpolation=method))
            errs[method].append(np.abs(p.directivity_dbi - true.directivity_dbi).mean())
    assert np.mean(errs["spline"]) < 0.8 * np.mean(errs["linear"])


def test_full_sphere_recovered_and_normalised_with_sin_weighting():
    rng = np.random.default_rng(3)
    true = smartphone_like(rng, polar_step_deg=5.0)
    m = _noise_free(true, elevations_deg=np.arange(0.0, 181.0, 5.0))
    p = enrol(m)  # polar step inferred from the measured elevations
    assert p.polar_deg.size == 37 and not p.is_slice
    assert np.abs(p.directivity_dbi - true.directivity_dbi).max() < 0.25
    assert mean_intensity(p) == pytest.approx(1.0, rel=1e-12)


def test_full_sphere_missing_rows_are_filled_along_theta():
    true = smartphone_like(np.random.default_rng(3), polar_step_deg=5.0)
    m = _noise_free(true, elevations_deg=np.arange(0.0, 181.0, 10.0))
    p = enrol(m, EnrolConfig(polar_step_deg=5.0))
    assert p.polar_deg.size == 37
    assert np.abs(p.directivity_dbi - true.directivity_dbi).max() < 0.5
    # beyond the measured elevations the nearest measured row is held
    part = enrol(_noise_free(true, elevations_deg=[60.0, 90.0, 120.0]))  # rows 0, 30, … 180
    d = part.directivity_dbi
    np.testing.assert_allclose(d[:, 1], d[:, 2])  # 30° holds the 60° row
    np.testing.assert_allclose(d[:, 0], mw_to_dbm(dbm_to_mw(d[:, 2]).mean()))  # pole: one value


# ---------------------------------------------------------------- coverage
def _slice(motor_az, elevation=90.0):
    motor_az = np.asarray(motor_az, dtype=float)
    rss = -50.0 + 5.0 * np.cos(np.deg2rad(motor_az))
    return Measurements(motor_az, np.full(motor_az.size, elevation), rss)


def test_a_quarter_circle_is_refused_not_filled_to_a_full_pattern(tmp_path):
    # the walkthrough: motor azimuths 0–90° gave a 360° pattern, 270° of it spline
    with pytest.raises(CoverageGapError) as err:
        enrol(_slice(np.arange(0.0, 90.5, 0.5)))
    assert err.value.column == "motor_azimuth_deg" and err.value.path is None
    assert str(err.value) == (
        "column 'motor_azimuth_deg': measurements leave motor azimuths 90–360° (a 270° gap) "
        "unmeasured; at most 90° can be filled"
    )
    path = tmp_path / "m_q.csv"
    path.write_text(
        "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n"
        + "".join(f"{a},90,-50\n" for a in (0, 30, 60, 90, 200, 270, 330))
    )
    with pytest.raises(InputError, match=r"motor azimuths 90–200° \(a 110° gap\)") as err:
        enrol_csv(path)
    assert (err.value.path, err.value.column) == (str(path), "motor_azimuth_deg")
    assert "radians" not in str(err.value)


def test_a_gap_through_zero_names_its_ends_in_range():
    """Motor azimuths 100–200° were reported as 'motor azimuths 200–460° (a 260° gap)'."""
    with pytest.raises(CoverageGapError) as err:
        enrol(_slice(np.arange(100.0, 200.5, 0.5)))
    assert "leave motor azimuths 200–100° through 0° (a 260° gap) unmeasured" in str(err.value)
    with pytest.raises(CoverageGapError) as err:  # ends at 360 exactly: no wrap
        enrol(_slice(np.arange(0.0, 90.5, 0.5)))
    assert "leave motor azimuths 90–360° (a 270° gap)" in str(err.value)
    with pytest.raises(CoverageGapError) as err:  # one azimuth: 90–450° before
        enrol(_slice([90.0, 90.0]))
    assert "leave every motor azimuth but 90° (a 360° gap) unmeasured" in str(err.value)


def test_azimuths_in_radians_are_named_as_such():
    with pytest.raises(CoverageGapError, match=r"radians\? motor_azimuth_deg is in degrees"):
        enrol(_slice(np.linspace(0.0, 2 * np.pi, 100)))
    with pytest.raises(CoverageGapError) as err:  # degrees up to 7: no hint
        enrol(_slice(np.linspace(0.0, 7.0, 100)))
    assert "radians" not in str(err.value)


@settings(max_examples=80, deadline=None)
@given(st.sets(st.integers(0, 359), min_size=1, max_size=12))
def test_enrolment_fills_gaps_up_to_the_limit_only(azimuths):
    gap, _ = largest_circular_gap(sorted(azimuths))
    if gap > MAX_FILL_GAP_DEG + FILL_GAP_SLACK_DEG:
        with pytest.raises(CoverageGapError, match=f"a {gap:g}° gap"):
            enrol(_slice(sorted(azimuths)))
    else:
        assert enrol(_slice(sorted(azimuths))).azimuth_deg.size == 360


def test_a_four_stop_plan_with_encoder_noise_is_filled():
    """The 90° limit had no tolerance: motor azimuths 0, 90.2, 180, 270 were refused as
    a 90.2° gap, and 350, 80, 170, 260.5 (the documented four-stop plan, logged by an
    encoder) as 90.5°. Gaps up to MAX_FILL_GAP_DEG + FILL_GAP_SLACK_DEG are filled."""
    assert (MAX_FILL_GAP_DEG, FILL_GAP_SLACK_DEG) == (90.0, 1.0)
    for motor_az in ([0, 90.2, 180, 270], [350, 80, 170, 260.5], [0, 91, 180, 270]):
        assert enrol(_slice(motor_az)).azimuth_deg.size == 360
    with pytest.raises(CoverageGapError, match=r"\(a 91.5° gap\)"):
        enrol(_slice([0, 91.5, 180, 270]))
    # elevations alike: 8 azimuths at 45° and 135.8° (a 90.8° gap between them)
    rows = [(a, e) for e in (45.0, 135.8) for a in np.arange(0.0, 360.0, 45.0)]
    m = Measurements([r[0] for r in rows], [r[1] for r in rows], np.full(len(rows), -50.0))
    assert enrol(m, EnrolConfig(polar_step_deg=1.0)).polar_deg.size == 181
    rows = [(a, e) for e in (45.0, 136.5) for a in np.arange(0.0, 360.0, 45.0)]
    m = Measurements([r[0] for r in rows], [r[1] for r in rows], np.full(len(rows), -50.0))
    with pytest.raises(CoverageGapError, match=r"motor elevations 45–136.5° \(a 91.5° gap\)"):
        enrol(m, EnrolConfig(polar_step_deg=1.0))


def test_a_cut_through_the_poles_is_refused_with_what_to_measure():
    """A sphere measured as one great circle through the poles (motor azimuths 0 and
    180° at every elevation) is refused: every ring would be half invented. The error
    said only 'a 180° gap at elevation 5°'; it now names the cut and what to add, and
    the orthogonal cut (90 and 270°) makes four azimuths per ring, which is filled."""

    def cuts(*azimuths):
        rows = [(a, e) for e in np.arange(0.0, 181.0, 5.0) for a in azimuths]
        return Measurements([r[0] for r in rows], [r[1] for r in rows], np.full(len(rows), -50.0))

    with pytest.raises(CoverageGapError) as err:
        enrol(cuts(0.0, 180.0))
    assert str(err.value) == (
        "column 'motor_azimuth_deg': measurements leave motor azimuths 180–360° at "
        "elevation 5° (a 180° gap) unmeasured; at most 90° can be filled; every elevation "
        "off the poles has at most 2 motor azimuths (a cut through the poles: the fill "
        "would invent half of every ring): measure at least 4, at most 90° apart "
        "(e.g. add the orthogonal cut)"
    )
    with pytest.raises(CoverageGapError, match="a cut through the poles"):
        enrol(cuts(0.0))  # half a cut
    sphere = enrol(cuts(0.0, 90.0, 180.0, 270.0))
    assert sphere.polar_deg.size == 37
    with pytest.raises(CoverageGapError) as err:  # rings of 3 azimuths: a plain gap
        enrol(cuts(0.0, 90.0, 180.0))
    assert "a 180° gap" in str(err.value) and "cut through the poles" not in str(err.value)
    with pytest.raises(CoverageGapError) as err:  # a slice of 2 azimuths is no cut
        enrol(_slice([0.0, 180.0]))
    assert "cut through the poles" not in str(err.value)


def test_sphere_elevation_gaps_are_refused_and_poles_need_one_azimuth():
    az = np.arange(0.0, 360.0, 45.0)
    rows = [(a, e) for e in (100.0, 120.0, 150.0) for a in az]
    m = Measurements([r[0] for r in rows], [r[1] for r in rows], np.full(len(rows), -50.0))
    with pytest.raises(CoverageGapError) as err:  # 0–100° held from the 100° row
        enrol(m)
    assert err.value.column == "motor_elevation_deg"
    assert "motor elevations 0–100° (a 100° gap) unmeasured" in str(err.value)
    # a pole is one direction: one azimuth there is the whole row
    rows = [(0.0, 0.0), (0.0, 180.0)] + [(a, e) for e in (45.0, 90.0, 135.0) for a in az]
    m = Measurements([r[0] for r in rows], [r[1] for r in rows], np.full(len(rows), -50.0))
    assert enrol(m).polar_deg.size == 5


# ---------------------------------------------------------------- troughs
def _sharp_lobes() -> object:
    """Two narrow lobes (~12° wide) over broad troughs, linear intensity."""
    phi = np.deg2rad(AZ)
    u = np.exp(40 * (np.cos(phi - 1.0) - 1)) + 0.7 * np.exp(40 * (np.cos(phi - 3.0) - 1)) + 0.02
    return from_linear("lobes", AZ, SLICE, u[:, None])


def test_linear_smoothing_preserves_troughs_db_smoothing_fills_them():
    true = _sharp_lobes()
    m = _noise_free(true)
    lin = enrol(m).directivity_dbi[:, 0]
    dbs = enrol(m, EnrolConfig(smoothing_domain="db")).directivity_dbi[:, 0]
    t = true.directivity_dbi[:, 0]
    floor = t < t.min() + 0.5  # the broad trough floor (≈ 240° of the slice)
    # linear: the troughs stay at their level (power kept, no renormalisation shift)
    assert lin.min() == pytest.approx(t.min(), abs=0.01)
    assert abs(np.median(lin[floor] - t[floor])) < 0.01
    # dB: the narrow lobes lose power, the renormalisation lifts every trough
    assert dbs.min() - t.min() > 0.15, f"dB smoothing lift {dbs.min() - t.min():.3f} dB"
    assert np.median(dbs[floor] - t[floor]) > 0.15


def test_a_null_narrower_than_the_window_is_filled_by_both():
    """Counter-example, recorded: a null narrower than ±5° is filled more in mW.

    The linear boxcar average of ``ε + c·x²`` over ±w is ``c·w²/3``; the dB
    average is ``c·w²·e⁻²`` — dB smoothing keeps such a null ~3.9 dB deeper.
    """
    phi = np.deg2rad(AZ)
    u = np.abs(1 + 0.95 * np.exp(1j * 6 * np.cos(phi))) ** 2  # two-element interference
    true = from_linear("nulls", AZ, SLICE, u[:, None])
    m = _noise_free(true)
    lin = enrol(m).directivity_dbi.min()
    dbs = enrol(m, EnrolConfig(smoothing_domain="db")).directivity_dbi.min()
    unsmoothed = enrol(m, EnrolConfig(smooth_deg=0)).directivity_dbi.min()
    assert unsmoothed == pytest.approx(true.directivity_dbi.min(), abs=1e-9)
    assert unsmoothed < dbs - 5.0 and dbs < lin - 2.0


# ---------------------------------------------------------------- config and simulation
@pytest.mark.parametrize(
    "kwargs",
    [
        {"smooth_deg": -1.0},
        {"smooth_deg": float("nan")},
        {"azimuth_step_deg": 7.0},
        {"azimuth_step_deg": 0.0},
        {"polar_step_deg": 7.0},
        {"interpolation": "cubic"},
        {"smoothing_domain": "log"},
    ],
)
def test_bad_config_is_an_input_error(kwargs):
    with pytest.raises(InputError):
        EnrolConfig(**kwargs)


def test_simulated_measurements_follow_the_contract():
    true = smartphone_like(np.random.default_rng(1))
    m = simulate_positioner_measurements(
        true,
        np.random.default_rng(2),
        azimuth_step_deg=90.0,
        samples_per_direction=2,
        noise_db=0.0,
        tx_power_dbm=10.0,
        path_loss_db=50.0,
    )
    assert len(m) == 8
    phi, theta = motor_to_pattern_deg(m.motor_azimuth_deg, m.motor_elevation_deg)
    np.testing.assert_allclose(m.rss_dbm, 10.0 - 50.0 + true.lookup_dbi(phi, theta))
    np.testing.assert_allclose(np.unique(phi), [0.0, 90.0, 180.0, 270.0])


def test_measurements_reject_nan_and_empty_enrolment():
    with pytest.raises(ValueError):
        Measurements([0.0], [90.0], [np.nan])
    with pytest.raises(InputError):
        enrol(Measurements([], [], []))


def test_enrolment_does_not_mutate_inputs():
    m = _noise_free(smartphone_like(np.random.default_rng(1)), azimuth_step_deg=30.0)
    before = m.rss_dbm.copy()
    enrol(m)
    np.testing.assert_array_equal(m.rss_dbm, before)
    assert not m.rss_dbm.flags.writeable
    assert db_to_linear(0.0) == 1.0


@pytest.mark.parametrize(
    ("kwargs", "column", "match"),
    [
        ({"azimuth_step_deg": 1e-9}, "azimuth_step_deg", "azimuth step 1e-09 deg is finer than"),
        ({"azimuth_step_deg": 0.09}, "azimuth_step_deg", "finer than the 0.1 deg limit"),
        ({"polar_step_deg": 1e-7}, "polar_step_deg", "polar step 1e-07 deg is finer than"),
        ({"polar_step_deg": 5e-324}, "polar_step_deg", "finer than the 0.1 deg limit"),
    ],
)
def test_grid_finer_than_the_limit_is_rejected_before_allocating(kwargs, column, match):
    with pytest.raises(InputError, match=match) as err:
        EnrolConfig(**kwargs)
    assert err.value.column == column and err.value.path is None
    EnrolConfig(azimuth_step_deg=0.1, polar_step_deg=0.1)  # the limit itself is allowed


def test_inferred_polar_step_finer_than_the_limit_names_the_row(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(
        "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n"
        "0,90,-40\n90,90,-41\n270,90,-43\n180,90.001,-42\n"  # azimuths 90° apart
    )
    with pytest.raises(InputError) as err:
        enrol_csv(path)
    assert (err.value.path, err.value.line, err.value.column) == (
        str(path),
        5,
        "motor_elevation_deg",
    )
    assert (
        "elevations 90 and 90.001 deg imply a polar step of 0.001 deg, finer than the 0.1 deg "
        "limit" in str(err.value)
    )
    # an explicit polar step overrides the inferred one
    p = enrol_csv(path, EnrolConfig(polar_step_deg=10.0))
    assert p.polar_deg.size == 19
