"""Experiment TOML files: the shipped five, seeds, and one-line errors naming the key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from radiopose.cli import main
from radiopose.errors import InputError
from radiopose.evaluate.experiments import (
    SHIPPED,
    SHIPPED_BEYOND,
    load_experiment,
    parse_experiment,
)
from radiopose.evaluate.runner import plan, run_seed
from radiopose.tracker import PAPER_METHODS

BASE = """
name = "tiny"
seed = 4711
runs = 2
methods = ["full", "top", "lms"]
[scenario]
size_m = 6.0
step_m = 0.5
duration_s = 0.05
[sweep]
scenario.noise_db = [0.5, 3.0]
[quick]
runs = 1
sweep.scenario.noise_db = [0.5]
[[figure]]
kind = "error"
x = "noise_db"
quantity = "position"
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "exp.toml"
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("quick", [False, True])
def test_shipped_experiments_load(quick):
    exps = {n: load_experiment(n, quick=quick) for n in SHIPPED}
    assert all(e.methods == (*PAPER_METHODS, "filter") for e in exps.values())
    noise = exps["noise"]
    assert [dict(c.params)["noise_db"] for c in noise.conditions] == [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    assert all(c.scenario.n_receivers == 4 for c in noise.conditions)
    rx = {dict(c.params)["n_receivers"] for c in exps["receivers"].conditions}
    assert rx == {3, 4, 5, 6}
    intervals = [c.scenario.interval_ms for c in exps["interval"].conditions]
    assert intervals[0] == 5.0 and max(intervals) >= 250.0
    assert {c.scenario.motion.rotation for c in exps["motion"].conditions} == {"linear", "periodic"}
    assert {c.scenario.motion.rotation for c in exps["bounds"].conditions} == {"linear", "fast"}
    if not quick:
        assert all(e.runs == 10 for e in exps.values())
        assert len(exps["receivers"].conditions) == 24  # 4 receiver counts x 6 sigmas


def test_quick_overrides(tmp_path):
    p = _write(tmp_path, BASE)
    full = load_experiment(p)
    quick = load_experiment(p, quick=True)
    assert (full.runs, len(full.conditions)) == (2, 2)
    assert (quick.runs, len(quick.conditions)) == (1, 1)
    assert load_experiment(p, runs=5).runs == 5


def test_seeds_depend_only_on_experiment_seed_and_run():
    seeds = [run_seed(4711, i) for i in range(20)]
    assert len(set(seeds)) == 20
    assert seeds[:5] == [run_seed(4711, i) for i in range(5)]
    assert run_seed(4712, 0) != seeds[0]
    ss = np.random.SeedSequence(4711).spawn(3)[2]
    assert seeds[2] == int(ss.generate_state(1, np.uint32)[0])
    # The same run index has the same seed in every condition (common random numbers).
    exp = parse_experiment(
        {"name": "t", "seed": 4711, "runs": 2, "sweep": {"scenario": {"noise_db": [1.0, 2.0]}}},
        "t.toml",
    )
    tasks = plan([exp])
    assert [t.seed for t in tasks] == [seeds[0], seeds[1], seeds[0], seeds[1]]
    assert len({t.key for t in tasks}) == 4


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (("noise_db = [0.5, 3.0]", "noise_db = [0.5, 40.0]"), "sweep.scenario.noise_db"),
        (("size_m = 6.0", "size_m = 6.0\nnoize_db = 1.0"), "scenario.noize_db"),
        (("runs = 2", 'runs = "two"'), "runs"),
        (("step_m = 0.5", "step_m = -0.5"), "scenario.step_m"),
        (("[quick]\nruns = 1", "[quick]\nruns = 1\nrunz = 3"), "quick.runz"),
        (('x = "noise_db"', 'x = "n_receivers"'), "figure[0].x"),
        (('quantity = "position"', 'quantity = "speed"'), "figure[0].quantity"),
        (('methods = ["full", "top", "lms"]', 'methods = ["full", "best"]'), "methods"),
        (("[sweep]", "[tracker]\nk = 0\n[sweep]"), "tracker.k"),
        (("[sweep]", '[motion]\nrotation = "spin"\n[sweep]'), "motion.rotation"),
        (
            ("sweep.scenario.noise_db = [0.5]", "sweep.scenario.n_receivers = [3]"),
            "quick.sweep.scenario.n_receivers",
        ),
    ],
)
def test_malformed_config_names_the_key(tmp_path, edit, key):
    old, new = edit
    assert old in BASE
    p = _write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        load_experiment(p)
    msg = str(exc.value)
    assert f"'{key}'" in msg, msg
    assert str(p) in msg and "\n" not in msg


