"""Importers: MSI/Planet, NGMN BASTA JSON, MIT LL chamber captures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.patterns.importers import (
    read_basta_json,
    read_mitll,
    read_mitll_measurements,
    read_msi,
)
from radiopose.patterns.pattern import read_pattern_csv, write_pattern_csv

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


def test_msi_tabs_between_keyword_and_value(shared_data, tmp_path):
    """Tab-separated MSI files (common) read as the spaced original: the keyword
    lines split on any whitespace, as the data lines did (helper-63: a tab after
    HORIZONTAL made the file "data line outside a section")."""
    path = shared_data / "antenna-files" / MSI_NAME
    text = path.read_text(encoding="utf-8")
    for name, tabbed in (
        ("kw.msi", text.replace("HORIZONTAL ", "HORIZONTAL\t").replace("VERTICAL ", "VERTICAL\t")),
        ("all.msi", text.replace(" ", "\t")),
    ):
        assert tabbed != text
        (tmp_path / name).write_text(tabbed, encoding="utf-8")
        for mode in ("horizontal", "sphere"):
            a, b = read_msi(path, mode=mode), read_msi(tmp_path / name, mode=mode)
            np.testing.assert_array_equal(a.directivity_dbi, b.directivity_dbi)


@pytest.mark.parametrize(
    ("mutate", "line", "column", "match"),
    [
        (lambda t: t.replace("GAIN 10 dBi\n", ""), 724, "GAIN", "no GAIN"),
        (lambda t: t.replace("GAIN 10 dBi", "GAIN ten dBi"), 3, "GAIN", "not a number"),
        (lambda t: t.replace("GAIN 10 dBi", "GAIN 10 dBm"), 3, "GAIN", "unknown gain unit"),
        (lambda t: t.replace("\n5 20.00\n", "\n5 abc\n"), 10, "HORIZONTAL attenuation", "number"),
        (lambda t: t.replace("\n5 20.00\n", "\n5 nan\n"), 10, "HORIZONTAL attenuation", "finite"),
        (lambda t: t.replace("\n5 20.00\n", "\n400 20.00\n"), 10, "HORIZONTAL angle", "range"),
        # the duplicate is reported at the offending line, naming the first
        (
            lambda t: t.replace("\n5 20.00\n", "\n4 20.00\n"),
            10,
            "HORIZONTAL angle",
            r"duplicate angle 4 \(first at line 9\)",
        ),
        (
            lambda t: t.replace("\n5 20.00\n", "\n5.5 20.00\n"),
            10,
            "HORIZONTAL angle",
            "not a multiple of 1 deg",
        ),
        (lambda t: t.split("VERTICAL")[0], 364, "VERTICAL", "no VERTICAL"),
        (lambda t: t.replace("HORIZONTAL 360", "HORIZONTAL 999"), 4, "HORIZONTAL", "announces"),
        # a stray data line between the blocks is not a header key
        (
            lambda t: t.replace("VERTICAL 360", "360 0.00\nVERTICAL 360"),
            365,
            "HORIZONTAL",
            r"data line '360 0.00' outside a section \(after the 360 points",
        ),
        (lambda t: "0 1.00\n" + t, 1, None, "before any HORIZONTAL/VERTICAL section"),
        # a deleted line: the next section header ends the block early
        (
            lambda t: t.replace("\n5 20.00\n", "\n"),
            364,
            "HORIZONTAL",
            "announces 360 points but this line ends it after 359",
        ),
        (
            lambda t: t + "HORIZONTAL 1\n0 0\n",
            726,
            "HORIZONTAL",
            r"second HORIZONTAL section \(the first is at line 4\)",
        ),
        # a mistyped angle that starts with a letter is a bad number, not a section end
        (
            lambda t: t.replace("\n3 20.00\n", "\nx3 0.03\n"),
            8,
            "HORIZONTAL angle",
            "not a number: 'x3'",
        ),
        (
            lambda t: t.replace("\n3 20.00\n", "\nabc 0.03\n"),
            8,
            "HORIZONTAL angle",
            "not a number: 'abc'",
        ),
        # a known header keyword inside a block still ends it (a deleted line)
        (
            lambda t: t.replace("\n3 20.00\n", "\nTILT 2\n"),
            8,
            "HORIZONTAL",
            "this line ends it after 3",
        ),
        # absurd values and extra fields: rejected at their line, not read
        (
            lambda t: t.replace("\n3 20.00\n", "\n3 1e308\n"),
            8,
            "HORIZONTAL attenuation",
            r"1e308 is out of range \[-1000, 1000\]",
        ),
        (
            lambda t: t.replace("\n3 20.00\n", "\n3 20.00 9\n"),
            8,
            "HORIZONTAL",
            "got 3 fields",
        ),
        # one negative attenuation among positive ones: ambiguous, rejected at its line
        (
            lambda t: t.replace("\n5 20.00\n", "\n5 -20.00\n"),
            10,
            "HORIZONTAL attenuation",
            "attenuation -20 dB has the opposite sign of the file's 717 positive values",
        ),
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


def test_msi_negative_attenuations_throughout_read_by_magnitude(tmp_path):
    h, v = _asymmetric_cuts()
    pos, neg = tmp_path / "pos.msi", tmp_path / "neg.msi"
    pos.write_text(_msi_text(h, v))
    neg.write_text(_msi_text(-h, -v))
    for mode in ("horizontal", "sphere"):
        a, b = read_msi(pos, mode=mode), read_msi(neg, mode=mode)
        np.testing.assert_array_equal(a.directivity_dbi, b.directivity_dbi)
    # a majority of negative values: the lone positive one is the odd one out
    text = _msi_text(-h, -v).replace("\n5 -20.00\n", "\n5 20.00\n")
    neg.write_text(text)
    with pytest.raises(InputError, match="opposite sign of the file's 717 negative") as err:
        read_msi(neg)
    assert (err.value.line, err.value.column) == (10, "HORIZONTAL attenuation")


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


def _line_of(text: str, fragment: str, nth: int = 0) -> int:
    """1-based line of the ``nth`` occurrence of ``fragment`` in ``text``."""
    at = -1
    for _ in range(nth + 1):
        at = text.index(fragment, at + 1)
    return text.count("\n", 0, at) + 1


@pytest.mark.parametrize(
    ("change", "column", "match", "fragment"),
    [
        ({"Coordinate_System": "SPCS_Geo"}, "Coordinate_System", "unsupported", '"SPCS_Geo"'),
        ({"Gain": {"value": "x", "unit": "dBi"}}, "Gain", "expected", '"Gain"'),
        ({"Gain": None}, "Gain", r"missing \(the value is null\)", '"Gain"'),
        ({"Data_Set": [[1.0]] * 3}, "Data_Set", "3 rows", "  [\n   1.0\n  ]\n ]"),
        (
            {"Data_Set_Row_Structure": ["PhaseCo"]},
            "Data_Set_Row_Structure",
            "MagAttenuation",
            '"Data_Set_Row_Structure"',
        ),
        ({"Theta_Sampling": [-90, 30, 100]}, "Theta_Sampling", "stop", '"Theta_Sampling"'),
        (
            {"Theta_Sampling": [0, 30, 180]},
            "Theta_Sampling",
            r"covers 0…180, out of range \[-90, 90\] for SPCS_CW",
            '"Theta_Sampling"',
        ),
        (
            {"Phi_Sampling": [30, 30, 360]},
            "Phi_Sampling",
            r"out of range \[-180, 360\)",
            '"Phi_Sampling"',
        ),
        # a sampling finer than the 0.1 deg grid limit, checked before allocating
        (
            {"Theta_Sampling": [-90, 1e-9, 90]},
            "Theta_Sampling",
            "step 1e-09 deg is finer than the 0.1 deg limit",
            '"Theta_Sampling"',
        ),
        (
            {"Phi_Sampling": [0, 0.01, 359.99]},
            "Phi_Sampling",
            "step 0.01 deg is finer than the 0.1 deg limit",
            '"Phi_Sampling"',
        ),
        # ends far out of range: rejected from the numbers, no overflow
        (
            {"Phi_Sampling": [-1e308, 0.5, 1e308]},
            "Phi_Sampling",
            r"out of range \[-180, 360\)",
            '"Phi_Sampling"',
        ),
        # a theta range that stops short: the polar grid misses 180 (theta 90 = nadir)
        (
            {"Theta_Sampling": [-90, 30, 60], "Data_Set": [[1.0]] * 72},
            "Theta_Sampling",
            r"Data_Set row 60 \(Theta 60, Phi 0\): missing grid point azimuth 0, polar 180",
            '"Theta_Sampling"',
        ),
    ],
)
def test_basta_bad_input(tmp_path, change, column, match, fragment):
    path = tmp_path / "b.json"
    text = json.dumps(_basta() | change, indent=1)
    path.write_text(text)
    with pytest.raises(InputError, match=match) as err:
        read_basta_json(path)
    assert err.value.column == column and str(path) in str(err.value)
    assert err.value.line == _line_of(text, fragment) > 1
    assert "\n" not in str(err.value)


def test_basta_a_key_given_twice_is_refused_at_its_second_line(tmp_path):
    """Two ``Gain`` members: JSON leaves which counts undefined, and json.loads
    kept the last without a word (helper-63); now one line naming the key and
    the line of its second appearance."""
    text = json.dumps(_basta(), indent=1)
    gain = text[text.index('"Gain"') : text.index("}", text.index('"Gain"')) + 1]
    twice = text.replace(gain, gain + ",\n " + gain.replace('"value": 15.0', '"value": 3.0'), 1)
    assert twice.count('"Gain"') == 2
    path = tmp_path / "twice.json"
    path.write_text(twice)
    with pytest.raises(InputError, match="key 'Gain' appears twice") as err:
        read_basta_json(path)
    second = twice.index('"Gain"', twice.index('"Gain"') + 1)
    assert err.value.line == twice.count("\n", 0, second) + 1 and err.value.column == "Gain"


def test_basta_missing_key_and_row_count(tmp_path):
    d = _basta()
    del d["Gain"]
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d, indent=2))
    with pytest.raises(InputError, match="missing key in the top-level object") as err:
        read_basta_json(path)
    assert (err.value.line, err.value.column) == (1, "Gain")
    d = _basta()
    d["Data_Set"] = d["Data_Set"] + [[1.0], [2.0]]  # 84 + 2 rows: the first extra is named
    text = json.dumps(d, indent=2)
    path.write_text(text)
    with pytest.raises(
        InputError, match="86 rows, Theta_Sampling × Phi_Sampling gives 7×12"
    ) as err:
        read_basta_json(path)
    # four '[' open lists before the rows: row k is the (4 + k)-th
    assert (err.value.line, err.value.column) == (_line_of(text, "[", 4 + 84), "Data_Set")


@pytest.mark.parametrize("indent", [None, 2])
def test_basta_nan_names_row_line_and_column(tmp_path, indent):
    d = _basta()
    d["Data_Set"][5] = [float("nan")]
    path = tmp_path / "n.json"
    text = json.dumps(d, indent=indent)  # json writes the NaN literal
    path.write_text(text)
    with pytest.raises(InputError, match="Data_Set row 5: not a finite number: NaN") as err:
        read_basta_json(path)
    assert err.value.column == "MagAttenuationTP"
    assert err.value.line == _line_of(text, "NaN")
    assert (err.value.line == 1) == (indent is None)


def test_basta_broken_json_and_non_numbers(tmp_path):
    path = tmp_path / "n.json"
    path.write_text('{\n "Gain": {"value": 1,\n')
    with pytest.raises(InputError, match="invalid JSON") as err:
        read_basta_json(path)
    assert err.value.line == 3
    for bad, literal in (("1.5", '"1.5"'), (True, "true"), (None, "null")):
        d = _basta()
        d["Data_Set"][7] = [bad]
        text = json.dumps(d, indent=2)
        path.write_text(text)
        with pytest.raises(InputError, match=f"Data_Set row 7: not a number: {literal}") as err:
            read_basta_json(path)
        assert err.value.column == "MagAttenuationTP"
        assert err.value.line == _line_of(text, "[", 4 + 7) + 1
    d = _basta()
    d["Data_Set"][9] = [1.0, 2.0]
    text = json.dumps(d, indent=2)
    path.write_text(text)
    with pytest.raises(
        InputError, match="Data_Set row 9 is 2 values, Data_Set_Row_Structure names 1"
    ):
        read_basta_json(path)


def test_basta_absurd_value_is_rejected_at_its_line(tmp_path, shared_data):
    src = json.loads((shared_data / "antenna-files" / BASTA_NAME).read_text())
    src["Data_Set"][5][0] = 1e308
    path = tmp_path / "b.json"
    path.write_text(json.dumps(src))
    with pytest.raises(InputError, match=r"Data_Set row 5: out of range \[-1000, 1000\]"):
        read_basta_json(path)


def test_basta_real_file_nan_line(shared_data, tmp_path):
    """The real file's layout (indent 2, one value per line): the line of the value."""
    d = json.loads((shared_data / "antenna-files" / BASTA_NAME).read_text())
    d["Data_Set"][100][1] = float("inf")
    text = json.dumps(d, indent=2)
    path = tmp_path / "real.json"
    path.write_text(text)
    with pytest.raises(InputError, match="Data_Set row 100: not a finite number: Infinity") as err:
        read_basta_json(path)
    assert err.value.column == "MagAttenuationCr"
    assert err.value.line == text.splitlines().index("      Infinity") + 1


