"""Shared fixtures: small simulated sites and the path to the shared real data."""

from __future__ import annotations

import contextlib
import importlib
import os
import pkgutil
from pathlib import Path

import anyio
import matplotlib
import pytest

# pytest rewrites (parses) on first import every module of a distribution that
# ships a pytest plugin, anyio among them. Starlette serves a file through
# anyio, which imports its modules lazily (the asyncio backend for the thread
# pool; since anyio 4.16 also ``_core._fileio`` for ``open_file``): in a server
# thread, while the main thread parses a test module, CPython 3.11's ast.parse
# is not thread-safe ("SystemError: AST constructor recursion depth mismatch",
# CI failures of the dashboard test on a fresh clone, sessions 24 and 27). So
# every anyio module is imported here, once, in the main thread; one that
# cannot be imported (the trio backend without trio) is skipped.
for _module in pkgutil.walk_packages(anyio.__path__, "anyio."):
    with contextlib.suppress(ImportError):
        importlib.import_module(_module.name)

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

TIERS: dict[str, str] = {
    # analytic: closed-form references and exact equivalences on small, hand-built inputs
    "test_baselines": "analytic",
    "test_clustering": "analytic",
    "test_filter_kernels": "analytic",
    "test_filter_likelihood_option": "analytic",
    "test_filter_smoother": "analytic",
    "test_filter_speed": "analytic",
    "test_likelihood": "analytic",
    "test_likelihood_compiled": "analytic",
    "test_refine2d_banded": "analytic",
    "test_motion": "analytic",
    "test_patterns_enrol": "analytic",
    "test_scoring": "analytic",
    "test_security_attacker": "analytic",
    "test_units": "analytic",
    # property: seeded properties, round trips and hypothesis fuzzing of parsers/geometry
    "test_api_input": "property",
    "test_capture_radiotap": "property",
    "test_capture_records": "property",
    "test_geometry": "property",
    "test_module_seams": "property",
    "test_pose3d_settings": "property",
    "test_filter_settings": "property",
    "test_pose3d_site": "property",
    "test_patterns_importers": "property",
    "test_refine3d_escalate": "e2e",
    "test_orientation_path": "e2e",
    "test_patterns_io": "property",
    "test_site": "property",
    "test_site_toml_keys": "property",
    "test_site_validation": "property",
    "test_site_api_input": "property",
    "test_patterns_api_input": "property",
    "test_tables": "property",
    # e2e: simulated (or real) scenarios through the pipeline, the CLI and the reports,
    # asserting an error bound or a pinned output
    "test_accuracy": "e2e",
    "test_startup_cache": "e2e",
    "test_capture_sync": "e2e",
    "test_cli_core": "e2e",
    "test_demo": "e2e",
    "test_demo_walk": "e2e",
    "test_detection": "e2e",
    "test_detection_oracle": "e2e",
    "test_detection_wiring": "e2e",
    "test_evaluate_experiments": "e2e",
    "test_evaluate_pose3d": "e2e",
    "test_evaluate_report": "e2e",
    "test_evaluate_runner": "e2e",
    "test_filter": "e2e",
    "test_live_resolve": "e2e",
    "test_textbook_pf": "e2e",
    "test_filter_offline_workers": "e2e",
    "test_filter_offset": "e2e",
    "test_filter_offset_refit": "e2e",
    "test_filter_offset_profile": "e2e",
    "test_filter_offset_grid": "e2e",
    "test_filter_laplace": "e2e",
    "test_filter_coarse_track": "e2e",
    "test_filter_angular_noise": "e2e",
    "test_filter_refine2d": "e2e",
    "test_filter_reverse": "e2e",
    "test_filter_smoother_jump": "e2e",
    "test_method_protocol": "e2e",
    "test_method_plugins": "e2e",
    "test_method_registry": "e2e",
    "test_method_registry_filter": "e2e",
    "test_patterns_cli": "e2e",
    "test_pipeline_cli": "e2e",
    "test_pose3d": "e2e",
    "test_refine3d": "e2e",
    "test_refine3d_heading": "property",
    "test_reverse3d": "e2e",
    "test_restart3d": "e2e",
    "test_offline_particles3d": "e2e",
    "test_refine3d_anneal": "e2e",
    "test_refine3d_band": "e2e",
    "test_coarse3d": "e2e",
    "test_realdata": "e2e",
    "test_scripts_smoke": "e2e",
    "test_security_experiments": "e2e",
    "test_simulate": "e2e",
    "test_tracker": "e2e",
    # live: the live system (HTTP server, database, receiver agents, browser)
    "test_demo_dashboard": "live",
    "test_server_api": "live",
    "test_server_dashboard": "live",
    "test_server_durability": "live",
    "test_server_live": "live",
    "test_server_live_lag": "live",
    "test_server_pose3d": "live",
    # lint: the code base's own checks
    "test_style": "lint",
}
"""Test module -> its tier (a pytest marker, registered in pyproject.toml). ``pytest -m
property`` runs one tier; ``slow`` is marked per test and left out by default. A new test
module gets its row here (``tests/test_style.py`` fails until it has one)."""


