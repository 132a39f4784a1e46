"""Every script in ``scripts/`` (and the two benchmark-support tools) runs on a tiny input.

Each script's ``main(argv)`` is called in this process with its smallest options
(``--quick``: a 10 m site with a 0.25 m grid and a 0.2 s trace; one seed; one σ),
and what it prints or writes is checked for the table it promises. The numbers
mean nothing at this size: these tests only keep the scripts from rotting (an API
they call renamed, an option gone). ``real_data.py --quick`` changes a module
global of ``radiopose.realdata.experiment``, so it runs in a subprocess. The
scripts whose smallest run is still long (standard-site filter runs, the real
site's cross-validation, the detector's quick plan, every 3-D variant of
``pose3d_accuracy.py``) are marked ``slow``.

Bad input (:data:`BAD_ARGUMENTS`) must be each script's usage error before any
work: exit status 2, one line naming the option, no traceback, nothing written
(:mod:`radiopose.scripting`'s types and checks; :func:`~radiopose.scripting.run_script`
for what is found only during the work).
"""

from __future__ import annotations

import argparse
import errno
import importlib.util
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"
BENCHMARKS = REPO / "benchmarks"
MITLL = REPO.parent / "shared" / "data" / "phone-patterns-mitll"


def _load(path: Path) -> ModuleType:
    """Import a script by path under a private module name (not ``__main__``)."""
    spec = importlib.util.spec_from_file_location(f"_smoke_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _run(path: Path, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = _load(path).main(argv)
    assert code in (None, 0)
    return capsys.readouterr().out


def _table_rows(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("|")]


def test_accuracy_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "accuracy.md"
    argv = ["--quick", "--seeds", "1", "--first-seed", "5", "--sigmas", "1", "--out", str(out)]
    printed = _run(SCRIPTS / "accuracy_table.py", argv, capsys)
    text = out.read_text(encoding="utf-8")
    assert text.startswith("# Accuracy on the smoke site (`--quick`")
    assert printed.strip() == text.strip()
    for method in ("full", "location", "orientation", "top", "lms"):
        assert any(f"| {method} " in row or f"| `{method}`" in row for row in _table_rows(text))
    assert out.with_suffix(".json").is_file()
    # the footer is the command that reproduces the table, --quick and every option with it
    assert f"Produced by `python scripts/accuracy_table.py {shlex.join(argv)}`" in text
    # a smoke table must not replace docs/accuracy.md (it once did): --quick needs --out
    with pytest.raises(SystemExit) as exit_:
        _load(SCRIPTS / "accuracy_table.py").main(["--quick", "--seeds", "1", "--sigmas", "1"])
    assert exit_.value.code == 2
    assert "--quick writes a smoke table" in capsys.readouterr().err


def test_accuracy_table_quick_header(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--quick's header describes the smoke site that ran (it said 20 × 20 m, 0.1 m,
    2 s = 40 packets, "1 runs"), with singular and plural right; --duration-s is
    honoured with --quick (it was ignored and the header said 0 s)."""
    out = tmp_path / "one.md"
    argv = ["--quick", "--seeds", "1", "--first-seed", "5", "--sigmas", "1", "--out", str(out)]
    _run(SCRIPTS / "accuracy_table.py", argv, capsys)
    text = out.read_text(encoding="utf-8")
    assert text.startswith("# Accuracy on the smoke site (`--quick`: not the paper's standard")
    assert "Smoke site (`ScenarioConfig.smoke()`: 10 × 10 m, 0.25 m and 1° candidate grid, " in text
    assert "0.2 s per run = 40 packets), 1 run per σ (seed 5), default pipeline" in text
    assert "20 × 20 m" not in text and "never used by tests" not in text
    out = tmp_path / "two.md"
    argv = ["--quick", "--seeds", "2", "--first-seed", "5", "--sigmas", "1", "--duration-s", "0.3",
            "--out", str(out)]  # fmt: skip
    _run(SCRIPTS / "accuracy_table.py", argv, capsys)
    text = out.read_text(encoding="utf-8")
    assert "0.3 s per run = 60 packets), 2 runs per σ (seeds 5–6), default pipeline" in text
    assert f"Produced by `python scripts/accuracy_table.py {shlex.join(argv)}`" in text


def test_live_lag_accuracy(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--quick", "--seeds", "1", "--first-seed", "5", "--sigmas", "1"]
    printed = _run(SCRIPTS / "live_lag_accuracy.py", argv, capsys)
    rows = _table_rows(printed)
    assert len(rows) == 2 + 4  # header, rule, one row per variant
    # the footer reproduces the run: --quick and the options given (it left them out)
    assert f"(`python scripts/live_lag_accuracy.py {shlex.join(argv)}`)." in printed
    assert all(row.startswith("| 1 |") for row in rows[2:])
    # --variants picks rows; --set overrides the filter (a bad field is argparse's error)
    argv += ["--variants", "causal", "--set", "jump_probability=0.01"]
    rows = _table_rows(_run(SCRIPTS / "live_lag_accuracy.py", argv, capsys))
    assert len(rows) == 2 + 1 and "| causal |" in rows[2]
    # --settle-s adds three columns: the errors after acquisition
    argv += ["--settle-s", "0.1", "--duration-s", "0.3"]
    rows = _table_rows(_run(SCRIPTS / "live_lag_accuracy.py", argv, capsys))
    assert "after 0.1 s" in rows[0] and rows[2].count("|") == 15
    # a phone's packet rate (--interval-ms): 0.3 s at 100 ms is 3 packets a run
    argv = ["--quick", "--seeds", "1", "--sigmas", "1", "--variants", "causal",
            "--interval-ms", "100", "--duration-s", "0.3"]  # fmt: skip
    printed = _run(SCRIPTS / "live_lag_accuracy.py", argv, capsys)
    assert "--interval-ms 100" in printed and len(_table_rows(printed)) == 3
    # issue 15's anchor beside the filter's rows
    argv = ["--quick", "--seeds", "1", "--sigmas", "1", "--variants", "causal", "textbook"]
    rows = _table_rows(_run(SCRIPTS / "live_lag_accuracy.py", argv, capsys))
    assert [r.split("|")[2].strip() for r in rows[2:]] == ["causal", "textbook"]
    # the live re-solve's bound: every packet answered from a re-solve of its prefix
    bound = "re-solved at every emission"
    argv = ["--quick", "--seeds", "1", "--sigmas", "1", "--duration-s", "0.4", "--variants", bound]
    rows = _table_rows(_run(SCRIPTS / "live_lag_accuracy.py", argv, capsys))
    assert rows[2].split("|")[2].strip() == bound and "| 100.0 % |" in rows[2]
    # --bins-s: a second table, the orientation error by time bin
    argv = ["--quick", "--seeds", "1", "--sigmas", "1", "--duration-s", "0.4", "--variants",
            "causal", "--bins-s", "0.1"]  # fmt: skip
    rows = _table_rows(_run(SCRIPTS / "live_lag_accuracy.py", argv, capsys))
    assert "0.3–0.4 s" in rows[3] and rows[5].startswith("| 1 | causal |")
    assert rows[5].count("|") == 2 + 4 + 1
    for bad, said in (
        (["--set", "no_such_field=1"], "no_such_field"),
        (["--settle-s", "0.2"], "--settle-s must be in [0, 0.2)"),
        (["--duration-s", "0"], "--duration-s must be > 0"),
        (["--bins-s", "0"], "--bins-s must be in (0, 0.2]"),
    ):
        with pytest.raises(SystemExit) as exc:
            _load(SCRIPTS / "live_lag_accuracy.py").main(["--quick", *bad])
        assert exc.value.code == 2
        assert said in capsys.readouterr().err


def test_mirror_diagnosis(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(
        SCRIPTS / "mirror_diagnosis.py", ["5", "1.0", "--quick", "--packets", "21"], capsys
    )
    lines = [line for line in printed.splitlines() if line.startswith("packet ")]
    assert [line.split(":")[0] for line in lines] == ["packet 0", "packet 20"]
    assert all("nearest-grid MSE" in line for line in lines)


def test_lock_diagnosis(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "lock_diagnosis.py", ["--quick", "--reverse", "--arbiter"], capsys)
    rows = [row for row in _table_rows(printed) if row.startswith("| 5 |")]
    assert {row.split("|")[4].strip() for row in rows} == {
        "filter",
        "+ reversed pass",
        "+ reversed pass, MAP arbiter",
    }
    assert all("Δ" not in row for row in rows)


def test_lock_diagnosis_candidates(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--quick", "--candidates", "--loud", "--set", "offline_offset_refit=True"]
    printed = _run(SCRIPTS / "lock_diagnosis.py", args, capsys)
    assert printed.startswith("seed 5 σ 3 +6 dB: ")
    assert "passes (centre dB: evidence nats): wide: " in printed
    assert "  forward (pass " in printed and "  truth " in printed and " *" in printed
    assert re.search(r"Laplace \d+\.\d", printed)  # every candidate's width term


def test_offset_profile(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "offset_profile.py", ["--quick", "--loud"], capsys)
    assert "σ 3 seed 5 device +6 grid 1 m/15° window 0.1 s σg 0.5: marginal argmax" in printed
    rows = _table_rows(printed)
    assert [row.split("|")[2].strip() for row in rows if row.startswith("| 3 |")] == ["+0", "+6"]


def test_handheld_dynamics(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "handheld_dynamics.py", ["--seeds", "9000-9001"], capsys)
    rows = _table_rows(printed)[2:]
    assert [row.split("|")[1].strip() for row in rows] == ["9000", "9001"]
    assert all(float(row.split("|")[2]) > 0 for row in rows)  # the walk turns
    with pytest.raises(SystemExit) as exc:  # a bad seed set: the parser's usage error
        _load(SCRIPTS / "handheld_dynamics.py").main(["--seeds", "9001-9000"])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().endswith("seed set '9001-9000' is empty")


def test_orientation_outliers(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--seeds", "1", "--first-seed", "5", "--grid", "test", "--windows", "0.1"]
    printed = _run(SCRIPTS / "orientation_outliers.py", argv, capsys)
    assert "window 0.1 s: pooled" in printed
    assert "seeds 5–5: pooled" in printed


def test_survey_interpolation_error(capsys: pytest.CaptureFixture[str]) -> None:
    rows = _table_rows(
        _run(SCRIPTS / "survey_interpolation_error.py", ["--quick", "--seeds", "1"], capsys)
    )
    assert len(rows) == 2 + 4  # header, rule; cubic and linear × all and far
    assert {row.split("|")[1].strip() for row in rows[2:]} == {"cubic", "linear"}
    rows = _table_rows(
        _run(SCRIPTS / "survey_interpolation_error.py", ["--quick", "--seeds", "1", "--pose", "3d"],
             capsys)
    )  # fmt: skip
    maps = {"survey", "detrended", "detrended + receiver gain"}
    assert {row.split("|")[1].strip() for row in rows[2:]} == maps
    assert len(rows) > 2 + 3  # every map, at least two distance bands each
    wrong = _table_rows(
        _run(SCRIPTS / "survey_interpolation_error.py",
             ["--quick", "--seeds", "1", "--pose", "3d", "--rx-pattern-error-db", "2",
              "--rx-orientation-error-deg", "5"], capsys)
    )  # fmt: skip
    # the receivers' enrolment errors move only the gain term's rows
    gain = [r for r in rows[2:] if "gain" in r]
    assert [r for r in wrong[2:] if "gain" not in r] == [r for r in rows[2:] if "gain" not in r]
    assert [r for r in wrong[2:] if "gain" in r] != gain


@pytest.mark.skipif(not MITLL.is_dir(), reason=f"MIT LL captures not found at {MITLL}")
def test_enrol_mitll(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--data", str(MITLL), "--patterns-dir", str(tmp_path), "--figures-dir", str(tmp_path)]
    printed = _run(SCRIPTS / "enrol_mitll.py", argv, capsys)
    assert printed.count("directivity") == 2
    for name in ("iphone-11", "galaxy-s10"):
        # the shipped patterns are what the script writes (it reproduces them)
        shipped = REPO / "src" / "radiopose" / "data" / "patterns" / f"{name}.csv"
        assert (tmp_path / f"{name}.csv").read_bytes() == shipped.read_bytes()
        assert (tmp_path / f"pattern-{name}.png").stat().st_size > 0
    assert (tmp_path / "pattern-phones.png").stat().st_size > 0


def test_benchmark_prune(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(BENCHMARKS / "bench_prune.py", ["--packets", "1"], capsys)
    assert printed.startswith("packet ") and "blocks surviving" in printed


def test_benchmark_profile(capsys: pytest.CaptureFixture[str]) -> None:
    import radiopose.likelihood.compiled as compiled

    names = ("exact_mse_db2", "_prefilter", "_shift_topk_shared", "_shift_topk_serial")
    before = [getattr(compiled, n) for n in names]
    printed = _run(BENCHMARKS / "bench_profile.py", ["--packets", "3", "--repeat", "1"], capsys)
    assert printed.startswith("warm packet ") and "kernel calls" in printed
    assert "exact rescoring" in printed
    # it wrapped the module's functions for its run only: the suite's later tests get them back
    assert [getattr(compiled, n) for n in names] == before


def test_benchmark_devices(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Many devices through the live pipeline: every packet tracked (the run
    raises otherwise), filter answers every one, the table has its rows."""
    out = tmp_path / "new" / "devices.md"  # (a missing directory is made, as --out allows)
    argv = ["--devices", "2", "--duration-s", "0.6", "--variants", "full", "filter",
            "--markdown", str(out)]  # fmt: skip
    printed = _run(BENCHMARKS / "bench_devices.py", argv, capsys)
    rows = _table_rows(printed)
    assert len(rows) == 2 + 2 and rows[2].startswith("| 2 | full | 20 | 12 |")
    assert rows[3].startswith("| 2 | filter | 20 | 12 | 100.0 % |")
    assert out.read_text(encoding="utf-8").strip() == printed.strip()


def test_benchmark_devices_paced(capsys: pytest.CaptureFixture[str]) -> None:
    """The real-time mode: batches stored as the trace's time passes, the server's
    defaults; its row counts what the process wrote (the frames' batches at least)
    and the pipeline's commits, and the ratio's baseline is full itself."""
    argv = ["--devices", "2", "--duration-s", "1.5", "--warm-s", "0.5", "--variants", "full",
            "--paced"]  # fmt: skip
    printed = _run(BENCHMARKS / "bench_devices.py", argv, capsys)
    rows = _table_rows(printed)
    head = [c.strip() for c in rows[0].split("|")[1:-1]]
    row = dict(zip(head, (c.strip() for c in rows[2].split("|")[1:-1]), strict=True))
    assert len(rows) == 3 and row["method"] == "full" and row["offered_per_s"] == "20"
    assert float(row["written_mb_per_s"]) > 0 and float(row["commits_per_s"]) > 0
    assert row["written_vs_full"] == "1.00"


@pytest.mark.slow
def test_benchmark_sharing(capsys: pytest.CaptureFixture[str]) -> None:
    """Per-device cost in one tracker and the methods at the 3-D site (5 fresh
    processes, about 40 s: slow)."""
    printed = _run(BENCHMARKS / "bench_sharing.py", ["--devices", "2", "--packets", "2"], capsys)
    rows = _table_rows(printed)
    assert [r.split("|")[1].strip() for r in rows[2:4]] == ["2d", "3d"]
    assert rows[-2].startswith("| full |") and rows[-1].startswith("| filter |")


# ---------------------------------------------------- slow: long even at their smallest
@pytest.mark.slow
def test_filter_accuracy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "filter-accuracy.md"
    argv = ["--seeds", "1", "--first-seed", "5", "--sigmas", "3", "--out", str(out)]
    _run(SCRIPTS / "filter_accuracy.py", argv, capsys)
    text = out.read_text(encoding="utf-8")
    assert any("filter" in row for row in _table_rows(text))
    assert f"(`python scripts/filter_accuracy.py {shlex.join(argv)}`)." in text


@pytest.mark.slow
def test_filter_scenarios(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "filter_scenarios.py", ["--seeds", "1", "--first-seed", "5"], capsys)
    assert any("30 % packet loss" in row for row in _table_rows(printed))
    assert "(`python scripts/filter_scenarios.py --seeds 1 --first-seed 5`)." in printed


@pytest.mark.slow
def test_spoof_detection(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--plan", "quick", "--out", str(tmp_path)]
    _run(SCRIPTS / "spoof_detection.py", argv, capsys)
    text = (tmp_path / "summary.md").read_text(encoding="utf-8")
    assert (
        text.startswith("# Spoofing detector, plan `quick`") and "## ROC over the threshold" in text
    )
    # attacks 1-2: the oracle bound (one case, one run) and the continuity test
    module = _load(SCRIPTS / "spoof_detection.py")
    module.ORACLE_CASES = ((4, 0.5, 1.0),)
    assert module.main(["--oracle", "1", "--out", str(tmp_path)]) == 0
    assert "| fixed | 4 | 0.5 | 1 |" in (tmp_path / "oracle.md").read_text(encoding="utf-8")
    assert module.main(["--plan", "tuning", "--split", "1", "0", "--out", str(tmp_path)]) == 0
    assert _table_rows((tmp_path / "split.md").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_real_data(tmp_path: Path) -> None:
    out = tmp_path / "real.md"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), *sys.path])}
    r = subprocess.run(
        [sys.executable, str(SCRIPTS / "real_data.py"), "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=1800,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    text = out.read_text(encoding="utf-8")
    assert _table_rows(text)
    # run as a program: the footer is its command line (it kept --quick but dropped --out)
    assert f"\npython scripts/real_data.py --quick --out {shlex.quote(str(out))}\n" in text


@pytest.mark.slow  # ~45 s: every 3-D variant on a 0.3 s trace
def test_pose3d_accuracy(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--seeds", "1", "--first-seed", "5", "--receivers", "6", "--sigmas", "1"]
    variants = ["--heading-prior-deg", "30", "--power-error-db", "4", "--no-refine", "--oracle"]
    variants += ["--refine-accel", "1", "400", "--refine-polish", "1"]
    variants += ["--polish-modes", "3", "10", "5", "--reverse-pass", "--reverse-members"]
    variants += ["--restarts", "1", "--offline-particles", "500"]
    printed = _run(
        SCRIPTS / "pose3d_accuracy.py", [*argv, "--duration-s", "0.3", *variants], capsys
    )
    rows = _table_rows(printed)
    assert any(r.startswith("| receivers |") for r in rows)
    for label in (
        "standard",
        "+ heading prior 30°",
        "devices.csv power 4 dB low",
        "without refinement",
        "oracle: refinement from the truth",
        "refinement prior constant-rate (height 1, tilt 400), polish 1",
        "oracle, refinement prior constant-rate (height 1, tilt 400)",
        "polish up to 3 modes within 10, switch 5",
        "+ reversed pass",
        "+ reversed pass and its members",
        "+ 1 mid-track restart",
        "offline particles 500",
    ):
        assert any(r.startswith(f"| 6 | 1 | {label} |") for r in rows)


def test_pose3d_accuracy_live_lag(capsys: pytest.CaptureFixture[str]) -> None:
    """``--live-lag-s``: the live server's 3-D filter (no refinement); a lag
    beyond the server's 0.25 s is refused."""
    argv = ["--seeds", "1", "--first-seed", "5", "--receivers", "6", "--sigmas", "1",
            "--duration-s", "0.3", "--live-lag-s", "0.25"]  # fmt: skip
    printed = _run(SCRIPTS / "pose3d_accuracy.py", argv, capsys)
    assert "live (lag 0.25 s, no refinement)" in printed
    assert any(r.startswith("| 6 | 1 | standard |") for r in _table_rows(printed))
    with pytest.raises(SystemExit) as exc:
        _load(SCRIPTS / "pose3d_accuracy.py").main([*argv[:-1], "0.5"])
    assert exc.value.code == 2
    assert "--live-lag-s must lie in [0, 0.25]" in capsys.readouterr().err


def test_live_pose3d(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--duration-s", "1.5", "--size-m", "6", "--receivers", "4", "--seed", "5"]
    printed = _run(SCRIPTS / "live_pose3d.py", argv, capsys)
    rows = _table_rows(printed)
    assert any(r.startswith("| 2d | 75 |") for r in rows)
    assert any(r.startswith("| 3d | 75 |") for r in rows)


def test_detect_pose3d(capsys: pytest.CaptureFixture[str]) -> None:
    rows = _table_rows(_run(SCRIPTS / "detect_pose3d.py", ["--quick", "--sigmas", "1"], capsys))
    assert len(rows) == 2 + 1  # header, rule, one row per σ
    assert rows[2].startswith("| 1 | 0.001 |")


def test_pose3d_identifiability(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "pose3d_identifiability.py", ["--starts", "5", "--seed", "5"], capsys)
    assert "offset known:" in printed and "offset free:" in printed


@pytest.mark.slow
def test_real_data_ablation(capsys: pytest.CaptureFixture[str]) -> None:
    printed = _run(SCRIPTS / "real_data_ablation.py", ["--variants", "base", "--jobs", "1"], capsys)
    # one line per variant, not a table: the pooled errors, then each track's mean
    [line] = printed.splitlines()
    assert line.startswith("base ") and " seed 0 mean " in line and " median " in line
    assert len(line.split("|")) == 3


def test_coarse3d_lead(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--seeds", "9000", "--no-pipeline", "--duration-s", "1"]
    printed = _run(SCRIPTS / "coarse3d_lead.py", argv, capsys)
    rows = _table_rows(printed)[2:]
    assert [row.split("|")[1].strip() for row in rows] == ["9000"]
    position_m = float(rows[0].split("|")[3].split("/")[0])
    assert 0.0 <= position_m < 10.0  # a path inside the 10 m site


@pytest.mark.slow
def test_pose3d_misfit(capsys: pytest.CaptureFixture[str]) -> None:
    import radiopose.filtering.refine3d as refine3d

    before = refine3d.refine_smoothed
    argv = ["--seeds", "9000", "--duration-s", "0.5", "--oracle"]
    rows = _table_rows(_run(SCRIPTS / "pose3d_misfit.py", argv, capsys))[2:]
    cells = [c.strip() for c in rows[0].split("|")[1:-1]]
    assert cells[0] == "9000" and int(cells[3]) > 0
    assert 0.0 < float(cells[5]) < 10.0  # the residuals' RMS, dB (σ 1 dB simulated)
    kept, truth, gap = float(cells[7]), float(cells[8]), float(cells[10])
    assert gap == pytest.approx(kept - truth, abs=0.11) and 0.0 <= float(cells[9]) < 180.0
    assert refine3d.refine_smoothed is before  # the script's hook is undone
    with pytest.raises(SystemExit) as exc:
        _load(SCRIPTS / "pose3d_misfit.py").main(["--pose3d-set", "no_such_field=1"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:  # the scenario's overrides are checked too
        _load(SCRIPTS / "pose3d_misfit.py").main(["--sim-set", "pitch_range_deg=(70.0,20.0)"])
    assert exc.value.code == 2


# ---------------------------------------------- bad input: one line, exit status 2
BAD_ARGUMENTS: list[tuple[str, list[str], str]] = [
    # (script, argv ({tmp}: an empty directory holding an empty file "file"), the error says)
    ("orientation_outliers", ["--grid", "test", "--seeds", "0"],
     "argument --seeds: must be an integer >= 1, got '0'"),
    ("orientation_outliers", ["--sigma", "nan"], "argument --sigma: must be a finite number"),
    ("orientation_outliers", ["--windows", "-1"], "argument --windows: must be a finite"),
    ("orientation_outliers", ["--first-seed", "-5"],
     "argument --first-seed: must be an integer >= 0, got '-5'"),
    ("mirror_diagnosis", ["1", "nan"], "argument sigma_db: must be a finite number, got 'nan'"),
    ("mirror_diagnosis", ["1", "40", "--quick"], "noise_db = 40.0 is out of range"),
    ("mirror_diagnosis", ["--quick", "--packets", "0"], "argument --packets: must be"),
    ("accuracy_table", ["--quick", "--seeds", "0", "--sigmas", "1", "--out", "{tmp}/x/a.md"],
     "argument --seeds: must be an integer >= 1"),
    ("accuracy_table", ["--quick", "--seeds", "1", "--sigmas", "1", "--out", "{tmp}"],
     "--out {tmp}: is a directory, expected a file path"),
    ("accuracy_table", ["--quick", "--seeds", "1", "--sigmas", "1", "--out", "{tmp}/file/a.md"],
     "a parent is not a directory"),
    ("accuracy_table", ["--quick", "--seeds", "1", "--sigmas", "-1", "--out", "{tmp}/a.md"],
     "argument --sigmas: must be a finite number > 0"),
    ("accuracy_table", ["--quick", "--seeds", "1", "--sigmas", "1", "--duration-s", "inf",
                        "--out", "{tmp}/a.md"], "argument --duration-s: must be a finite number"),
    ("enrol_mitll", ["--data", "{tmp}/none", "--patterns-dir", "{tmp}/p", "--figures-dir",
                     "{tmp}/f"], "--data {tmp}/none: no such directory"),
    ("live_lag_accuracy", ["--quick", "--seeds", "1.5"], "--seeds: '1.5' is not an integer"),
    ("live_lag_accuracy", ["--quick", "--sigmas", "inf"], "argument --sigmas: must be a finite"),
    ("detect_pose3d", ["--quick", "--receivers", "2"], "n_receivers = 2 is out of range"),
    ("detect_pose3d", ["--quick", "--sigmas", "1", "--out", "{tmp}"], "is a directory"),
    ("filter_accuracy", ["--seeds", "1", "--jobs", "0"], "argument --jobs: must be"),
    ("filter_accuracy", ["--seeds", "1", "--sigmas", "nan"], "argument --sigmas: must be a finite"),
    ("filter_accuracy", ["--seeds", "1", "--first-seed", "-1"], "argument --first-seed"),
    ("filter_scenarios", ["--seeds", "0"], "argument --seeds: must be an integer >= 1"),
    ("handheld_dynamics", ["--seeds", "9000", "--duration-s", "0"],
     "argument --duration-s: must be a finite number > 0"),
    ("handheld_dynamics", ["--seeds", "9000", "--duration-s", "0.005"], "two samples at 200 Hz"),
    ("coarse3d_lead", ["--seeds", "9000", "--no-pipeline", "--receivers", "2"],
     "n_receivers = 2 is out of range"),
    ("coarse3d_lead", ["--seeds", "9000", "--no-pipeline", "--sigma", "-1"], "argument --sigma"),
    ("live_pose3d", ["--receivers", "2", "--duration-s", "1"], "n_receivers = 2 is out of range"),
    ("live_pose3d", ["--interval-ms", "0", "--duration-s", "1"], "argument --interval-ms"),
    ("lock_diagnosis", ["--quick", "--set", "jump_probability=0.01"], "give --candidates"),
    ("lock_diagnosis", ["--quick", "--sigma", "0"], "--sigma: must be a finite number > 0"),
    ("offset_profile", ["--quick", "--grids", "1:0"], "--grids: '1:0' is not STEP_M:STEP_DEG"),
    ("offset_profile", ["--quick", "--stride", "0"], "argument --stride: must be an integer >= 1"),
    ("pose3d_accuracy", ["--quick", "--restarts", "-1"], "argument --restarts"),
    ("pose3d_accuracy", ["--quick", "--polish-modes", "2.5", "1", "1"], "K must be an integer"),
    ("pose3d_accuracy", ["--quick", "--offline-particles", "5"], "offline_n_particles = 5"),
    ("pose3d_accuracy", ["--quick", "--only-variants"], "ask for another row too"),
    ("pose3d_identifiability", ["--starts", "0"], "argument --starts: must be an integer >= 1"),
    ("pose3d_identifiability", ["--starts", "1", "--receivers", "2"], "n_receivers = 2"),
    ("pose3d_misfit", ["--sim-set", "n_receivers=4"], "--sim-set n_receivers: give --receivers"),
    ("pose3d_misfit", ["--seeds", "9000", "--duration-s", "-0.5"], "argument --duration-s"),
    ("real_data", ["--dataset", "{tmp}/none", "--out", "{tmp}/r.md"],
     "--dataset {tmp}/none: no such directory"),
    ("real_data_ablation", ["--variants", "nope"], "argument --variants: invalid choice: 'nope'"),
    ("real_data_ablation", ["--variants", "base", "--jobs", "0"], "argument --jobs"),
    ("spoof_detection", ["--out", "{tmp}/file"], "--out {tmp}/file: is a file, expected a dir"),
    ("spoof_detection", ["--split", "0", "0", "--out", "{tmp}/s"], "RUNS must be an integer >= 1"),
    ("survey_interpolation_error", ["--quick", "--seeds", "1", "--rx-pattern-error-db", "2"],
     "apply with --pose 3d only"),
    ("survey_interpolation_error", ["--quick", "--seeds", "0"], "argument --seeds"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("script", "argv", "said"),
    BAD_ARGUMENTS,
    ids=[f"{s} {' '.join(a)}" for s, a, _ in BAD_ARGUMENTS],
)
def test_bad_arguments_are_usage_errors(
    script: str, argv: list[str], said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bad count, number, seed or output path is the parser's usage error before
    any work: exit status 2, one ``error:`` line naming it, no traceback, nothing
    written (they were tracebacks, an empty run, or an error after the run)."""
    (tmp_path / "file").write_text("", encoding="utf-8")
    before = sorted(tmp_path.rglob("*"))
    argv = [a.format(tmp=tmp_path) for a in argv]
    with pytest.raises(SystemExit) as exc:
        _load(SCRIPTS / f"{script}.py").main(argv)
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and captured.out == ""
    last = captured.err.strip().splitlines()[-1]
    assert ": error: " in last and said.format(tmp=tmp_path) in last
    assert sorted(tmp_path.rglob("*")) == before


def test_scripts_run_through_run_script() -> None:
    """Every script's entry point is :func:`radiopose.scripting.run_script`, so an
    error found during the work is one line with exit status 2, not a traceback."""
    for path in sorted(SCRIPTS.glob("*.py")):
        tail = path.read_text(encoding="utf-8").rstrip().splitlines()[-2:]
        entry = ['if __name__ == "__main__":', "    raise SystemExit(run_script(main))"]
        assert tail == entry, path


def test_run_script(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """run_script: an InputError raised inside a script's main is one line on
    stderr naming the script, exit status 2; an OSError names its file; Ctrl-C is
    130; a bug propagates with its traceback."""
    from radiopose.errors import InputError
    from radiopose.scripting import run_script

    module = _load(SCRIPTS / "mirror_diagnosis.py")
    raised: list[BaseException] = []

    def diagnose(*_a: object) -> None:
        raise raised[0]

    monkeypatch.setattr(module, "diagnose", diagnose)
    raised[:] = [InputError("bad value\non two lines", path="x.csv", line=3)]
    assert run_script(module.main, ["--quick"]) == 2
    captured = capsys.readouterr()
    assert captured.err == "mirror_diagnosis.py: x.csv:3: bad value on two lines\n"
    assert captured.out == ""
    raised[:] = [IsADirectoryError(errno.EISDIR, "Is a directory", "/tmp/d")]
    assert run_script(module.main, ["--quick"]) == 2
    assert capsys.readouterr().err == "mirror_diagnosis.py: /tmp/d: Is a directory\n"
    raised[:] = [KeyboardInterrupt()]
    assert run_script(module.main, ["--quick"]) == 130
    assert capsys.readouterr().err == "mirror_diagnosis.py: interrupted\n"
    raised[:] = [ValueError("a bug")]
    with pytest.raises(ValueError, match="a bug"):
        run_script(module.main, ["--quick"])
    with pytest.raises(SystemExit) as exc:  # the parser's own usage errors stay its own
        run_script(module.main, ["--packets", "0"])
    assert exc.value.code == 2
    capsys.readouterr()
    monkeypatch.setattr(module, "diagnose", lambda *_a: None)
    assert run_script(module.main, ["--quick"]) == 0


def test_run_script_as_a_program(tmp_path: Path) -> None:
    """Run as ``python scripts/x.py``: an error found only during the work (a
    seed past numpy's range, met at the second seed) is one line, status 2."""
    r = subprocess.run(
        [sys.executable, str(SCRIPTS / "orientation_outliers.py"), "--grid", "test",
         "--first-seed", str(2**63 - 1), "--seeds", "2", "--windows", "0.1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 2
    assert r.stderr == f"orientation_outliers.py: seed {2**63} must be an integer in [0, 2**63)\n"


@pytest.mark.parametrize(
    ("name", "good", "bad"),
    [
        ("positive_int", {"1": 1, "12": 12, " 3 ": 3},
         ["0", "-1", "1.5", "nan", "inf", "x", ""]),
        ("non_negative_int", {"0": 0, "5": 5, "1000": 1000},
         ["-1", "-5", "1.5", "nan", "inf", "x", ""]),
        ("finite_float", {"0": 0.0, "-1.5": -1.5, "1e3": 1000.0, "1": 1.0},
         ["nan", "inf", "-inf", "NaN", "x", ""]),
        ("positive_float", {"0.5": 0.5, "1e-9": 1e-9, "3": 3.0},
         ["0", "-0", "-1", "nan", "inf", "x"]),
        ("non_negative_float", {"0": 0.0, "-0": 0.0, "2.5": 2.5, "1": 1.0},
         ["-1", "-0.5", "nan", "inf", "-inf", "x"]),
    ],
)  # fmt: skip
def test_type_helpers(name: str, good: dict[str, float], bad: list[str]) -> None:
    """The scripts' argparse types: each valid string's value (an int for the
    counts), and an ArgumentTypeError quoting each invalid string."""
    import radiopose.scripting as scripting

    helper = getattr(scripting, name)
    for text, value in good.items():
        got = helper(text)
        assert got == value and type(got) is type(value), (name, text)
    for text in bad:
        with pytest.raises(argparse.ArgumentTypeError) as exc:
            helper(text)
        assert repr(text) in str(exc.value), (name, text)
    # through a parser: its usage error, exit status 2
    ap = argparse.ArgumentParser(prog="x.py")
    ap.add_argument("--n", type=helper)
    with pytest.raises(SystemExit) as exit_:
        ap.parse_args(["--n", "nan"])
    assert exit_.value.code == 2


def test_check_output_and_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """check_output refuses a directory given as a file, a file given as a
    directory and a path under a file, naming the option, and creates nothing;
    usage_errors turns an InputError into the parser's usage error."""
    from radiopose.errors import InputError
    from radiopose.scripting import check_output, usage_errors

    ap = argparse.ArgumentParser(prog="x.py")
    (tmp_path / "file").write_text("", encoding="utf-8")
    check_output(ap, "--out", files=[tmp_path / "new" / "a.md"], dirs=[tmp_path / "d"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    for kw, said in (
        ({"files": [tmp_path]}, f"--out {tmp_path}: is a directory, expected a file path"),
        (
            {"dirs": [tmp_path / "file"]},
            f"--out {tmp_path}/file: is a file, expected a directory",
        ),
        (
            {"files": [tmp_path / "file" / "a.md"]},
            f"--out {tmp_path}/file/a.md: cannot create: a parent is not a directory",
        ),
    ):
        with pytest.raises(SystemExit) as exc:
            check_output(ap, "--out", **kw)
        assert exc.value.code == 2
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"x.py: error: {said}"
    with pytest.raises(SystemExit) as exc, usage_errors(ap, "--set"):
        raise InputError("jump_probability = 2 must be in [0, 1]")
    assert exc.value.code == 2
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith("x.py: error: --set jump_probability = 2 must be in [0, 1]")
    )


SCRIPT_TESTS: dict[str, Callable[..., None]] = {
    "accuracy_table": test_accuracy_table,
    "coarse3d_lead": test_coarse3d_lead,
    "enrol_mitll": test_enrol_mitll,
    "filter_accuracy": test_filter_accuracy,
    "filter_scenarios": test_filter_scenarios,
    "handheld_dynamics": test_handheld_dynamics,
    "live_lag_accuracy": test_live_lag_accuracy,
    "lock_diagnosis": test_lock_diagnosis,
    "mirror_diagnosis": test_mirror_diagnosis,
    "pose3d_misfit": test_pose3d_misfit,
    "offset_profile": test_offset_profile,
    "orientation_outliers": test_orientation_outliers,
    "live_pose3d": test_live_pose3d,
    "pose3d_accuracy": test_pose3d_accuracy,
    "pose3d_identifiability": test_pose3d_identifiability,
    "real_data": test_real_data,
    "real_data_ablation": test_real_data_ablation,
    "spoof_detection": test_spoof_detection,
    "survey_interpolation_error": test_survey_interpolation_error,
    "detect_pose3d": test_detect_pose3d,
}


def test_every_script_has_a_smoke_test() -> None:
    assert sorted(p.stem for p in SCRIPTS.glob("*.py")) == sorted(SCRIPT_TESTS)