def _explicit(rows: list[list[float]], system: str = "SPCS_CW") -> dict:
    d = _basta(system)
    d.update(
        Data_Set_Row_Structure=["Theta", "Phi", "MagAttenuationTP"],
        Data_Set=rows,
        Theta_Sampling=None,
        Phi_Sampling=None,
    )
    return d


def test_basta_missing_and_duplicate_direction(tmp_path):
    path = tmp_path / "m.json"
    rows = [[-90.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 180.0, 1.0], [90.0, 0.0, 1.0]]
    rows.append([90.0, 180.0, 1.0])  # theta-major, (Theta -90, Phi 180) left out
    text = json.dumps(_explicit(rows), indent=2)
    path.write_text(text)
    with pytest.raises(InputError, match="missing grid point azimuth 180, polar 0 deg") as err:
        read_basta_json(path)
    assert err.value.column == "Phi"  # within theta -90 the next phi is missing
    assert "Data_Set row 0 (Theta -90, Phi 0)" in str(err.value)
    assert err.value.line == _line_of(text, "[", 2 + 0) + 2  # row 0's Phi: expected after it
    rows = [[-90.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [90.0, 0.0, 1.0]]
    text = json.dumps(_explicit(rows), indent=2)
    path.write_text(text)
    with pytest.raises(
        InputError,
        match=r"Data_Set row 2 \(Theta 0, Phi 0\): duplicate grid point azimuth 0, polar 90 deg "
        r"\(first in row 1\)",
    ) as err:
        read_basta_json(path)
    assert err.value.column == "Phi"
    assert err.value.line == _line_of(text, "[", 2 + 2) + 2


def _sphere_rows(phis: list[float]) -> list[list[float]]:
    return [[t, ph, 1.0] for t in (-90.0, 0.0, 90.0) for ph in phis]


def test_basta_explicit_angles_out_of_range_are_rejected_not_wrapped(tmp_path):
    path = tmp_path / "r.json"
    for k, (col, value, match) in enumerate(
        [
            ("Phi", 361.0, r"Data_Set row 4: Phi 361 out of range \[-180, 360\) for SPCS_CW"),
            ("Phi", 360.0, r"Phi 360 out of range"),
            ("Phi", -181.0, r"Phi -181 out of range"),
            ("Theta", 91.0, r"Data_Set row 4: Theta 91 out of range \[-90, 90\] for SPCS_CW"),
        ]
    ):
        rows = _sphere_rows([0.0, 90.0, 180.0, 270.0])
        rows[4][0 if col == "Theta" else 1] = value
        text = json.dumps(_explicit(rows), indent=2)
        path.write_text(text)
        with pytest.raises(InputError, match=match) as err:
            read_basta_json(path)
        assert err.value.column == col, k
        assert err.value.line == _line_of(text, "[", 2 + 4) + (1 if col == "Theta" else 2)
    rows = _sphere_rows([0.0, 90.0])
    rows[0][0] = -91.0
    path.write_text(json.dumps(_explicit(rows, "SPCS_Polar")))
    with pytest.raises(InputError, match=r"Theta -91 out of range \[0, 180\] for SPCS_Polar"):
        read_basta_json(path)


def test_basta_phi_minus_180_to_180_reads_like_0_to_360(tmp_path):
    path = tmp_path / "s.json"
    rows = _sphere_rows([0.0, 90.0, 180.0, 270.0])
    for r in rows:
        r[2] = 1.0 + r[1] / 90.0
    path.write_text(json.dumps(_explicit(rows)))
    a = read_basta_json(path)
    for r in rows:
        r[1] = r[1] - 360.0 if r[1] >= 180.0 else r[1]
    path.write_text(json.dumps(_explicit(rows)))
    np.testing.assert_array_equal(read_basta_json(path).directivity_dbi, a.directivity_dbi)
    rows.append([0.0, 270.0, 1.0])  # −90 and 270 are one direction
    path.write_text(json.dumps(_explicit(rows)))
    with pytest.raises(InputError, match=r"row 12 \(Theta 0, Phi 270\): duplicate grid point"):
        read_basta_json(path)


_JSON_JUNK = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=5),
    st.sampled_from([float("nan"), float("inf"), -1e400, 1e308, 10**400, -90, 0, 361, 360.0]),
    st.lists(st.floats(-400, 400, allow_nan=False), max_size=4),
    st.dictionaries(st.sampled_from(["value", "unit"]), st.sampled_from([1, "dBi", None])),
)
_BASTA_KEYS = [
    "Coordinate_System",
    "Gain",
    "Theta_Sampling",
    "Phi_Sampling",
    "Data_Set_Row_Structure",
    "Data_Set",
]


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    edits=st.lists(
        st.tuples(
            st.sampled_from(["key", "row", "value", "delete"]),
            st.sampled_from(_BASTA_KEYS),
            st.integers(0, 83),
            _JSON_JUNK,
        ),
        max_size=3,
    ),
    explicit=st.booleans(),
    indent=st.sampled_from([None, 0, 1, 4]),
)
def test_basta_fuzz_only_input_errors_with_a_line(tmp_path_factory, edits, explicit, indent):
    d = _basta()
    if explicit:
        rows = []
        for k, (t, ph) in enumerate(
            (t, ph) for t in range(-90, 91, 30) for ph in range(0, 360, 30)
        ):
            rows.append([float(t), float(ph), d["Data_Set"][k][0]])
        d.update(Data_Set_Row_Structure=["Theta", "Phi", "MagAttenuationTP"], Data_Set=rows)
    for kind, key, r, junk in edits:
        if kind == "key":
            d[key] = junk
        elif kind == "delete":
            d.pop(key, None)
        elif isinstance(d.get("Data_Set"), list) and r < len(d["Data_Set"]):
            if kind == "row":
                d["Data_Set"][r] = junk
            elif isinstance(d["Data_Set"][r], list) and d["Data_Set"][r]:
                d["Data_Set"][r][r % len(d["Data_Set"][r])] = junk
    try:
        text = json.dumps(d, indent=indent)
    except (TypeError, ValueError):
        return
    path = tmp_path_factory.mktemp("bj") / "f.json"
    path.write_text(text)
    try:
        read_basta_json(path)
    except InputError as exc:
        assert "\n" not in str(exc) and exc.path == str(path)
        assert exc.line is not None and 1 <= exc.line <= text.count("\n") + 1


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    edits=st.lists(
        st.tuples(
            st.integers(0, 724),
            st.sampled_from(
                ["", "360 0.00", "5 -1", "5 nan", "x y", "HORIZONTAL 3", "GAIN 3", "7", "1 2 3"]
            ),
            st.booleans(),
        ),
        max_size=3,
    )
)
def test_msi_fuzz_only_input_errors_with_a_line(tmp_path_factory, edits):
    h, v = _asymmetric_cuts()
    lines = _msi_text(h, v).splitlines()
    for at, text, insert in edits:
        at = min(at, len(lines))
        if insert or at == len(lines):
            lines.insert(at, text)
        else:
            lines[at] = text
    path = tmp_path_factory.mktemp("msi") / "f.msi"
    path.write_text("\n".join(lines) + "\n")
    for mode in ("horizontal", "sphere"):
        try:
            read_msi(path, mode=mode)
        except InputError as exc:
            assert "\n" not in str(exc) and exc.path == str(path)
            assert exc.line is not None and 1 <= exc.line <= max(len(lines), 1)


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
        # rows that were skipped silently (helper-63): each would change the pattern
        ("hello\n", 12, None, "one field 'hello'"),
        ("2020-05-07 14:07:07.68", 12, None, "a line cut short"),
        ("2020,bluetooth,aa:bb:cc:dd:ee:ff,-40,12,1.5e9,37\n", 12, None, "kind 'bluetooth'"),
        ("2020,Wifi,aa:bb:cc:dd:ee:ff,-40\n", 12, None, "unknown row kind 'Wifi'"),
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
    with pytest.raises(
        InputError, match="no 'Angle' header row before the first packet row"
    ) as err:
        read_mitll_measurements(path)
    assert (err.value.line, err.value.column) == (2, "Angle")
    assert str(err.value).startswith(f"{path}:2, column 'Angle'")
    path.write_text("2020,Device,Phone\n2020,Range,6\n2020,GPS,NA\n")
    with pytest.raises(InputError, match="no 'Angle' header row in the file") as err:
        read_mitll_measurements(path)
    assert (err.value.line, err.value.column) == (3, "Angle")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"no \*\.csv"):
        read_mitll_measurements(tmp_path / "empty")


