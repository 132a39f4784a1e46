"""Sites and survey maps built in Python are checked like site directories: bad
parts give a one-line :class:`InputError` naming the argument, receiver, row or
key (``load_site``'s own checks, one set), never a deep numpy/scipy traceback,
a silently wrong map or data written outside the site directory."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radiopose.errors import InputError
from radiopose.site import AreaGrid, Device, Receiver, SurveyConfig, SurveyRows
from radiopose.site_io import assemble_site, load_site, write_site
from radiopose.survey import (
    SurveyPoints,
    average_by_point,
    build_survey_map,
    interpolate_points,
)


def _one_line(err: pytest.ExceptionInfo[InputError]) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


@pytest.fixture(scope="module")
def sim():
    from radiopose.simulate import ScenarioConfig, simulate

    cfg = ScenarioConfig(
        size_m=6.0, step_m=0.5, duration_s=0.05, noise_db=0.5, min_receiver_spacing_m=2.0
    )
    return simulate(cfg, seed=4321)


@pytest.fixture(scope="module")
def sim3d():
    from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

    cfg = HandheldConfig(
        size_m=6.0, step_m=0.5, n_receivers=6, duration_s=0.2, noise_db=0.5,
        min_receiver_spacing_m=2.0, survey_step_m=1.0,
    )  # fmt: skip
    return simulate_handheld(cfg, seed=18018)


def _parts(site) -> dict:
    return {
        "name": site.name,
        "area": site.area,
        "orientations": site.orientations,
        "survey_config": site.survey_config,
        "receivers": site.receivers,
        "devices": site.devices,
        "patterns": site.patterns,
        "survey_rows": site.survey_rows,
    }


def _assemble(site, **changes):
    return assemble_site(**{**_parts(site), **changes})


def _rows(rows: SurveyRows, **changes) -> SurveyRows:
    arrays = {
        "xyz_m": rows.xyz_m.copy(),
        "receiver_id": rows.receiver_id.copy(),
        "rss_dbm": rows.rss_dbm.copy(),
        "orientation_deg": rows.orientation_deg.copy(),
    }
    arrays.update(changes)
    return SurveyRows(**arrays)


# ------------------------------------------------------------- 1. surveyed heights (3-D)
def _add_height(rows: SurveyRows, z: float, skip: str) -> SurveyRows:
    """The survey plus a copy of it at height ``z`` for every receiver but ``skip``."""
    keep = rows.receiver_id != skip
    xyz = rows.xyz_m[keep].copy()
    xyz[:, 2] = z
    return SurveyRows(
        np.concatenate([rows.xyz_m, xyz]),
        np.concatenate([rows.receiver_id, rows.receiver_id[keep]]),
        np.concatenate([rows.rss_dbm, rows.rss_dbm[keep]]),
        np.concatenate([rows.orientation_deg, rows.orientation_deg[keep]]),
    )


def test_a_3d_survey_height_without_rows_for_a_receiver_is_refused_on_load(sim3d, tmp_path):
    sim3d.write(tmp_path)
    survey = tmp_path / "site" / "survey.csv"
    with open(survey, newline="") as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], rows[1:]
    z, rid = header.index("z_m"), header.index("receiver_id")
    last = sim3d.site.receiver_ids[-1]
    extra = [[*r[:z], "2.5", *r[z + 1 :]] for r in data if r[rid] != last]
    with open(survey, "a", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(extra)
    with pytest.raises(InputError) as err:
        load_site(tmp_path / "site")
    text = _one_line(err)
    assert f"survey.csv:{len(data) + 2}, column 'z_m'" in text
    assert f"receiver {last!r} has no survey rows at the surveyed height 2.5 m" in text


def test_a_3d_survey_height_without_rows_for_a_receiver_is_refused_in_python(sim3d):
    site = sim3d.site
    last = site.receiver_ids[-1]
    rows = _add_height(site.survey_rows, 2.5, last)
    with pytest.raises(InputError) as err:
        _assemble(site, survey_rows=rows)
    assert f"assemble_site: survey_rows.z_m[{len(site.survey_rows.rss_dbm)}]" in _one_line(err)
    # a Site built around the checks: the height model names the gap (was an IndexError)
    from radiopose.survey_height import build_height_model

    with pytest.raises(InputError, match=f"receiver {last!r} has no survey rows at surveyed"):
        build_height_model(replace(site, survey_rows=rows))


def test_a_complete_second_height_still_builds_a_height_model(sim3d):
    from radiopose.survey_height import build_height_model

    site = sim3d.site
    rows = _add_height(site.survey_rows, 2.5, skip="")
    model = build_height_model(_assemble(site, survey_rows=rows))
    np.testing.assert_array_equal(model.layers_z_m, [1.2, 2.5])


def test_a_2d_site_ignores_survey_heights(sim):
    """The rule is the 3-D height model's: a 2-D site's survey map ignores heights."""
    site = sim.site
    rows = _add_height(site.survey_rows, site.area.z_m + 1.0, site.receiver_ids[0])
    assert _assemble(site, survey_rows=rows).survey_map.m_db.shape[0] == len(site.receivers)


# ------------------------------------------------------------- 2./3. assemble_site checks
def _bad_parts(site) -> list:
    rx, rows, area, cfg, dev = (
        site.receivers, site.survey_rows, site.area, site.survey_config, site.devices
    )  # fmt: skip
    unknown_rx = rows.receiver_id.copy()
    unknown_rx[3] = "rxZ"
    nan_x = rows.xyz_m.copy()
    nan_x[5, 0] = math.nan
    nan_rss = rows.rss_dbm.copy()
    nan_rss[7] = math.nan
    only_rx1 = rows.receiver_id != rx[-1].receiver_id
    return [
        ({"receivers": ()}, "assemble_site: receivers: no receivers"),
        ({"survey_rows": _rows(rows, receiver_id=unknown_rx)},
         r"survey_rows.receiver_id\[3\]: unknown receiver 'rxZ' \(not in receivers\)"),
        ({"survey_rows": SurveyRows(rows.xyz_m[only_rx1], rows.receiver_id[only_rx1],
                                    rows.rss_dbm[only_rx1], rows.orientation_deg[only_rx1])},
         rf"receivers\[{len(rx) - 1}\].receiver_id: receiver '{rx[-1].receiver_id}' has no "
         "survey rows in survey_rows"),
        ({"area": replace(area, step_m=0.0)}, r"area.step_m: must be > 0, got 0"),
        ({"area": replace(area, x_max_m=math.nan)}, "area.x_max_m: expected a finite number"),
        ({"survey_config": replace(cfg, pattern="nope")},
         r"survey_config.pattern: unknown pattern 'nope' \(not in patterns\)"),
        ({"survey_rows": _rows(rows, xyz_m=nan_x)},
         r"survey_rows.x_m\[5\]: not a finite number: nan"),
        ({"area": replace(area, x_min_m=area.x_max_m + 1.0)}, "area.x_max_m: must be >= x_min_m"),
        ({"area": replace(area, x_max_m=area.x_max_m - 0.1)},
         "area.step_m: the x span .* must be a whole number of steps"),
        ({"receivers": (*rx, rx[0])},
         rf"receivers\[{len(rx)}\].receiver_id: duplicate receiver id '{rx[0].receiver_id}'"),
        ({"survey_rows": _rows(rows, rss_dbm=nan_rss)},
         r"survey_rows.rss_dbm\[7\]: not a finite number: nan"),
        ({"survey_config": replace(cfg, tx_power_dbm=math.nan)},
         "survey_config.tx_power_dbm: expected a finite number, got nan"),
        ({"devices": (replace(dev[0], tx_power_dbm=math.nan),)},
         r"devices\[0\].tx_power_dbm: not a finite number: nan"),
        ({"receivers": (replace(rx[0], y_m=math.nan), *rx[1:])},
         r"receivers\[0\].y_m: not a finite number: nan"),
        ({"survey_config": replace(cfg, interpolation="nearest")},
         "survey_config.interpolation: expected one of cubic, linear, got 'nearest'"),
        ({"receivers": (replace(rx[0], pattern="../x"), *rx[1:])},
         r"receivers\[0\].pattern: pattern name '../x' is not a plain file name"),
        ({"area": replace(area, z_min_m=0.0)}, "area.z_max_m: missing: a height range needs"),
        ({"devices": (dev[0], replace(dev[0], transmitter=dev[0].transmitter.upper()))},
         r"devices\[1\].transmitter: duplicate transmitter"),
        ({"survey_rows": _rows(rows, xyz_m=rows.xyz_m[:, :2])}, "survey_rows: shapes xyz_m"),
    ]  # fmt: skip


@pytest.mark.parametrize("case", range(19))
def test_assemble_site_refuses_bad_parts_in_one_line(sim, case):
    cases = _bad_parts(sim.site)
    assert len(cases) == 19
    changes, message = cases[case]
    with pytest.raises(InputError, match=message) as err:
        _assemble(sim.site, **changes)
    assert _one_line(err).startswith("assemble_site: ")


def test_assemble_site_keeps_a_valid_site_exactly(sim):
    again = _assemble(sim.site)
    np.testing.assert_array_equal(again.survey_map.m_db, sim.site.survey_map.m_db)


_COLUMNS = {"x_m": 0, "y_m": 1, "z_m": 2, "rss_dbm": None}


@settings(max_examples=25, deadline=None)
@given(
    column=st.sampled_from(sorted(_COLUMNS)),
    frac=st.floats(0.0, 1.0, exclude_max=True),
    bad=st.sampled_from([math.nan, math.inf, -math.inf, 1e7, -1e7]),
)
def test_any_bad_survey_value_is_named_by_row_and_column(sim, column, frac, bad):
    rows = sim.site.survey_rows
    i = int(frac * rows.rss_dbm.size)
    if column == "rss_dbm":
        rss = rows.rss_dbm.copy()
        rss[i] = bad
        changed = _rows(rows, rss_dbm=rss)
    else:
        xyz = rows.xyz_m.copy()
        xyz[i, _COLUMNS[column]] = bad
        changed = _rows(rows, xyz_m=xyz)
    with pytest.raises(InputError) as err:
        _assemble(sim.site, survey_rows=changed)
    assert f"assemble_site: survey_rows.{column}[{i}]: " in _one_line(err)


# ------------------------------------------------------------- 4. write_site
def test_write_site_refuses_a_pattern_name_outside_the_directory_before_writing(sim, tmp_path):
    site = sim.site
    pats = dict(site.patterns)
    pats["../../escaped"] = pats[site.devices[0].pattern]
    bad = replace(site, patterns=pats)
    target = tmp_path / "a" / "b" / "site"
    with pytest.raises(InputError, match=r"write_site: site\.patterns: pattern name") as err:
        write_site(bad, target)
    _one_line(err)
    assert not any(tmp_path.rglob("*.csv")) and not any(tmp_path.rglob("*.toml"))


def test_write_site_still_writes_a_valid_site(sim, tmp_path):
    write_site(sim.site, tmp_path / "site")
    assert load_site(tmp_path / "site").receiver_ids == sim.site.receiver_ids


# ------------------------------------------------------------- 5. survey functions
def _grid_points(values=None) -> SurveyPoints:
    gx, gy = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    m = np.sin(xy[:, 0]) + xy[:, 1] if values is None else values
    return SurveyPoints(xy, np.asarray(m, float), np.ones(len(xy), np.int64))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda p: interpolate_points(p, [[math.nan, 1.0]]), r"query_xy_m\[0\] .* is not finite"),
        (lambda p: interpolate_points(
            SurveyPoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)), [[1.0, 1.0]]),
         "points: no survey points"),
        (lambda p: build_survey_map([], [], np.arange(3.0), np.arange(3.0)), "no receivers"),
        (lambda p: average_by_point([[0.0, 0.0], [1.0, 1.0]], [1.0]), "shapes"),
        (lambda p: interpolate_points(p, [[1.0, 1.0]], method="nearest"),
         "method must be one of cubic, linear, got 'nearest'"),
        (lambda p: interpolate_points(p, [[1.0, 1.0]], outside="clamp"),
         "outside must be one of nearest, exclude, got 'clamp'"),
        (lambda p: build_survey_map(["rx1", "rx2"], [p], np.arange(3.0), np.arange(3.0)),
         r"2 receiver id\(s\) but 1 set\(s\) of survey points"),
        (lambda p: build_survey_map(["rx1", "rx1"], [p, p], np.arange(3.0), np.arange(3.0)),
         r"receiver_ids\[1\] = 'rx1' is repeated"),
        (lambda p: average_by_point([[0.0, math.nan]], [1.0]), r"xy_m\[0\] .* is not finite"),
        (lambda p: build_survey_map(["rx1"], [p], np.array([0.0, math.nan]), np.arange(3.0)),
         "x_m must be a non-empty 1-D array of finite numbers"),
    ],
)  # fmt: skip
def test_survey_functions_refuse_bad_input_in_one_line(call, message):
    with pytest.raises(InputError, match=message) as err:
        call(_grid_points())
    _one_line(err)


@settings(max_examples=30, deadline=None)
@given(
    index=st.integers(0, 24),
    bad=st.sampled_from([math.nan, math.inf, -math.inf]),
    method=st.sampled_from(["cubic", "linear"]),
    outside=st.sampled_from(["nearest", "exclude"]),
)
def test_one_non_finite_survey_value_is_refused_not_spread(index, bad, method, outside):
    """Was: the whole cubic map silently fell back to nearest neighbour (or NaN)."""
    m = np.sin(np.arange(25.0))
    m[index] = bad
    q = np.array([[1.5, 2.5], [3.2, 0.4]])
    with pytest.raises(InputError, match=rf"m_db\[{index}\] = .* is not finite"):
        interpolate_points(_grid_points(m), q, method, outside)
    with pytest.raises(InputError, match=rf"points\[0\] \(receiver 'rx1'\): m_db\[{index}\]"):
        build_survey_map(["rx1"], [_grid_points(m)], np.arange(3.0), np.arange(3.0), method)


def test_valid_survey_interpolation_is_unchanged():
    p = _grid_points()
    out = interpolate_points(p, p.xy_m)
    np.testing.assert_allclose(out, p.m_db, atol=1e-9)


# ------------------------------------------------------------- 6. HeightModel.channel_db
def test_channel_db_refuses_a_non_finite_point(sim3d):
    from radiopose.survey_height import build_height_model

    model = build_height_model(sim3d.site)
    with pytest.raises(InputError, match=r"channel_db: point xyz_m\[1\] .* is not finite") as err:
        model.channel_db([[1.0, 1.0, 1.0], [math.nan, 1.0, 1.0]])
    _one_line(err)
    assert np.isfinite(model.channel_db([[1.0, 1.0, 1.0]])).all()


# ------------------------------------------------------------- 7. lookups
def test_lookups_name_what_is_missing(sim):
    site = sim.site
    with pytest.raises(InputError, match="transmitter must be text, got int 123"):
        site.device(123)  # type: ignore[arg-type]
    tx = site.devices[0].transmitter
    no_pattern = replace(site, patterns={})
    with pytest.raises(InputError, match=f"device {tx!r} names pattern .* does not hold"):
        no_pattern.device_pattern(tx)
    with pytest.raises(InputError, match="unknown receiver 'zz': the survey map holds 'rx1'"):
        site.survey_map.receiver_index("zz")
    assert site.survey_map.receiver_index(site.receiver_ids[-1]) == len(site.receivers) - 1
    with pytest.raises(InputError, match="load_site: the site directory must be a path, got int"):
        load_site(5)  # type: ignore[arg-type]


def test_the_parts_types_are_checked(sim):
    site = sim.site
    for changes, message in [
        ({"area": (0, 1)}, "assemble_site: area: expected an AreaGrid, got tuple"),
        ({"receivers": ("rx1",)}, r"assemble_site: receivers\[0\]: expected a Receiver"),
        ({"patterns": {"iso": 3}}, "assemble_site: patterns: 'iso': expected a Pattern"),
    ]:
        with pytest.raises(InputError, match=message):
            _assemble(site, **changes)
    r0 = site.receivers[0]
    assert isinstance(r0, Receiver) and isinstance(site.devices[0], Device)
    assert isinstance(site.area, AreaGrid) and isinstance(site.survey_config, SurveyConfig)


def test_load_site_accepts_path_like(sim, tmp_path):
    write_site(sim.site, tmp_path / "s")
    assert load_site(str(tmp_path / "s")).name == load_site(Path(tmp_path / "s")).name
