"""CLI: help, simulate per contract, one-line errors, demo."""

import subprocess
import sys
from pathlib import Path

import pytest

from radiopose.cli import main


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_help_lists_every_command(capsys):
    code, out, _ = run(["--help"], capsys)
    assert code == 0
    for cmd in ("simulate", "demo"):
        assert cmd in out


def test_simulate_contract_call(tmp_path, capsys):
    code, out, err = run(
        [
            "simulate",
            "-o",
            str(tmp_path / "s"),
            "--seed",
            "4",
            "--noise-db",
            "0.5",
            "--receivers",
            "3",
            "--interval-ms",
            "20",
            "--duration-s",
            "0.2",
            "--size-m",
            "8",
            "--step-m",
            "0.5",
        ],
        capsys,
    )
    assert code == 0, err
    assert (tmp_path / "s" / "site" / "site.toml").is_file()
    lines = (tmp_path / "s" / "truth.csv").read_text().splitlines()
    assert len(lines) == 1 + 10
    assert "packets.csv" in out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--receivers", "0"], "n_receivers = 0 is out of range"),
        (["--rotation", "spin"], "--rotation must be one of"),
        (["--noise-db", "-2"], "noise_db"),
    ],
)
def test_simulate_errors_one_line(tmp_path, capsys, args, needle):
    code, _, err = run(["simulate", "-o", str(tmp_path / "x"), *args], capsys)
    assert code == 2
    assert needle in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_console_script_no_traceback(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "radiopose", "simulate", "-o", str(tmp_path), "--receivers", "99"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.startswith("radiopose: ") and "Traceback" not in r.stderr


def test_demo_writes_and_reports(tmp_path, capsys):
    code, out, err = run(["demo", "-o", str(tmp_path / "d"), "--duration-s", "0.1"], capsys)
    assert code == 0, err
    for name in ("scene.png", "survey_map_rx1.png", "patterns.png"):
        assert (tmp_path / "d" / name).stat().st_size > 10_000
        assert name in out
    assert Path(tmp_path / "d" / "scenario" / "packets.csv").is_file()