def test_mitll_two_files_with_one_angle_are_rejected_naming_both(tmp_path):
    d, _ = _mitll_dir(tmp_path, {37: 0.0})
    # c1.csv claims 0 like c0.csv: 45 deg would be missing and silently interpolated
    _mitll_file(d / "c1.csv", 0.0, {37: -60.0})
    with pytest.raises(InputError, match=r"angle 0 deg again: .*c0\.csv:4 has it too") as err:
        read_mitll_measurements(d)
    assert err.value.path == str(d / "c1.csv")
    assert (err.value.line, err.value.column) == (4, "Angle")
    assert "\n" not in str(err.value)
    _mitll_file(d / "c1.csv", 360.0, {37: -60.0})  # 360 is 0
    with pytest.raises(InputError, match=r"angle 360 deg again: .*c0\.csv:4"):
        read_mitll_measurements(d)


def test_mitll_second_angle_row_in_one_file(tmp_path):
    path = tmp_path / "c.csv"
    _mitll_file(path, 0.0, {37: -50.0}, "2020,Angle,45\n")
    with pytest.raises(
        InputError, match=r"second 'Angle' row \(the first, at line 4, says 0\)"
    ) as err:
        read_mitll_measurements([path])
    assert (err.value.line, err.value.column) == (12, "Angle")


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


