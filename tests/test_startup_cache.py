"""The on-disk memo of a site's scipy-computed arrays (:mod:`radiopose.diskcache`):
the same numbers as computing them, recomputed when damaged or turned off, and a
second ``radiopose locate`` on a site that needs no scipy import for them.

Seed 4330 is used here only.
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from radiopose import diskcache
from radiopose.geometry import orientation_matrices, stored_orientation_matrices
from radiopose.packets import write_packets_csv
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.site import write_site
from radiopose.site_io import load_site

REPO = Path(__file__).resolve().parents[1]


def test_memo_computes_once_and_reads_back_the_same_bytes(tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(tmp_path))
    calls = []
    x = np.linspace(-3.0, 7.0, 11)

    def compute():
        calls.append(1)
        return {"y": np.sin(x) / 3.0, "n": np.arange(4)}

    first = diskcache.memo_arrays("unit", (x, "cubic"), compute)
    again = diskcache.memo_arrays("unit", (x, "cubic"), compute)
    assert len(calls) == 1
    for k in ("y", "n"):
        assert again[k].dtype == first[k].dtype
        assert again[k].tobytes() == first[k].tobytes()
    # any input that differs (a value, one bit of an array) is another entry
    diskcache.memo_arrays("unit", (x, "linear"), compute)
    diskcache.memo_arrays("unit", (np.nextafter(x, 10.0), "cubic"), compute)
    assert len(calls) == 3


def test_memo_recomputes_a_damaged_entry_and_can_be_turned_off(tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return {"y": np.full(3, 2.5)}

    diskcache.memo_arrays("unit", (1,), compute)
    (entry,) = tmp_path.glob("unit-*.npz")
    whole = entry.read_bytes()
    for damaged in (b"not a zip file", whole[: len(whole) // 2], b""):
        entry.write_bytes(damaged)
        np.testing.assert_array_equal(diskcache.memo_arrays("unit", (1,), compute)["y"], 2.5)
    assert len(calls) == 4
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", "")
    assert diskcache.cache_dir() is None
    diskcache.memo_arrays("unit", (1,), compute)
    diskcache.memo_arrays("unit", (1,), compute)
    assert len(calls) == 6


def test_key_follows_the_computing_modules_source():
    survey = diskcache.cache_key("unit", (1,), "radiopose.survey")
    assert survey == diskcache.cache_key("unit", (1,), "radiopose.survey")
    assert survey != diskcache.cache_key("unit", (1,), "radiopose.geometry")
    assert survey != diskcache.cache_key("unit", (2,), "radiopose.survey")


def test_memo_runs_without_a_writable_directory(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(blocker / "cache"))  # cannot be made
    out = diskcache.memo_arrays("unit", (2,), lambda: {"y": np.ones(2)})
    np.testing.assert_array_equal(out["y"], 1.0)


def test_stored_orientation_matrices_equal_scipys(tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(tmp_path))
    rng = np.random.default_rng(4330)
    o = np.column_stack(
        [rng.uniform(0, 360, 50), rng.uniform(-60, 60, 50), rng.uniform(0, 360, 50)]
    )
    want = orientation_matrices(*o.T)
    for _ in range(2):  # computed, then read back
        got = stored_orientation_matrices(o)
        assert got.tobytes() == want.tobytes()


@pytest.fixture(scope="module")
def site_files(tmp_path_factory):
    cfg = ScenarioConfig(
        size_m=6.0, step_m=0.25, duration_s=0.1, min_receiver_spacing_m=2.0, noise_db=1.0
    )
    sim = simulate(replace(cfg), seed=4330)
    root = tmp_path_factory.mktemp("startup")
    write_site(sim.site, root / "site")
    write_packets_csv(sim.packets, root / "packets.csv")
    return root


def test_site_loaded_through_the_cache_equals_the_computed_one(site_files, tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", "")
    want = load_site(site_files / "site").survey_map.m_db
    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(tmp_path))
    for _ in range(2):  # computed and stored, then read back
        got = load_site(site_files / "site").survey_map.m_db
        assert got.tobytes() == want.tobytes()
        assert not got.flags.writeable
    assert {p.name.split("-")[0] for p in tmp_path.glob("*.npz")} >= {"survey", "hull"}


_PROBE = """
import sys
from radiopose.cli import main
rc = main(sys.argv[1:])
# scipy.ndimage: only the 3-D refinement's pre-smoothing needs it (≈ 0.07 s)
heavy = sorted(
    m for m in ("scipy.interpolate", "scipy.spatial", "scipy.ndimage") if m in sys.modules
)
print("HEAVY", ",".join(heavy) or "-")
sys.exit(rc)
"""


def test_second_locate_imports_no_scipy_interpolate_or_spatial(site_files, tmp_path):
    env = {**os.environ, "RADIOPOSE_CACHE_DIR": str(tmp_path / "cache")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), env.get("PYTHONPATH", "")])
    args = [str(site_files / "site"), str(site_files / "packets.csv")]
    seen = []
    for i in range(2):
        out = tmp_path / f"est{i}.csv"
        res = subprocess.run(
            [sys.executable, "-c", _PROBE, "locate", *args, "-o", str(out), "--method", "filter"],
            capture_output=True,
            text=True,
            env=env,
            check=False,
        )
        assert res.returncode == 0, res.stderr
        seen.append(res.stdout.split("HEAVY")[-1].strip())
    assert seen[0] != "-"  # the first run computed the survey map with scipy
    assert seen[1] == "-"  # the second read it back
    assert (tmp_path / "est0.csv").read_bytes() == (tmp_path / "est1.csv").read_bytes()


def test_locate_keeps_its_start_up_objects_out_of_full_collections(
    site_files, tmp_path, monkeypatch
):
    """``radiopose locate`` freezes the objects made by its imports for the run
    (docs/performance.md, "Ninth pass") and unfreezes them when it ends; the
    same estimates without it. A host process that froze its own objects is
    left alone."""
    import gc

    from radiopose.cli import main

    monkeypatch.setenv("RADIOPOSE_CACHE_DIR", str(tmp_path / "cache"))
    args = [str(site_files / "site"), str(site_files / "packets.csv"), "--method", "filter"]
    counts: list[int] = []
    real_freeze = gc.freeze

    def freeze() -> None:
        real_freeze()
        counts.append(gc.get_freeze_count())

    monkeypatch.setattr(gc, "freeze", freeze)
    assert gc.get_freeze_count() == 0
    assert main(["locate", *args, "-o", str(tmp_path / "a.csv"), "--quiet"]) == 0
    assert len(counts) == 1 and counts[0] > 10_000  # the imported modules' objects
    assert gc.get_freeze_count() == 0  # unfrozen when the run ended
    monkeypatch.setattr(gc, "freeze", lambda: counts.append(-1))  # without it
    assert main(["locate", *args, "-o", str(tmp_path / "b.csv"), "--quiet"]) == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    # a host's own freeze: locate neither freezes more nor unfreezes it
    real_freeze()
    try:
        held = gc.get_freeze_count()
        assert main(["locate", *args, "-o", str(tmp_path / "c.csv"), "--quiet"]) == 0
        assert gc.get_freeze_count() > held // 2  # not unfrozen (a few freed meanwhile)
        assert counts == [counts[0], -1]  # nor frozen again
    finally:
        gc.unfreeze()