def test_the_shipped_anchor_experiment_is_noise_with_the_anchor():
    """``anchor`` (beyond the paper) is the noise experiment with the anchor
    beside the methods: the same conditions and seeds, so the methods' rows
    are those of ``noise``."""
    anchor, noise = load_experiment("anchor"), load_experiment("noise")
    assert "anchor" in SHIPPED_BEYOND and "anchor" not in SHIPPED
    assert anchor.methods == ("full", "top", "lms", "filter", "textbook")
    assert [t.seed for t in plan([anchor])] == [t.seed for t in plan([noise])]
    assert [c.params for c in anchor.conditions] == [c.params for c in noise.conditions]


def test_the_anchor_is_known_to_experiments_and_2d_only():
    """Issue 15's anchor is a method name experiments accept (an unknown name's
    error lists it); a 3-D experiment refuses it in one line naming the key."""
    doc = {"name": "t", "seed": 1, "methods": ["filter", "textbook"]}
    assert parse_experiment(doc, "t.toml").methods == ("filter", "textbook")
    with pytest.raises(InputError, match=r"unknown method 'best' \(known: .*textbook\)"):
        parse_experiment({**doc, "methods": ["best"]}, "t.toml")
    with pytest.raises(InputError) as exc:
        parse_experiment({**doc, "scenario": {"pose": "3d"}}, "t.toml")
    assert "'methods'" in str(exc.value) and "2-D sites only" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_missing_seed_and_bad_toml(tmp_path):
    p = _write(tmp_path, BASE.replace("seed = 4711\n", ""))
    with pytest.raises(InputError, match="missing key 'seed'"):
        load_experiment(p)
    p = _write(tmp_path, BASE.replace("runs = 2", "runs = = 2"))
    with pytest.raises(InputError, match=r"exp\.toml:\d+: invalid TOML"):
        load_experiment(p)
    with pytest.raises(InputError, match="no experiment named 'nosuch'"):
        load_experiment("nosuch")


def test_cli_reports_a_malformed_config_in_one_line(tmp_path, capsys):
    p = _write(tmp_path, BASE.replace("noise_db = [0.5, 3.0]", "noise_db = [0.5, 40.0]"))
    code = main(["evaluate", str(p), "-o", str(tmp_path / "out"), "--workers", "0"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "'sweep.scenario.noise_db'" in err, err
    assert not (tmp_path / "out").exists()


def test_a_sweep_too_large_is_refused_before_it_is_built(tmp_path):
    """10⁵ conditions took 33 s and 1 GB to parse, 10⁷ never ended."""
    ten = lambda start, step: "[" + ", ".join(f"{start + i * step:g}" for i in range(10)) + "]"  # noqa: E731
    sweep = (
        f"scenario.noise_db = {ten(0.1, 0.1)}\n"
        f"scenario.survey_noise_db = {ten(0.0, 0.1)}\n"
        f"scenario.tx_power_dbm = {ten(10.0, 1.0)}\n"
        f"scenario.loss_fraction = {ten(0.0, 0.05)}\n"
        f"scenario.interval_ms = {ten(5.0, 1.0)}\n"
    )
    p = _write(tmp_path, BASE.replace("scenario.noise_db = [0.5, 3.0]\n", sweep))
    with pytest.raises(
        InputError, match=r"key 'sweep': 100,000 conditions \(10 × 10 × 10 × 10 × 10\)"
    ):
        load_experiment(p)
    p = _write(
        tmp_path,
        BASE.replace("runs = 2", "runs = 100000").replace(
            "[0.5, 3.0]", "[0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]"
        ),
    )
    with pytest.raises(InputError, match=r"key 'runs': 11 conditions × 100,000 runs"):
        load_experiment(p)
    with pytest.raises(InputError, match=r"--runs 1000000: 2 conditions"):
        load_experiment(_write(tmp_path, BASE), runs=100_000 * 10)