# ---------------------------------------------------------------- BASTA Gain
def _flat_basta(gain_value: object, unit: str = "dBi") -> dict:
    """A 30° sphere with attenuation 0 everywhere: directivity = the gain."""
    d = _basta(Gain={"value": gain_value, "unit": unit})
    d["Data_Set"] = [[0.0] for _ in d["Data_Set"]]
    return d


@pytest.mark.parametrize(
    ("value", "unit", "match"),
    [
        (1e308, "dBi", r"Gain 1e\+308 dBi is out of range \[-200, 200\] dBi"),
        (-201, "dBi", r"Gain -201 dBi is out of range \[-200, 200\] dBi"),
        (199, "dBd", r"Gain 199 dBd \(201.15 dBi\) is out of range \[-200, 200\] dBi"),
        (10**400, "dBi", r"Gain 1000000000\d* dBi is out of range"),
        ("15.1", "dBi", r'Gain value "15.1" is not a number'),
        (True, "dBi", "Gain value true is not a number"),
        (None, "dBi", "Gain value null is not a number"),
        ([15.1], "dBi", "Gain value a list is not a number"),
        (float("nan"), "dBi", "Gain value NaN is not a finite number"),
        (15.1, "dB", 'Gain unit "dB" is not dBi or dBd'),
    ],
)
def test_basta_gain_must_be_a_number_within_the_pattern_csv_range(tmp_path, value, unit, match):
    path = tmp_path / "g.json"
    text = json.dumps(_flat_basta(value, unit), indent=2)
    path.write_text(text)
    with pytest.raises(InputError, match=match) as err:
        read_basta_json(path)
    assert (err.value.line, err.value.column) == (_line_of(text, '"Gain"'), "Gain")
    assert str(err.value).startswith(f"{path}:{err.value.line}, column 'Gain': ")
    assert "\n" not in str(err.value)