ACCURACY_RUNS: tuple[str, ...] = (
    "test_accuracy::",
    "test_filter::test_every_packet_answered_within_bounds",
    "test_filter::test_causal_variant_answers_every_packet",
    "test_filter::test_unknown_transmit_power_is_estimated",
    "test_filter::test_motion_model_matters",
    "test_filter::test_heard_outliers_do_not_throw_the_track",
    "test_filter_offset::test_plus_6_db_is_within_the_issue_bound_only_with_the_selection",
    "test_filter_smoother_jump::",
    "test_filter_reverse::test_reversed_pass_leaves_a_wrong_lock",
    "test_filter_refine2d::test_arbiter_leaves_the_wrong_lock",
    "test_filter_offset_refit::test_round7_leaves_the_wrong_lock",
    "test_filter_offset_profile::test_round8_",
    "test_filter_offset_grid::test_loud_",
    "test_filter_laplace::test_loud_",
    "test_filter_coarse_track::test_loud_",
    "test_filter_angular_noise::",
    "test_realdata::test_filter_settings_for_a_track_are_chosen_without_it",
    "test_realdata::test_real_position_error_bound",
    "test_pose3d::test_known_pose_recovered_noise_free",
    "test_reverse3d::test_the_reversed_pass_leaves_a_wrong_mode",
    "test_restart3d::test_a_restart_leaves_a_wrong_mode",
    "test_offline_particles3d::test_more_offline_particles_leave_a_wrong_mode",
)
"""``module::test-name prefixes`` of the end-to-end accuracy runs (an error bound measured
on seeded scenarios or the real tracks: the suite's slowest e2e tests). Marked
``accuracy``; they stay in the default suite (``pytest -m "not accuracy"`` leaves them out
for a quick run, ``pytest -m accuracy`` runs only them)."""


def _is_accuracy_run(item: pytest.Item) -> bool:
    key = f"{item.path.stem}::{item.name}"
    return any(key.startswith(p) for p in ACCURACY_RUNS)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test with its module's tier (:data:`TIERS`) and the accuracy runs
    (:data:`ACCURACY_RUNS`) with ``accuracy``."""
    for item in items:
        if _is_accuracy_run(item):
            item.add_marker(pytest.mark.accuracy)
        tier = TIERS.get(item.path.stem)
        if tier is not None:
            item.add_marker(getattr(pytest.mark, tier))


@pytest.fixture(scope="session", autouse=True)
def _disk_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The on-disk memo of the sites' scipy-computed arrays (radiopose.diskcache)
    in a directory of this session, not the user's cache."""
    os.environ.setdefault("RADIOPOSE_CACHE_DIR", str(tmp_path_factory.mktemp("radiopose-cache")))


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
