"""The code base stays ruff clean (configuration in pyproject.toml)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_ruff_clean():
    if (
        shutil.which("ruff") is None
        and subprocess.run(
            [sys.executable, "-m", "ruff", "--version"], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("ruff not installed (pip install -e '.[test]')")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "ruff",
            "check",
            "--no-cache",
            "src",
            "tests",
            "benchmarks",
            "scripts",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_every_test_module_has_a_registered_tier():
    import tomllib

    from conftest import TIERS

    modules = {p.stem for p in (REPO / "tests").glob("test_*.py")}
    assert sorted(modules - set(TIERS)) == [], "add these modules to TIERS in tests/conftest.py"
    assert sorted(set(TIERS) - modules) == [], "TIERS in tests/conftest.py names missing modules"
    with (REPO / "pyproject.toml").open("rb") as fh:
        markers = tomllib.load(fh)["tool"]["pytest"]["ini_options"]["markers"]
    registered = {m.split(":")[0] for m in markers}
    assert set(TIERS.values()) | {"slow"} <= registered