@settings(
    max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(-(10**30), 10**30),
        st.booleans(),
        st.text(max_size=6),
        st.none(),
    ),
    unit=st.sampled_from(["dBi", "dBd"]),
)
def test_basta_gain_either_round_trips_or_is_an_error_at_gain(tmp_path_factory, value, unit):
    """An imported gain is written and read back by the project's own reader, or refused."""
    folder = tmp_path_factory.mktemp("gain")
    path = folder / "g.json"
    path.write_text(json.dumps(_flat_basta(value, unit)))
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    dbi = float(value) + (2.15 if unit == "dBd" else 0.0) if number else math.nan
    try:
        p = read_basta_json(path)
    except InputError as exc:
        assert exc.column == "Gain" and exc.line == 1, str(exc)
        assert not abs(dbi) <= 200.0  # refused only outside [-200, 200] dBi (or not a number)
        return
    assert abs(dbi) <= 200.0
    write_pattern_csv(p, folder / "g.csv")
    # the CSV keeps 6 decimals
    assert read_pattern_csv(folder / "g.csv").range_dbi == pytest.approx((dbi, dbi), abs=1e-6)


# ---------------------------------------------------------------- enough angles
@pytest.mark.parametrize(
    ("change", "column", "match"),
    [
        (
            {"Theta_Sampling": [0, 30, 0], "Data_Set": [[1.0]] * 12},
            "Theta_Sampling",
            r"Theta_Sampling: 1 distinct angle \(0 deg\), a sphere needs at least 3 polar angles",
        ),
        (
            {"Theta_Sampling": [-90, 180, 90], "Data_Set": [[1.0]] * 24},
            "Theta_Sampling",
            r"Theta_Sampling: 2 distinct angles \(-90, 90 deg\), a sphere needs at least 3 polar",
        ),
        (
            {"Phi_Sampling": [0, 30, 0], "Data_Set": [[1.0]] * 7},
            "Phi_Sampling",
            r"Phi_Sampling: 1 distinct angle \(0 deg\), a sphere needs at least 3 azimuths",
        ),
        (
            {"Phi_Sampling": [0, 180, 180], "Data_Set": [[1.0]] * 14},
            "Phi_Sampling",
            r"Phi_Sampling: 2 distinct angles \(0, 180 deg\), a sphere needs at least 3 azimuths",
        ),
    ],
)
def test_basta_sampling_of_one_or_two_angles_is_rejected(tmp_path, change, column, match):
    path = tmp_path / "b.json"
    text = json.dumps(_basta() | change, indent=1)
    path.write_text(text)
    with pytest.raises(InputError, match=match) as err:
        read_basta_json(path)
    assert (err.value.line, err.value.column) == (_line_of(text, f'"{column}"'), column)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_basta_explicit_angles_need_three_of_each(tmp_path):
    path = tmp_path / "e.json"
    for rows, column, match in (
        ([[t, 0.0, 1.0] for t in (-90.0, 0.0, 90.0)], "Phi", r"Data_Set Phi: 1 distinct angle"),
        (
            [[t, ph, 1.0] for t in (-90.0, 90.0) for ph in (0.0, 120.0, 240.0)],
            "Theta",
            r"Data_Set Theta: 2 distinct angles \(-90, 90 deg\)",
        ),
    ):
        text = json.dumps(_explicit(rows), indent=2)
        path.write_text(text)
        with pytest.raises(InputError, match=match) as err:
            read_basta_json(path)
        assert (err.value.line, err.value.column) == (_line_of(text, '"Data_Set"'), column)
    rows = [[t, ph, 1.0] for t in (-90.0, 0.0, 90.0) for ph in (0.0, 120.0, 240.0)]
    path.write_text(json.dumps(_explicit(rows)))
    assert read_basta_json(path).directivity_dbi.shape == (3, 3)  # the minimum sphere


