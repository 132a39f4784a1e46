"""3-D pose site keys: the ``[area]`` height range and pitch/roll lists (docs/pose3d.md).

The small site (conftest ``small_site_dir``) writes site.toml with line 8 ``z_m = 1.0``,
line 13 ``pitch_deg``, line 14 ``roll_deg``.
"""

from pathlib import Path

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.site import load_site, site_is_3d, write_site

RANGE = "z_min_m = 0.8\nz_max_m = 1.6\nz_step_m = 0.2"


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def load_error(site_dir: Path) -> InputError:
    with pytest.raises(InputError) as exc:
        load_site(site_dir)
    assert "\n" not in str(exc.value)
    return exc.value


def test_height_range_loads_and_round_trips(small_site_dir, tmp_path):
    edit(small_site_dir / "site.toml", "z_m = 1.0", RANGE)
    site = load_site(small_site_dir)
    np.testing.assert_allclose(site.area.z_levels_m(), [0.8, 1.0, 1.2, 1.4, 1.6])
    assert site.area.z_m == pytest.approx(1.2)  # the middle level: where 2-D methods search
    assert site_is_3d(site)
    write_site(site, tmp_path / "copy")
    text = (tmp_path / "copy" / "site.toml").read_text()
    assert "z_min_m = 0.8" in text and "z_m =" not in text
    again = load_site(tmp_path / "copy")
    assert again.area == site.area


def test_two_d_site_unchanged(small_site_dir):
    site = load_site(small_site_dir)
    assert not site.area.has_height_range
    np.testing.assert_array_equal(site.area.z_levels_m(), [site.area.z_m])
    assert not site_is_3d(site)


def test_pitch_list_makes_a_site_3d(small_site_dir):
    edit(small_site_dir / "site.toml", "pitch_deg = [0.0]", "pitch_deg = [20.0, 45.0, 70.0]")
    assert site_is_3d(load_site(small_site_dir))


@pytest.mark.parametrize(
    ("old", "new", "key", "what"),
    [
        ("z_m = 1.0", "z_m = 1.0\n" + RANGE, "area.z_min_m", "not both"),
        ("z_m = 1.0", "z_min_m = 0.8\nz_max_m = 1.6", "area.z_step_m", "missing"),
        ("z_m = 1.0", "z_max_m = 1.6\nz_step_m = 0.2", "area.z_min_m", "missing"),
        # a misspelt key is named at its own line, not as the key it misses (session 27)
        ("z_m = 1.0", RANGE.replace("z_step_m", "z_stepm"), "area.z_stepm", "did you mean"),
        ("z_m = 1.0", "z_m = 1.0\nz_mm = 2.0", "area.z_mm", "unknown key"),
        ("z_m = 1.0", RANGE.replace("z_max_m = 1.6", "z_max_m = 0.5"), "area.z_max_m", ">= z_min"),
        ("z_m = 1.0", RANGE.replace("0.2", "0.0"), "area.z_step_m", "must be > 0"),
        ("z_m = 1.0", RANGE.replace("0.2", "-0.2"), "area.z_step_m", "must be > 0"),
        ("z_m = 1.0", RANGE.replace("0.2", "0.3"), "area.z_step_m", "whole number"),
        ("z_m = 1.0", RANGE.replace("0.2", "1e-6"), "area.z_step_m", "more than 1000"),
        ("z_m = 1.0", RANGE.replace("0.8", '"low"'), "area.z_min_m", "expected a number"),
        ("z_m = 1.0", RANGE.replace("1.6", "inf"), "area.z_max_m", "finite"),
        ("pitch_deg = [0.0]", "pitch_deg = [20.0, 95.0]", "orientations.pitch_deg", "range"),
        ("pitch_deg = [0.0]", "pitch_deg = [-90.5]", "orientations.pitch_deg", "range"),
        ("pitch_deg = [0.0]", "pitch_deg = [30.0, 30.0]", "orientations.pitch_deg", "distinct"),
        ("roll_deg = [0.0]", "roll_deg = [-180.0, 180.0]", "orientations.roll_deg", "modulo 360"),
        ("roll_deg = [0.0]", "roll_deg = [10.0, 370.0]", "orientations.roll_deg", "range"),
        ("roll_deg = [0.0]", 'roll_deg = ["x"]', "orientations.roll_deg", "item 0"),
    ],
)
def test_malformed_height_pitch_roll_is_one_line_error(small_site_dir, old, new, key, what):
    edit(small_site_dir / "site.toml", old, new)
    err = load_error(small_site_dir)
    assert Path(err.path).name == "site.toml"
    assert err.column == key, str(err)
    assert what in err.reason, str(err)
