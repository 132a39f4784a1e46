"""``[filter.pose3d]`` of a site's ``tracker.toml``: the 3-D filter's settings
(:class:`~radiopose.filtering.particle3d.Pose3dConfig`), read, validated, written
back and applied (docs/pose3d.md, "Settings").

* every field written by :func:`write_tracker_toml` reads back as written
  (hypothesis over subsets of the fields and values in range);
* an unknown key, a value of the wrong type, a non-finite or out-of-range value
  is a one-line error naming the file, the line and the dotted key;
* ``radiopose locate`` and the streaming tracker at a 3-D site run the 3-D
  filter with the file's settings; a 2-D site ignores the table;
* a malformed table stops ``radiopose locate`` with that one line, no traceback.

Seed 18018 (a small 3-D scene) is used here only.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.filtering.config import MAX_LAG_S
from radiopose.filtering.particle3d import ParticleFilter3d, Pose3dConfig
from radiopose.packets import group_packets
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import Tracker, TrackerConfig
from radiopose.tracker_settings import (
    POSE3D_RANGES,
    TrackerSettings,
    apply_tracker_settings,
    load_site_settings,
    read_tracker_settings,
    read_tracker_toml,
    write_tracker_toml,
)

FIELDS = {f.name: type(f.default) for f in dataclasses.fields(Pose3dConfig)}


def _write(tmp: Path, body: str) -> Path:
    p = tmp / "tracker.toml"
    p.write_text(body, encoding="utf-8")
    return p


def test_the_ranges_name_fields_and_admit_the_defaults():
    """Every row of POSE3D_RANGES is a Pose3dConfig field whose default lies in its
    range (a field added later without a row is read as a positive number)."""
    assert set(POSE3D_RANGES) <= set(FIELDS)
    for name, (lo, hi) in POSE3D_RANGES.items():
        default = getattr(Pose3dConfig(), name)
        values = default if isinstance(default, tuple) else (default,)
        assert all(lo <= v <= hi for v in values), name


def test_a_field_without_a_row_is_read_as_a_positive_number(tmp_path: Path, monkeypatch):
    import radiopose.tracker_settings as ts

    monkeypatch.delitem(ts.POSE3D_RANGES, "acquisition_sigma_db")
    monkeypatch.delitem(ts.POSE3D_RANGES, "refine_steps")
    p = _write(tmp_path, "[filter.pose3d]\nacquisition_sigma_db = 2.5\nrefine_steps = 3\n")
    assert read_tracker_settings(p).pose3d_overrides == {
        "acquisition_sigma_db": 2.5,
        "refine_steps": 3,
    }
    p = _write(tmp_path, "[filter.pose3d]\nacquisition_sigma_db = 0.0\n")
    with pytest.raises(InputError, match="> 0"):
        read_tracker_settings(p)


def _value(name: str) -> st.SearchStrategy[float | int | tuple[float, ...]]:
    lo, hi = POSE3D_RANGES[name]
    if (
        FIELDS[name] is tuple
    ):  # the offset bank: a few distinct offsets (at most 5 of 2,000 particles)
        item = st.floats(lo, hi, allow_nan=False, allow_infinity=False)
        return st.lists(item, max_size=5, unique=True).map(tuple)
    if FIELDS[name] is int:
        return st.integers(int(lo), int(min(hi, 10**7)))
    return st.floats(lo, hi, exclude_min=True, allow_nan=False, allow_infinity=False)


@st.composite
def _overrides(draw: st.DrawFn) -> dict[str, float | int | tuple[float, ...]]:
    names = draw(st.lists(st.sampled_from(sorted(POSE3D_RANGES)), unique=True))
    out = {n: draw(_value(n)) for n in names}
    try:  # keys valid one by one can still clash (a small n_particles for a 5-member bank)
        replace(Pose3dConfig(), **out)
    except InputError:
        assume(False)
    return out


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(pose3d=_overrides(), lag=st.none() | st.floats(0.0, MAX_LAG_S))
def test_round_trip(
    tmp_path: Path, pose3d: dict[str, float | int | tuple[float, ...]], lag: float | None
):
    p = tmp_path / "tracker.toml"
    write_tracker_toml(p, {"huber_c": 1.5}, lag, "written by a test", pose3d=pose3d)
    s = read_tracker_settings(p)
    assert s.pose3d_overrides == pose3d
    assert s.filter_overrides == {"huber_c": 1.5} and s.smoothing_lag_s == lag
    assert read_tracker_toml(p) == ({"huber_c": 1.5}, lag)  # the 2-D reader's view
    assert s.pose3d() == replace(Pose3dConfig(), **pose3d)
    cfg = apply_tracker_settings(TrackerConfig(), s)
    assert cfg.pose3d == s.pose3d() and cfg.filter.huber_c == 1.5
    assert cfg.smoothing_lag_s == (TrackerConfig().smoothing_lag_s if lag is None else lag)


def test_no_table_no_change(tmp_path: Path):
    p = tmp_path / "tracker.toml"
    write_tracker_toml(p, {"huber_c": 1.0})
    assert "pose3d" not in p.read_text()
    s = read_tracker_settings(p)
    assert s == TrackerSettings({"huber_c": 1.0})
    assert apply_tracker_settings(TrackerConfig(), s).pose3d == Pose3dConfig()
    assert load_site_settings(tmp_path / "nowhere") == (TrackerSettings(), None)


def test_live_use_keeps_the_live_lag(tmp_path: Path):
    p = _write(tmp_path, "smoothing_lag_s = 5.0\n[filter.pose3d]\nrefine_steps = 2\n")
    s, path = load_site_settings(tmp_path)
    assert path == p
    live = apply_tracker_settings(TrackerConfig(), s, batch=False)
    assert live.smoothing_lag_s == TrackerConfig().smoothing_lag_s
    assert live.pose3d.refine_steps == 2


def test_writer_rejects_what_the_reader_would():
    with pytest.raises(ValueError, match="not a Pose3dConfig field"):
        write_tracker_toml("/dev/null", {}, pose3d={"huber_c": 1.0})
    with pytest.raises(ValueError, match="not finite"):
        write_tracker_toml("/dev/null", {}, pose3d={"height_noise_mps": math.inf})


BAD = [
    ("n_partciles = 100", 3, "n_partciles", "unknown key"),
    ('n_particles = "many"', 3, "n_particles", "expected an integer"),
    ("n_particles = 2.5", 3, "n_particles", "expected an integer"),
    ("n_particles = true", 3, "n_particles", "expected an integer"),
    ("n_particles = 5", 3, "n_particles", "out of range"),
    ("refine_steps = -1", 3, "refine_steps", "out of range"),
    ("acquisition_heights = 0", 3, "acquisition_heights", "out of range"),
    ("acquisition_tilts = 0", 3, "acquisition_tilts", "out of range"),
    ("max_table_entries = 999", 3, "max_table_entries", "out of range"),
    ("height_noise_mps = nan", 3, "height_noise_mps", "finite"),
    ("tilt_noise_dps = inf", 3, "tilt_noise_dps", "finite"),
    ("acquisition_step_m = 0.0", 3, "acquisition_step_m", "> 0"),
    ("sigma_floor_db = -0.5", 3, "sigma_floor_db", "> 0"),
    ("reentry_interval_s = 0", 3, "reentry_interval_s", "out of range [0.001, 3600]"),
    ("proposal_window_s = 1e9", 3, "proposal_window_s", "out of range"),
    ("acquisition_azimuth_step_deg = 400.0", 3, "acquisition_azimuth_step_deg", "out of range"),
    ('acquisition_sigma_db = "3"', 3, "acquisition_sigma_db", "expected a number"),
    ("tilt_noise_dps = [1.0]", 3, "tilt_noise_dps", "expected a number"),
    ('estimate = "median"', 3, "estimate", "expected one of"),
    ("estimate = 1", 3, "estimate", "expected a non-empty string"),
    ("heading_prior_deg = -1.0", 3, "heading_prior_deg", "out of range"),
    ("refine_tilt_accel_noise_dps2 = -1.0", 3, "refine_tilt_accel_noise_dps2", "out of range"),
    ("refine_height_accel_noise_mps2 = nan", 3, "refine_height_accel_noise_mps2", "finite"),
    ("refine_polish_starts = -1", 3, "refine_polish_starts", "out of range"),
    ("refine_polish_margin = -1.0", 3, "refine_polish_margin", "out of range"),
    ("refine_polish_margin = inf", 3, "refine_polish_margin", "finite"),
    ('refine_polish_margin = "10"', 3, "refine_polish_margin", "expected a number"),
    ("refine_polish_switch = -0.5", 3, "refine_polish_switch", "out of range"),
    ("offset_bank_db = 3.0", 3, "offset_bank_db", "write [3.0]"),
    ("offset_bank_db = [0.0, nan]", 3, "offset_bank_db", "item 1 is not a finite number"),
    ("offset_bank_db = [0.0, 99.0]", 3, "offset_bank_db", "out of range"),
]


def test_strings_lists_and_zero_where_zero_switches_off(tmp_path: Path):
    """The estimate (a choice), the offset bank (a list; empty: no bank) and the
    heading prior (0: off) are read with their types."""
    p = _write(
        tmp_path,
        '[filter.pose3d]\nestimate = "mode"\noffset_bank_db = []\nheading_prior_deg = 0\n',
    )
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.estimate == "mode" and cfg.offset_bank_db == () and cfg.heading_prior_deg == 0.0
    p = _write(tmp_path, "[filter.pose3d]\noffset_bank_db = [-4.5, 0, 4.5]\n")
    assert read_tracker_settings(p).pose3d().offset_bank_db == (-4.5, 0.0, 4.5)


@pytest.mark.parametrize(("line", "lineno", "key", "what"), BAD)
def test_bad_settings_are_one_line_errors(tmp_path: Path, line, lineno, key, what):
    p = _write(tmp_path, f"[filter]\n[filter.pose3d]\n{line}\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    msg = str(exc.value)
    assert "\n" not in msg
    assert exc.value.path == str(p) and exc.value.line == lineno
    assert exc.value.column == f"filter.pose3d.{key}"
    assert what in msg


_TOML_VALUES = (
    st.integers(-(2**70), 2**70).map(str)
    | st.floats(allow_nan=True, allow_infinity=True).map(
        lambda x: "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf") if math.isinf(x)
        else repr(x)
    )
    | st.booleans().map(lambda b: "true" if b else "false")
    | st.text(st.characters(codec="utf-8", exclude_characters='"\\'), max_size=8).map(
        lambda t: f'"{t}"'
    )
    | st.lists(st.integers(-5, 5), max_size=3).map(str)
)  # fmt: skip


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    key=st.sampled_from(sorted(FIELDS)) | st.from_regex(r"[a-z_]{1,12}", fullmatch=True),
    value=_TOML_VALUES,
)
def test_any_value_reads_or_is_a_one_line_error(tmp_path: Path, key: str, value: str):
    """Fuzz: whatever one key of the table holds, the reader accepts it (a value
    Pose3dConfig takes) or raises one InputError naming the file; nothing else."""
    p = _write(tmp_path, f"[filter.pose3d]\n{key} = {value}\n")
    try:
        s = read_tracker_settings(p)
    except InputError as exc:
        assert exc.path == str(p) and "\n" not in str(exc)
        return
    assert s.pose3d_overrides.keys() == {key}
    assert getattr(s.pose3d(), key) == s.pose3d_overrides[key]


def test_the_table_must_be_a_table(tmp_path: Path):
    p = _write(tmp_path, "[filter]\nhuber_c = 1.0\npose3d = 3\n")
    with pytest.raises(InputError, match="expected a table") as exc:
        read_tracker_settings(p)
    assert exc.value.line == 3 and exc.value.column == "filter.pose3d"


def test_the_dataclass_check_names_the_file_and_key(tmp_path: Path, monkeypatch):
    """Values inside the reader's ranges that Pose3dConfig rejects (its own checks run
    last) are an error naming the file and the key's line (session 27: it named the
    table's header line, though docs/pose3d.md promises the key's)."""
    import radiopose.tracker_settings as ts

    monkeypatch.setitem(ts.POSE3D_RANGES, "n_particles", (1, 10))
    p = _write(tmp_path, "# a comment\n[filter.pose3d]\nn_particles = 3\n")
    with pytest.raises(InputError, match="n_particles >= 10") as exc:
        read_tracker_settings(p)
    assert exc.value.line == 3 and exc.value.column == "filter.pose3d.n_particles"
    p = _write(tmp_path, "[filter.pose3d]\nrefine = true\nhand_height_m = [1.6, 0.8]\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    assert exc.value.line == 3 and exc.value.column == "filter.pose3d.hand_height_m", exc.value


# ----------------------------------------------------------------------------- applied
SCENE = HandheldConfig(
    size_m=6.0, step_m=0.5, n_receivers=6, duration_s=0.2, noise_db=0.5,
    min_receiver_spacing_m=2.0, survey_step_m=1.0,
)  # fmt: skip
SMALL_P3 = {"acquisition_step_m": 2.0, "acquisition_tilts": 2, "n_particles": 200}


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("scene3d")
    sim = simulate_handheld(SCENE, seed=18018)
    sim.write(root)
    return sim, root


def test_the_tracker_runs_the_3d_filter_with_the_settings(scene):
    sim, root = scene
    write_tracker_toml(root / "site" / "tracker.toml", {}, pose3d=SMALL_P3)
    s, _ = load_site_settings(root / "site")
    tr = Tracker(sim.site, "filter", apply_tracker_settings(TrackerConfig(), s))
    for o in group_packets(sim.packets)[:5]:
        tr.update(o)
    (dev,) = tr._devices.values()
    pf = dev.engine
    assert isinstance(pf, ParticleFilter3d)
    assert pf.pose3d == replace(Pose3dConfig(), **SMALL_P3)
    assert pf.config.n_particles == 200  # Pose3dConfig's replaces FilterConfig's
    (state,) = tr.states.values()
    members = state.bank or [state]  # the offset bank splits the particles over its members
    assert len(members) == len(Pose3dConfig().offset_bank_db)
    assert sum(m.particles.shape[0] for m in members) == 200
    # the coarse grid follows acquisition_step_m: 6 m at 2 m → 4 × 4 positions per height
    xy = np.unique(pf.model3d.coarse.positions_m[:, :2], axis=0)
    assert len(xy) == 16


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "radiopose", *args], capture_output=True, text=True, timeout=600
    )


def test_locate_reads_the_table_and_names_a_bad_key(scene, tmp_path: Path):
    _sim, root = scene
    toml = root / "site" / "tracker.toml"
    toml.write_text("[filter.pose3d]\nacquisition_step_m = 2.0\nacquisition_tilts = 0\n")
    r = _cli("locate", str(root / "site"), str(root / "packets.csv"), "-o", str(tmp_path / "e.csv"),
             "--method", "filter")  # fmt: skip
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "tracker.toml" in line and ":3" in line and "filter.pose3d.acquisition_tilts" in line
    assert "Traceback" not in r.stderr


def test_serve_names_a_bad_key_before_it_starts(scene, tmp_path: Path):
    _sim, root = scene
    site = tmp_path / "site"
    site.mkdir()
    for f in (root / "site").rglob("*"):
        if f.is_file() and f.name != "tracker.toml":
            dest = site / f.relative_to(root / "site")
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(f.read_bytes())
    (site / "tracker.toml").write_text('[filter.pose3d]\nheight_noise_mps = "fast"\n')
    r = _cli("serve", str(site), "--db", f"sqlite:///{tmp_path / 'x.db'}", "--port", "1")
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "tracker.toml:2" in line and "filter.pose3d.height_noise_mps" in line
    assert not (tmp_path / "x.db").exists()  # stopped before opening the database


def test_the_refinement_prior_reads_with_zero_for_off(tmp_path: Path):
    """The refinement's constant-rate densities read from ``[filter.pose3d]``;
    0 (the random walks) is a value."""
    p = _write(
        tmp_path,
        "[filter.pose3d]\nrefine_tilt_accel_noise_dps2 = 250.0\n"
        "refine_height_accel_noise_mps2 = 0.0\n",
    )
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine_tilt_accel_noise_dps2 == 250.0
    assert cfg.refine_height_accel_noise_mps2 == 0.0
    p = _write(
        tmp_path,
        "[filter.pose3d]\nrefine_polish_margin = 0\nrefine_polish_starts = 3\n"
        "refine_polish_switch = 0\n",
    )
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine_polish_margin == 0.0 and cfg.refine_polish_starts == 3
    assert cfg.refine_polish_switch == 0.0


def test_refine_is_a_boolean(tmp_path: Path):
    """``refine`` (the offline batch refinement, on by default) reads as a boolean
    and round-trips; a number there is a one-line error naming the key."""
    assert Pose3dConfig().refine is True
    p = _write(tmp_path, "[filter.pose3d]\nrefine = false\nrefine_max_nfev = 20\n")
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine is False and cfg.refine_max_nfev == 20
    q = tmp_path / "written.toml"
    write_tracker_toml(q, {}, None, "written by a test", pose3d={"refine": False})
    assert read_tracker_settings(q).pose3d().refine is False
    p = _write(tmp_path, "[filter.pose3d]\nrefine = 1\n")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    assert exc.value.column == "filter.pose3d.refine" and "\n" not in str(exc.value)


def test_the_coarse_path_keys_read_and_bad_ones_are_one_line_errors(tmp_path: Path):
    """``refine_coarse_path`` (a boolean), its walk and its number of paths read
    from ``[filter.pose3d]``; 9 paths and a zero walk are one-line errors
    naming the key."""
    p = _write(
        tmp_path,
        "[filter.pose3d]\nrefine_coarse_path = true\nrefine_coarse_paths = 3\n"
        "refine_coarse_walk_m = 0.5\nrefine_coarse_walk_deg = 12.0\n",
    )
    cfg = read_tracker_settings(p).pose3d()
    assert cfg.refine_coarse_path is True and cfg.refine_coarse_paths == 3
    assert (cfg.refine_coarse_walk_m, cfg.refine_coarse_walk_deg) == (0.5, 12.0)
    for line, key in (("refine_coarse_paths = 9", "refine_coarse_paths"),
                      ("refine_coarse_walk_m = 0.0", "refine_coarse_walk_m")):  # fmt: skip
        p = _write(tmp_path, f"[filter.pose3d]\n{line}\n")
        with pytest.raises(InputError) as exc:
            read_tracker_settings(p)
        assert exc.value.column == f"filter.pose3d.{key}" and "\n" not in str(exc.value)


def test_locate_notes_that_the_papers_methods_search_the_3d_grid(scene, tmp_path: Path):
    """At a 3-D site the paper's top-k methods score every candidate per packet:
    ``locate`` says so once on stderr and names ``--method filter``; ``lms``
    (no candidate search) and ``filter`` get no note."""
    import shutil

    _sim, root = scene
    site = tmp_path / "site"
    shutil.copytree(root / "site", site, ignore=shutil.ignore_patterns("tracker.toml"))
    lines = (root / "packets.csv").read_text().splitlines()
    first = {ln.split(",")[0] for ln in lines[1:]}
    keep = sorted(first, key=int)[:2]
    packets = tmp_path / "packets.csv"
    packets.write_text("\n".join([lines[0], *(ln for ln in lines[1:] if ln.split(",")[0] in keep)]))
    for method, noted in (("orientation", True), ("lms", False)):
        r = _cli("locate", str(site), str(packets), "-o", str(tmp_path / "e.csv"), "-q",
                 "--method", method)  # fmt: skip
        assert r.returncode == 0, r.stderr
        notes = [ln for ln in r.stderr.splitlines() if ln.startswith("note:")]
        assert len(notes) == noted, r.stderr
        if noted:
            assert "3-D site" in notes[0] and "--method filter" in notes[0]


def test_devices_of_one_pattern_and_power_share_the_3d_model(scene):
    """At a 3-D site the filter's arrays (height maps, coarse acquisition table)
    are built once per pattern, power and settings among a tracker's devices;
    each device's estimates are those of a tracker that saw only that device,
    and a device with another power builds its own."""
    sim, _root = scene
    d0 = sim.site.devices[0]
    devs = (
        replace(d0, transmitter="aa:00:00:00:00:01"),
        replace(d0, transmitter="aa:00:00:00:00:02"),
        replace(d0, transmitter="aa:00:00:00:00:03", tx_power_dbm=d0.tx_power_dbm - 4.0),
    )
    site = replace(sim.site, devices=devs)
    cfg = replace(TrackerConfig(), pose3d=replace(Pose3dConfig(), **SMALL_P3))
    obs = group_packets(sim.packets)[:12]
    own = [replace(o, transmitter=d.transmitter, packet_id=f"{i}-{o.packet_id}")
           for o in obs for i, d in enumerate(devs)]  # fmt: skip
    together = Tracker(site, "filter", cfg)
    out = [together.update(o)[0] for o in own]
    assert sum(e is not None for e in out) >= 30
    a, b, c = (together.device(d.transmitter).engine for d in devs)
    assert b.model3d.coarse is a.model3d.coarse and b.model3d.maps_db is a.model3d.maps_db
    assert b.model3d.space.transmitter == devs[1].transmitter
    assert c.model3d.coarse is not a.model3d.coarse
    for d in devs:
        alone = Tracker(site, "filter", cfg)
        expect = [alone.update(o)[0] for o in own if o.transmitter == d.transmitter]
        got = [e for o, e in zip(own, out, strict=True) if o.transmitter == d.transmitter]
        assert [e is None for e in got] == [e is None for e in expect]
        for g, e in zip(got, expect, strict=True):
            if e is not None:
                assert g.position_m == e.position_m and g.orientation_deg == e.orientation_deg