def _msi_cuts(h_angles: list[float], v_angles: list[float], gain: str = "10 dBi") -> str:
    lines = ["NAME t", f"GAIN {gain}", f"HORIZONTAL {len(h_angles)}"]
    lines += [f"{a:g} {k}" for k, a in enumerate(h_angles)]
    lines += [f"VERTICAL {len(v_angles)}"] + [f"{a:g} {k}" for k, a in enumerate(v_angles)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("h", "v", "line", "column", "match"),
    [
        ([0.0], [0.0, 120.0, 240.0], 3, "HORIZONTAL", r"HORIZONTAL: 1 distinct angle \(0 deg\)"),
        ([0.0, 180.0], [0.0, 120.0, 240.0], 3, "HORIZONTAL", r"2 distinct angles \(0, 180 deg\)"),
        ([0.0, 120.0, 240.0], [0.0, 180.0], 7, "VERTICAL", r"VERTICAL: 2 distinct angles"),
    ],
)
def test_msi_cut_of_one_or_two_angles_is_rejected(tmp_path, h, v, line, column, match):
    path = tmp_path / "c.msi"
    path.write_text(_msi_cuts(h, v))
    for mode in ("horizontal", "sphere"):
        with pytest.raises(InputError, match=match) as err:
            read_msi(path, mode=mode)
        assert (err.value.line, err.value.column) == (line, column)
        assert str(err.value).endswith("a cut needs at least 3 around the circle")
    path.write_text(_msi_cuts([0.0, 120.0, 240.0], [0.0, 120.0, 240.0]))
    assert read_msi(path, mode="sphere").directivity_dbi.shape == (360, 181)  # the minimum


