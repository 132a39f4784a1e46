"""Importers: MSI/Planet, NGMN BASTA JSON, MIT LL chamber captures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.patterns.importers import (
    read_basta_json,
    read_mitll,
    read_mitll_measurements,
    read_msi,
)
from radiopose.patterns.pattern import read_pattern_csv

REPO = Path(__file__).resolve().parents[1]
MSI_NAME = "python_antenna_pattern_simulated_05T.msi"
BASTA_NAME = "eas-3d-pattern_VENDOR_ANTMODEL4_3700_UniformSampling_3drp.json"


# ---------------------------------------------------------------- MSI
def _msi_text(h: np.ndarray, v: np.ndarray, gain: str = "10 dBi") -> str:
    lines = ["NAME test", "FREQUENCY 2437", f"GAIN {gain}", "HORIZONTAL 360"]
    lines += [f"{k} {h[k]:.2f}" for k in range(360)]
    lines += ["VERTICAL 360"] + [f"{k} {v[k]:.2f}" for k in range(360)]
    return "\n".join(lines) + "\n"


def _asymmetric_cuts() -> tuple[np.ndarray, np.ndarray]:
    h = np.full(360, 20.0)
    h[0], h[90], h[270] = 0.0, 3.0, 12.0  # 90° clockwise is weaker than 270° clockwise
    v = np.full(360, 25.0)
    v[0], v[10], v[350] = 1.0, 0.0, 6.0  # peak 10° below the horizon
    return h, v


def test_msi_horizontal_cut_clockwise_to_counter_clockwise(tmp_path):
    h, v = _asymmetric_cuts()
    path = tmp_path / "a.msi"
    path.write_text(_msi_text(h, v))
    p = read_msi(path)
    assert p.is_slice and p.polar_deg[0] == 90.0 and p.name == "a"
    d = p.directivity_dbi[:, 0]
    assert d[0] == pytest.approx(10.0)  # boresight = body +x, gain in dBi
    assert d[270] == pytest.approx(10.0 - 3.0)  # h = 90 (clockwise) -> phi = 270
    assert d[90] == pytest.approx(10.0 - 12.0)  # h = 270 -> phi = 90


def test_msi_gain_in_dbd_by_default(tmp_path):
    h, v = _asymmetric_cuts()
    for gain, peak in (("10", 12.15), ("10 dBd", 12.15), ("10 dBi", 10.0)):
        path = tmp_path / "g.msi"
        path.write_text(_msi_text(h, v, gain))
        assert read_msi(path).range_dbi[1] == pytest.approx(peak)


def test_msi_sphere_follows_both_cuts(tmp_path):
    h, v = _asymmetric_cuts()
    path = tmp_path / "s.msi"
    path.write_text(_msi_text(h, v))
    p = read_msi(path, mode="sphere")
    assert p.directivity_dbi.shape == (360, 181)
    # front vertical half-plane: theta = 90 + v; down-tilt 10° -> peak at theta 100
    assert p.directivity_dbi[0, 100] == pytest.approx(10.0)
    assert p.directivity_dbi[0, 90] == pytest.approx(9.0)
    assert p.directivity_dbi[0, 80] == pytest.approx(4.0)  # v = 350 (10° above)
    # horizontal cut on the tilt cone
    assert p.directivity_dbi[270, 100] == pytest.approx(7.0)
    assert p.range_dbi[0] == pytest.approx(10.0 - 25.0)  # capped at the largest attenuation
    np.testing.assert_allclose(p.directivity_dbi[:, 0], p.directivity_dbi[0, 0])  # pole


def test_msi_real_file(shared_data):
    path = shared_data / "antenna-files" / MSI_NAME
    h = read_msi(path)
    assert h.range_dbi == pytest.approx((19.09 - 45.0, 19.09))
    assert h.azimuth_deg[np.argmax(h.directivity_dbi[:, 0])] == 0.0
    s = read_msi(path, mode="sphere")
    i, j = np.unravel_index(np.argmax(s.directivity_dbi), s.directivity_dbi.shape)
    assert (i, j) == (0, 95)  # ELECTRICAL_TILT 05: 5° below the horizon
    assert s.range_dbi == pytest.approx((19.09 - 50.0, 19.09))
    n = read_msi(path, mode="sphere", normalise=True)
    assert n.range_dbi[1] == pytest.approx(18.89, abs=0.01)  # near the stated gain


@pytest.mark.parametrize(
    ("mutate", "line", "column", "match"),
    [
        (lambda t: t.replace("GAIN 10 dBi\n", ""), None, "GAIN", "no GAIN"),
        (lambda t: t.replace("GAIN 10 dBi", "GAIN ten dBi"), 3, "GAIN", "not a number"),
        (lambda t: t.replace("GAIN 10 dBi", "GAIN 10 dBm"), 3, "GAIN", "unknown gain unit"),
        (lambda t: t.replace("\n5 20.00\n", "\n5 abc\n"), 10, "HORIZONTAL attenuation", "number"),
        (lambda t: t.replace("\n5 20.00\n", "\n5 nan\n"), 10, "HORIZONTAL attenuation", "finite"),
        (lambda t: t.replace("\n5 20.00\n", "\n400 20.00\n"), 10, "HORIZONTAL angle", "range"),
        (lambda t: t.replace("\n5 20.00\n", "\n4 20.00\n"), 4, "HORIZONTAL", "duplicate"),
        (lambda t: t.split("VERTICAL")[0], None, "VERTICAL", "no VERTICAL"),
        (lambda t: t.replace("HORIZONTAL 360", "HORIZONTAL 999"), 4, "HORIZONTAL", "announces"),
    ],
)
def test_msi_bad_input(tmp_path, mutate, line, column, match):
    h, v = _asymmetric_cuts()
    path = tmp_path / "bad.msi"
    path.write_text(mutate(_msi_text(h, v)))
    with pytest.raises(InputError, match=match) as err:
        read_msi(path)
    assert err.value.path == str(path) and err.value.line == line
    assert err.value.column == column and "\n" not in str(err.value)


# ---------------------------------------------------------------- BASTA
def _basta(system: str = "SPCS_CW", step: float = 30.0, **extra) -> dict:
    if system == "SPCS_Polar":
        th = np.arange(0.0, 180.0 + step / 2, step)
    else:
        th = np.arange(-90.0, 90.0 + step / 2, step)
    ph = np.arange(0.0, 360.0, step)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    polar = tt if system == "SPCS_Polar" else tt + 90.0
    att = 20.0 * (1 - np.sin(np.deg2rad(polar))) + np.where(pp == 60.0, 0.0, 5.0)
    att = np.where(np.isclose(np.sin(np.deg2rad(polar)), 0.0), 25.0, att)  # flat poles
    data = {
        "BASTA_AA_WP_version": "3.0",
        "Coordinate_System": system,
        "Gain": {"value": 15.0, "unit": "dBi"},
        "Theta_Sampling": [float(th[0]), step, float(th[-1])],
        "Phi_Sampling": [0.0, step, 360.0 - step],
        "Data_Set_Row_Structure": ["MagAttenuationTP"],
        "Data_Set": [[float(a)] for a in att.ravel()],
    }
    data.update(extra)
    return data


@pytest.mark.parametrize(("system", "phi_peak"), [("SPCS_CW", 300.0), ("SPCS_CCW", 60.0)])
def test_basta_cw_and_ccw_conversions(tmp_path, system, phi_peak):
    path = tmp_path / "b.json"
    path.write_text(json.dumps(_basta(system)))
    p = read_basta_json(path)
    assert p.polar_deg.size == 7 and p.azimuth_deg.size == 12
    i, j = np.unravel_index(np.argmax(p.directivity_dbi), p.directivity_dbi.shape)
    assert (p.azimuth_deg[i], p.polar_deg[j]) == (phi_peak, 90.0)
    assert p.range_dbi[1] == pytest.approx(15.0)


def test_basta_polar_system_and_dbd_gain(tmp_path):
    path = tmp_path / "b.json"
    path.write_text(json.dumps(_basta("SPCS_Polar", Gain={"value": 15.0, "unit": "dBd"})))
    p = read_basta_json(path)
    i, j = np.unravel_index(np.argmax(p.directivity_dbi), p.directivity_dbi.shape)
    assert (p.azimuth_deg[i], p.polar_deg[j]) == (60.0, 90.0)
    assert p.range_dbi[1] == pytest.approx(17.15)


def test_basta_co_plus_cross_polar_and_explicit_angles(tmp_path):
    d = _basta("SPCS_CW")
    rows = []
    k = 0
    for t in np.arange(-90.0, 91.0, 30.0):
        for ph in np.arange(0.0, 360.0, 30.0):
            a = d["Data_Set"][k][0]
            rows.append([t, ph, a + 3.0103, a + 3.0103])  # two halves of the power
            k += 1
    d.update(
        Data_Set_Row_Structure=["Theta", "Phi", "MagAttenuationCo", "MagAttenuationCr"],
        Data_Set=rows,
        Theta_Sampling=None,
        Phi_Sampling=None,
    )
    path = tmp_path / "b.json"
    path.write_text(json.dumps(d))
    p = read_basta_json(path)
    assert p.range_dbi[1] == pytest.approx(15.0, abs=1e-4)


def test_basta_real_file(shared_data):
    p = read_basta_json(shared_data / "antenna-files" / BASTA_NAME)
    assert p.directivity_dbi.shape == (360, 181)
    i, j = np.unravel_index(np.argmax(p.directivity_dbi), p.directivity_dbi.shape)
    assert (p.azimuth_deg[i], p.polar_deg[j]) == (0.0, 90.0)
    assert p.range_dbi == pytest.approx((-72.25, 15.11), abs=0.01)


@pytest.mark.parametrize(
    ("change", "column", "match"),
    [
        ({"Coordinate_System": "SPCS_Geo"}, "Coordinate_System", "unsupported"),
        ({"Gain": {"value": "x", "unit": "dBi"}}, "Gain", "expected"),
        ({"Gain": None}, "Gain", "missing"),
        ({"Data_Set": [[1.0]] * 3}, "Data_Set", "rows"),
        ({"Data_Set_Row_Structure": ["PhaseCo"]}, "Data_Set_Row_Structure", "MagAttenuation"),
        ({"Theta_Sampling": [-90, 30, 100]}, "Theta_Sampling", "stop"),
        ({"Theta_Sampling": [0, 30, 180]}, "Data_Set", "theta out of range"),
    ],
)
def test_basta_bad_input(tmp_path, change, column, match):
    path = tmp_path / "b.json"
    path.write_text(json.dumps(_basta(**{}) | change))
    with pytest.raises(InputError, match=match) as err:
        read_basta_json(path)
    assert err.value.column == column and str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_basta_nan_and_broken_json(tmp_path):
    d = _basta()
    d["Data_Set"][5] = [float("nan")]
    path = tmp_path / "n.json"
    path.write_text(json.dumps(d))  # json writes the NaN literal
    with pytest.raises(InputError, match="row 5 has NaN"):
        read_basta_json(path)
    path.write_text('{\n "Gain": {"value": 1,\n')
    with pytest.raises(InputError, match="invalid JSON") as err:
        read_basta_json(path)
    assert err.value.line == 3


def test_basta_missing_direction(tmp_path):
    d = _basta()
    d.update(
        Data_Set_Row_Structure=["Theta", "Phi", "MagAttenuationTP"],
        Data_Set=[[0.0, 0.0, 1.0], [0.0, 180.0, 1.0], [-90.0, 0.0, 1.0]],
    )
    path = tmp_path / "m.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="missing direction"):
        read_basta_json(path)
    d["Data_Set"] = [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="duplicate direction azimuth 0, polar 90"):
        read_basta_json(path)


# ---------------------------------------------------------------- MIT LL
def _mitll_file(path: Path, angle: float, levels: dict[int, float], extra: str = "") -> None:
    lines = [
        "2020-05-07 14:03:04.1,Environment,Anechoic Chamber w/ Positioner",
        "2020-05-07 14:03:04.1,Device,Test Phone",
        "2020-05-07 14:03:04.1,Range,6",
        f"2020-05-07 14:03:04.1,Angle,{angle:g}",
        "2020-05-07 14:03:04.1,TxPower,12",
        "2020-05-07 14:03:04.1,GPS,NA",
    ]
    for k in range(4):
        for ch, level in levels.items():
            rss = level + (1.0 if k % 2 else -1.0)
            lines.append(f"2020-05-07 14:00:53.4,Bluetooth,aa:bb:cc:dd:ee:ff,{rss:g},12,1.5e9,{ch}")
    lines.append("2020-05-07 14:00:53.4,Bluetooth,11:22:33:44:55:66,-20,12,1.5e9,37")  # stray
    path.write_text("\n".join(lines) + "\n" + extra)


def _mitll_dir(tmp_path: Path, offsets: dict[int, float]) -> tuple[Path, np.ndarray]:
    d = tmp_path / "phone"
    d.mkdir()
    shape = 3.0 * np.cos(np.deg2rad(np.arange(0, 360, 45) - 90.0))
    for k, angle in enumerate(range(0, 360, 45)):
        _mitll_file(d / f"c{k}.csv", angle, {ch: -60.0 + shape[k] + o for ch, o in offsets.items()})
    return d, shape


def test_mitll_channel_offsets_are_removed(tmp_path):
    d, _ = _mitll_dir(tmp_path, {37: -6.0, 38: 0.0, 39: 4.0})
    m = read_mitll_measurements(d)
    assert len(m) == 24 and np.all(m.motor_elevation_deg == 90.0)
    per = m.rss_dbm.reshape(8, 3)
    np.testing.assert_allclose(per - per[:, :1], 0.0, atol=1e-12)  # channels agree after removal
    p = read_mitll(d)
    (tmp_path / "one").mkdir()
    single, _ = _mitll_dir(tmp_path / "one", {38: 0.0})
    q = read_mitll(single)
    np.testing.assert_allclose(p.directivity_dbi, q.directivity_dbi, atol=1e-9)
    # shape peaks at positioner angle 90 -> pattern azimuth 270
    assert p.azimuth_deg[np.argmax(p.directivity_dbi[:, 0])] == 270.0


def test_mitll_without_channel_removal_keeps_offsets(tmp_path):
    d, _ = _mitll_dir(tmp_path, {37: -6.0, 39: 4.0})
    per = read_mitll_measurements(d, remove_channel_means=False).rss_dbm.reshape(8, 2)
    np.testing.assert_allclose(per[:, 1] - per[:, 0], 10.0, atol=1e-9)


def test_mitll_mac_selection(tmp_path):
    d, _ = _mitll_dir(tmp_path, {37: 0.0})
    stray = read_mitll_measurements(d, mac="11:22:33:44:55:66", remove_channel_means=False)
    np.testing.assert_allclose(stray.rss_dbm, -20.0)
    with pytest.raises(InputError, match="no packets from"):
        read_mitll_measurements(d, mac="00:00:00:00:00:00")


@pytest.mark.parametrize(
    ("extra", "line", "column", "match"),
    [
        ("2020,Bluetooth,aa:bb:cc:dd:ee:ff,-5x,12,1.5e9,37\n", 12, "RSSI dBm", "not a number"),
        ("2020,Bluetooth,aa:bb:cc:dd:ee:ff,nan,12,1.5e9,37\n", 12, "RSSI dBm", "finite"),
        ("2020,Bluetooth,aa:bb:cc:dd:ee:ff,-50,12,1.5e9,40\n", 12, "BLE channel", "37/38/39"),
        ("2020,Bluetooth,aa:bb:cc:dd:ee:ff,-50\n", 12, None, "fields"),
        ("2020,Angle,400\n", 12, "Angle", "out of range"),
    ],
)
def test_mitll_bad_rows(tmp_path, extra, line, column, match):
    path = tmp_path / "c.csv"
    _mitll_file(path, 0.0, {37: -50.0}, extra)
    with pytest.raises(InputError, match=match) as err:
        read_mitll_measurements([path])
    assert err.value.line == line and err.value.column == column
    assert str(err.value).startswith(f"{path}:{line}")


def test_mitll_missing_angle_and_empty_dir(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("2020,Device,Phone\n2020,Bluetooth,aa,-50,12,1.5e9,37\n")
    with pytest.raises(InputError, match="no 'Angle'"):
        read_mitll_measurements(path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"no \*\.csv"):
        read_mitll_measurements(tmp_path / "empty")


@pytest.mark.parametrize(
    ("folder", "shipped", "low", "high"),
    [
        ("iPhone-11-2", "iphone-11", -4.74, 4.88),
        ("Samsung-Galaxy-S10-2", "galaxy-s10", -4.47, 2.18),
    ],
)
def test_mitll_real_phones_match_shipped_patterns(shared_data, folder, shipped, low, high):
    p = read_mitll(shared_data / "phone-patterns-mitll" / folder, name=shipped)
    assert p.range_dbi == pytest.approx((low, high), abs=0.01)
    ship = read_pattern_csv(REPO / "src" / "radiopose" / "data" / "patterns" / f"{shipped}.csv")
    np.testing.assert_allclose(ship.directivity_dbi, p.directivity_dbi, atol=2e-6)
