"""Shared fixtures: small simulated sites and the path to the shared real data."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the repository (skips the test if absent)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def small_sim():
    """A small, fast simulated scenario (10 m area, 0.25 m grid, 0.3 s trace)."""
    from radiopose.simulate import ScenarioConfig, simulate

    cfg = ScenarioConfig(
        size_m=10.0, step_m=0.25, duration_s=0.3, noise_db=0.5, min_receiver_spacing_m=3.0
    )
    return simulate(cfg, seed=1234)


@pytest.fixture
def small_site_dir(small_sim, tmp_path: Path) -> Path:
    """The small scenario written to disk; returns the site directory."""
    small_sim.write(tmp_path / "sim")
    return tmp_path / "sim" / "site"