def test_mitll_captures_of_one_or_two_angles_are_rejected(tmp_path):
    d = tmp_path / "two"
    d.mkdir()
    for k, angle in enumerate((0.0, 45.0)):
        _mitll_file(d / f"c{k}.csv", angle, {37: -60.0 - k})
    msg = r"capture Angle in 2 files: 2 distinct angles \(0, 45 deg\), a pattern needs at least 3"
    for source in (d, sorted(d.glob("*.csv"))):
        with pytest.raises(InputError, match=msg) as err:
            read_mitll(source)
        assert (err.value.line, err.value.column) == (None, "Angle")
        assert err.value.path == str(d if source == d else d / "c0.csv")
    with pytest.raises(InputError, match=r"in 1 file: 1 distinct angle \(45 deg\)") as err:
        read_mitll_measurements(d / "c1.csv")
    assert (err.value.path, err.value.line, err.value.column) == (str(d / "c1.csv"), 4, "Angle")
    _mitll_file(d / "c2.csv", 90.0, {37: -65.0})
    # three angles pass the count but leave 90–360° to the fill: refused, not invented
    with pytest.raises(InputError, match=r"motor azimuths 90–360° \(a 270° gap\)") as err:
        read_mitll(d)
    assert (err.value.path, err.value.column) == (str(d), "Angle")
    _mitll_file(d / "c3.csv", 180.0, {37: -62.0})
    _mitll_file(d / "c4.csv", 270.0, {37: -63.0})
    assert read_mitll(d).azimuth_deg.size == 360  # gaps of at most 90°: filled


def test_mitll_angles_in_radians_hint_names_the_angle_column(tmp_path):
    """The radians hint said 'motor_azimuth_deg is in degrees' under column 'Angle':
    it names the column of the file being read."""
    d = tmp_path / "rad"
    d.mkdir()
    for k, angle in enumerate((0.0, 1.57, 3.14, 4.71)):
        _mitll_file(d / f"c{k}.csv", angle, {37: -60.0 - k})
    with pytest.raises(InputError) as err:
        read_mitll(d)
    assert (err.value.path, err.value.column) == (str(d), "Angle")
    assert str(err.value).endswith("radians? Angle is in degrees")
    assert "motor_azimuth_deg" not in str(err.value)


# ---------------------------------------------------------------- large BASTA files
def _compact_basta(theta_step: float, phi_step: float) -> str:
    """A BASTA JSON as compact as such files get: no spaces, one decimal."""
    th = np.arange(-90.0, 90.0 + theta_step / 2, theta_step)
    ph = np.arange(0.0, 360.0 - phi_step / 2, phi_step)
    rows = np.round(np.random.default_rng(1).uniform(0, 40, (th.size * ph.size, 2)), 1)
    d = {
        "Coordinate_System": "SPCS_CW",
        "Gain": {"value": 15.0, "unit": "dBi"},
        "Theta_Sampling": [-90.0, theta_step, 90.0],
        "Phi_Sampling": [0.0, phi_step, float(ph[-1])],
        "Data_Set_Row_Structure": ["MagAttenuationCo", "MagAttenuationCr"],
        "Data_Set": rows.tolist(),
    }
    return json.dumps(d, separators=(",", ":"))


def test_basta_peak_memory_is_a_small_multiple_of_the_file(tmp_path):
    """Data_Set goes straight into a float array: no list and float objects per row
    (47x the file's size before, 15x now, measured by tracemalloc)."""
    import tracemalloc

    path = tmp_path / "large.json"
    text = _compact_basta(0.5, 1.0)  # 361 × 360 directions, 1.5 MB
    path.write_text(text)
    tracemalloc.start()
    try:
        p = read_basta_json(path)
        peak_bytes = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert p.directivity_dbi.shape == (360, 361)
    assert peak_bytes < 25 * len(text), peak_bytes / len(text)


