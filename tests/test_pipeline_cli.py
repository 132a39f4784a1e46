"""CLI: ``radiopose locate`` and ``radiopose score`` exactly per the contract."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from radiopose.cli import main


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def scenario(small_sim, tmp_path: Path) -> Path:
    small_sim.write(tmp_path / "sim")
    return tmp_path / "sim"


@pytest.mark.parametrize("method", ["full", "lms"])
def test_locate_then_score(scenario, capsys, method):
    est = scenario / f"est_{method}.csv"
    code, _, err = run(
        [
            "locate",
            str(scenario / "site"),
            str(scenario / "packets.csv"),
            "-o",
            str(est),
            "--method",
            method,
        ],
        capsys,
    )
    assert code == 0, err
    assert f"method {method}: 60 packets in" in err and "coverage" in err
    header = est.read_text().splitlines()[0].split(",")
    assert set(header) == {
        "timestamp_s",
        "transmitter",
        "packet_id",
        "x_m",
        "y_m",
        "z_m",
        "azimuth_deg",
        "pitch_deg",
        "roll_deg",
        "method",
    }
    code, out, err = run(["score", str(scenario / "truth.csv"), str(est), "--json"], capsys)
    assert code == 0, err
    (row,) = json.loads(out)
    assert row["method"] == method and row["n_packets"] == 60
    assert 0 < row["coverage"] <= 1
    assert (row["orientation_deg"] is None) == (method == "lms")
    code, out, _ = run(["score", str(scenario / "truth.csv"), str(est)], capsys)
    assert code == 0 and method in out and "coverage" in out


def test_locate_errors_are_one_line(scenario, capsys, tmp_path):
    site, pk = str(scenario / "site"), scenario / "packets.csv"
    code, _, err = run(
        ["locate", site, str(pk), "-o", str(tmp_path / "e.csv"), "--method", "magic"], capsys
    )
    assert code == 2 and err.count("\n") == 1 and "--method must be one of" in err
    lines = pk.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([lines[0], lines[1].replace("rx1", "rx9"), *lines[2:]]) + "\n")
    code, _, err = run(["locate", site, str(bad), "-o", str(tmp_path / "e.csv")], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "bad.csv:2, column 'receiver_id'" in err
    assert not (tmp_path / "e.csv").exists()
    empty = tmp_path / "empty.csv"
    empty.write_text(lines[0] + "\n")
    code, _, err = run(["locate", site, str(empty), "-o", str(tmp_path / "e.csv")], capsys)
    assert code == 2 and "no packets" in err and err.count("\n") == 1


def test_locate_acquisition_window_option(scenario, capsys, tmp_path):
    site, pk = str(scenario / "site"), str(scenario / "packets.csv")
    out = str(tmp_path / "e.csv")
    code, _, err = run(["locate", site, pk, "-o", out, "--acquisition-window-ms", "15"], capsys)
    assert code == 0, err
    assert "acquiring (pooling packets)" in err
    code, _, err = run(["locate", site, pk, "-o", out, "--acquisition-window-ms", "-1"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--acquisition-window-ms must be" in err


def test_score_missing_file(capsys, tmp_path):
    code, _, err = run(["score", str(tmp_path / "t.csv"), str(tmp_path / "e.csv")], capsys)
    assert code == 2 and "file not found" in err