_ROW_JUNK = st.one_of(
    st.floats(-2000, 2000),
    st.integers(-5, 5),
    st.sampled_from([float("nan"), float("inf"), 10**400, True, False, None, "1.5", [1.0], {}]),
)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    rows=st.lists(st.lists(_ROW_JUNK, min_size=0, max_size=3), min_size=0, max_size=6),
    indent=st.sampled_from([None, 0, 2]),
    tail=st.sampled_from(["", " ", "\n", ",", "]", " x", '{"a": 1}']),
    twice=st.booleans(),
)
def test_basta_row_decoder_reads_what_json_loads_reads(tmp_path_factory, rows, indent, tail, twice):
    """The row-by-row decoder gives json.loads's document with Data_Set as an array,
    or leaves the file to json.loads (None): it never reads a file differently."""
    from radiopose.patterns.importers.basta import _decode

    d = {"Coordinate_System": "SPCS_CW", "Data_Set": rows, "Gain": {"value": 1, "unit": "dBi"}}
    text = json.dumps(d, indent=indent)
    if twice:  # a repeated key: the last one wins
        text = text[:-1] + ', "Data_Set": [[1.5, 2]]}'
    text += tail
    try:
        expected = json.loads(text)
    except ValueError:
        assert _decode(text) is None
        return
    got = _decode(text)
    if got is None:
        return
    table = expected.pop("Data_Set")
    assert np.array_equal(got.pop("Data_Set"), np.array(table, dtype=np.float64), equal_nan=True)
    assert all(type(v) in (int, float) for row in table for v in row)
    assert got == expected


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from([0.0, -0.0, 1.0, 1e-300, 5e-324]), st.sampled_from([0.0, 90.0])),
        min_size=1,
        max_size=10,
    )
)
def test_grid_duplicate_search_agrees_with_a_dict_walk(pairs):
    """pattern_from_samples finds repeats by one sort instead of a dict of every sample."""
    from radiopose.patterns.pattern import first_repeat

    seen: dict[tuple[float, float], int] = {}
    expected = None
    for r, key in enumerate(pairs):
        if key in seen:
            expected = (r, seen[key])
            break
        seen[key] = r
    az, po = (np.array(v) for v in zip(*pairs, strict=True))
    assert first_repeat(az, po) == expected


# ------------------------------------- the directivity's range, reached by gain - attenuation
def test_gain_minus_attenuation_beyond_the_pattern_csv_range_is_refused_naming_the_file(
    tmp_path,
):
    """A gain and an attenuation each within their own bounds can give a
    directivity the pattern CSV refuses (15 dBi − 300 dB = −285 dBi): refused
    on import, naming the file and the direction (it used to be imported and
    written, and the written file then refused)."""
    d = _basta()
    d["Data_Set"][5] = [300.0]
    path = tmp_path / "deep.json"
    path.write_text(json.dumps(d))
    with pytest.raises(
        InputError,
        match=r"Data_Set row 5: directivity -285 dBi \(Gain 15 dBi − attenuation 300 dB\) "
        r"is out of \[-200, 200\]",
    ) as err:
        read_basta_json(path)
    assert err.value.path == str(path) and "\n" not in str(err.value)
    assert err.value.column == "MagAttenuationTP" and err.value.line is not None
    h, v = _asymmetric_cuts()
    h[100] = 250.0  # 10 dBi − 250 dB
    msi = tmp_path / "deep.msi"
    msi.write_text(_msi_text(h, v))
    for mode in ("horizontal", "sphere"):
        with pytest.raises(
            InputError, match=r"directivity -240 dBi .* out of \[-200, 200\]"
        ) as err:
            read_msi(msi, mode=mode)
        assert err.value.path == str(msi)


def test_pattern_beyond_the_csv_range_is_refused_in_python():
    from radiopose.patterns.pattern import Pattern

    d = np.zeros((4, 1))
    d[2, 0] = -200.5
    with pytest.raises(InputError, match=r"directivity -200.5 dBi at azimuth 180, polar 90 deg"):
        Pattern("p", np.arange(4) * 90.0, np.array([90.0]), d)
    d[2, 0] = -200.0  # the bound itself is the CSV's, accepted
    assert Pattern("p", np.arange(4) * 90.0, np.array([90.0]), d).range_dbi[0] == -200.0


def test_basta_integer_beyond_pythons_digit_limit_is_an_input_error(tmp_path):
    path = tmp_path / "long.json"
    path.write_text(json.dumps(_basta()).replace('"value": 15.0', '"value": ' + "1" * 5000))
    with pytest.raises(InputError, match="invalid JSON: Exceeds the limit") as err:
        read_basta_json(path)
    assert err.value.path == str(path) and "\n" not in str(err.value)
