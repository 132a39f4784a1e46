"""The spoofing experiments end to end on a small seeded site, the report and the CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radiopose.cli import main
from radiopose.errors import InputError
from radiopose.security.attacker import AttackerModel
from radiopose.security.experiments import (
    SpoofConfig,
    parse_experiments,
    plan_tasks,
    run_experiment,
)
from radiopose.security.report import collect, mean_ci95, summarise
from radiopose.simulate import ScenarioConfig
from radiopose.units import angle_diff_deg

SMALL = SpoofConfig(
    scenario=ScenarioConfig(
        size_m=10.0, step_m=0.25, azimuth_step_deg=2.0, duration_s=0.005, min_receiver_spacing_m=3.0
    ),
    attacker=AttackerModel(min_distance_m=3.0),
    n_targets=8,
    path_packets=120,
    seed=2,
)


def test_parse_experiments():
    assert parse_experiments([]) == ("match", "pattern", "path", "e2e")
    assert parse_experiments(["4", "1", "match"]) == ("match", "e2e")
    with pytest.raises(InputError, match="unknown experiment"):
        parse_experiments(["5"])
    assert plan_tasks(("path", "e2e"), 2) == [("e2e", 0), ("e2e", 1)]


def test_mean_ci95_is_student_t():
    m, h = mean_ci95([0.5, 0.6])
    assert m == pytest.approx(0.55)
    assert h == pytest.approx(12.7062047 * np.std([0.5, 0.6], ddof=1) / math.sqrt(2), rel=1e-6)
    assert math.isnan(mean_ci95([0.5])[1])


@pytest.fixture(scope="module")
def e2e_run():
    return run_experiment("e2e", 0, SMALL)


def test_path_attack_chain_obeys_the_limits(e2e_run):
    # Recompute the chain's poses from the trace and check every hop.
    attack = [r for r in e2e_run.tables["end_to_end"] if r["source"] == "attack"]
    assert len(attack) >= 10  # this seed has a sustained attack to check
    t = np.array([r["timestamp_s"] for r in attack])
    xy = np.array([[r["sender_x_m"], r["sender_y_m"]] for r in attack])
    az = np.array([r["sender_azimuth_deg"] for r in attack])
    dt = np.diff(t)
    assert np.all(dt > 0) and np.all(dt <= 0.25 + 1e-9)  # never silent past t/2
    assert np.all(np.linalg.norm(np.diff(xy, axis=0), axis=1) <= 10.0 * dt + 1e-9)
    assert np.all(np.abs(angle_diff_deg(az[1:], az[:-1])) <= 360.0 * dt + 1e-9)
    # every sender pose is at least d from the pose it spoofs
    spoofed = np.array([[r["spoofed_x_m"], r["spoofed_y_m"]] for r in attack])
    assert np.all(np.linalg.norm(xy - spoofed, axis=1) >= 3.0 - 0.25)  # grid snap margin
    # power within range
    assert np.all(np.abs([r["power_offset_db"] for r in attack]) <= 10.0 + 1e-9)


def test_path_attack_outcome_and_tracker_bounds(e2e_run):
    paths = {r["limit_scale"]: r for r in e2e_run.tables["paths"]}
    # stricter limits can never sustain an attack longer
    assert paths[0.1]["packets_until_failure"] <= paths[1.0]["packets_until_failure"]
    # seeded: this attack is sustained for a while and then fails (margins around 56 / 106)
    assert 30 <= paths[1.0]["sustained_packets"] <= 90
    assert paths[1.0]["failed"] == 1
    assert paths[1.0]["packets_until_failure"] == paths[1.0]["sustained_packets"] + 50
    summary = {r["source"]: r for r in e2e_run.tables["end_to_end_summary"]}
    # the tracker follows the genuine device on the same path (observed 0.22 m)
    assert summary["genuine"]["median_error_to_spoofed_m"] <= 0.6
    assert summary["genuine"]["within_radius_fraction"] >= 0.8
    # the spoofed packets never make the tracker follow beyond the attack's own span
    assert summary["attack"]["followed_s"] <= summary["attack"]["span_s"] + 1e-9


def test_match_experiment_rows_and_summary():
    outs = [run_experiment("match", r, SMALL) for r in range(2)]
    tables = collect(outs)
    rows = tables["targets"]
    assert len(rows) == 2 * SMALL.n_targets
    for r in rows:
        assert r["matched"] == int(r["n_match_candidates"] > 0)
        if r["matched"]:
            assert r["best_distance_m"] >= 3.0 - 1e-9
            assert abs(r["best_offset_db"]) <= 10.0 + 1e-9
            assert r["best_mse_db2"] <= r["threshold_db2"]
    summ = {(s["experiment"], s["metric"]): s for s in summarise(tables, ("match",))}
    p = summ[("match", "p_at_least_one_match")]
    per_run = [np.mean([r["matched"] for r in rows if r["run"] == j]) for j in (0, 1)]
    assert p["value"] == pytest.approx(np.mean(per_run))
    assert p["paper_value"] == 0.522 and p["n_runs"] == 2


def test_cli_spoof_writes_tables_figures_and_report(tmp_path, capsys):
    out = tmp_path / "spoof"
    code = main(
        [
            "spoof",
            "1",
            "--runs",
            "2",
            "--targets",
            "4",
            "--size-m",
            "8",
            "--step-m",
            "0.5",
            "--azimuth-step-deg",
            "10",
            "--min-distance-m",
            "2",
            "--workers",
            "0",
            "-q",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    for name in (
        "targets.csv",
        "summary.csv",
        "report.md",
        "match-probability.png",
        "sites.csv",
        "timings.csv",
    ):
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    assert "0.522 ± 0.040" in report and "radiopose spoof 1 --runs 2" in report
    assert "p_at_least_one_match" in capsys.readouterr().out


def test_cli_spoof_errors_are_one_line(tmp_path, capsys):
    code = main(["spoof", "7", "-o", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "unknown experiment" in err
    code = main(["spoof", "--runs", "0", "-o", str(tmp_path / "x")])
    assert code == 2 and "--runs" in capsys.readouterr().err


def test_cli_spoof_refuses_an_unusable_output_before_any_run(tmp_path, capsys, monkeypatch):
    """``-o`` naming a file, a path below a file, or a directory where one of its
    files goes is a one-line error before the first run; it was found only when
    writing, after the whole experiment (``spoof detect --quick`` ran 46 s, then said
    'File exists'; ``spoof 1`` finished a run, then said 'afile/parts: Not a directory')."""
    import radiopose.security.detect_experiment as detect
    import radiopose.security.runner as runner

    def no_run(*args, **kwargs):
        raise AssertionError("a run started before the output directory was checked")

    monkeypatch.setattr(runner, "map_runs", no_run)
    monkeypatch.setattr(detect, "run_tracks", no_run)
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    (tmp_path / "d" / "report.md").mkdir(parents=True)
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "parts").write_text("mine\n")
    (tmp_path / "f" / "roc.csv").mkdir(parents=True)
    one = ["--runs", "1", "--targets", "1", "--workers", "0"]
    cases = [
        (["spoof", "1", *one, "-o", str(afile)], f"{afile}: is a file, expected a directory"),
        (
            ["spoof", "detect", "--quick", "--workers", "0", "-o", str(afile)],
            f"{afile}: is a file, expected a directory",
        ),
        (
            ["spoof", "1", *one, "-o", str(afile / "sub")],
            f"{afile / 'sub'}: cannot create: a parent is not a directory",
        ),
        (
            ["spoof", "1", *one, "-o", str(tmp_path / "d")],
            f"{tmp_path / 'd' / 'report.md'}: is a directory, expected a file path",
        ),
        (
            ["spoof", "1", *one, "-o", str(tmp_path / "e")],
            f"{tmp_path / 'e' / 'parts'}: is a file, expected a directory",
        ),
        (
            ["spoof", "detect", "--quick", "--workers", "0", "-o", str(tmp_path / "f")],
            f"{tmp_path / 'f' / 'roc.csv'}: is a directory, expected a file path",
        ),
    ]
    for args, message in cases:
        assert main(args) == 2, args
        assert capsys.readouterr().err == f"radiopose: {message}\n", args
    assert afile.read_text() == "mine\n" and (tmp_path / "e" / "parts").read_text() == "mine\n"
    assert sorted(p.name for p in tmp_path.rglob("*")) == [
        "afile", "d", "e", "f", "parts", "report.md", "roc.csv"
    ]  # fmt: skip


TINY_SPOOF = ["--runs", "1", "--targets", "2", "--size-m", "8", "--step-m", "0.5"]
TINY_SPOOF += ["--azimuth-step-deg", "10", "--min-distance-m", "2", "--workers", "0"]


def test_cli_spoof_never_removes_files_it_did_not_write(tmp_path, capsys, monkeypatch):
    """``spoof 1 -o .`` removed every file of its output names it had not written
    this time, so a directory that never held a spoof run lost the user's
    paths.csv, end_to_end.csv, path-failure.png and end-to-end.png. Only files
    the previous run's manifest lists may go: here none, on either run."""
    monkeypatch.chdir(tmp_path)
    mine = ["paths.csv", "end_to_end.csv", "path-failure.png", "end-to-end.png"]
    for name in mine:
        (tmp_path / name).write_text("mine\n")
    for _ in range(2):  # the second run has the first one's manifest
        assert main(["spoof", "1", *TINY_SPOOF, "-o", "."]) == 0
        assert "removed" not in capsys.readouterr().err
        assert [(tmp_path / name).read_text() for name in mine] == ["mine\n"] * 4


def test_cli_spoof_rerun_with_fewer_experiments_leaves_only_its_own_outputs(
    tmp_path, capsys, monkeypatch
):
    """Running ``spoof 1`` into the directory of an earlier ``spoof 1 3`` rewrote
    report.md and summary.csv for experiment 1 but left paths.csv and
    path-failure.png beside them, which the report did not cover. The files the
    earlier run's manifest lists and this run did not write go, with a note
    naming them (read from ``-o .``); parts/ and other files stay."""
    monkeypatch.chdir(tmp_path)
    assert main(["spoof", "1", "3", *TINY_SPOOF, "-o", "."]) == 0
    first = {p.name for p in tmp_path.iterdir()}
    assert {"paths.csv", "path-failure.png", ".radiopose-spoof-outputs.json"} <= first
    (tmp_path / "notes.txt").write_text("mine\n")
    parts = sorted(p.name for p in (tmp_path / "parts").iterdir())
    capsys.readouterr()
    assert main(["spoof", "1", *TINY_SPOOF, "-o", "."]) == 0
    err = capsys.readouterr().err
    assert {p.name for p in tmp_path.iterdir()} == first - {"paths.csv", "path-failure.png"} | {
        "notes.txt"
    }
    assert sorted(p.name for p in (tmp_path / "parts").iterdir()) == parts
    assert (
        "spoof: removed path-failure.png, paths.csv: the previous spoof run into this "
        "directory wrote them and this one did not, so they are not in its report; that "
        "run's results stay in parts/, from which the earlier command, run again, resumes them"
    ) in err.splitlines()
    # nothing stale: no note
    assert main(["spoof", "1", *TINY_SPOOF, "-o", "."]) == 0
    assert "removed" not in capsys.readouterr().err


def test_cli_spoof_does_not_remove_a_listed_file_replaced_by_a_link(tmp_path, capsys):
    """A file the previous run wrote (so listed in its manifest) that is now a
    symbolic link is the user's: the link and the file it names stay; the
    other stale file goes, and the note names only it."""
    out = tmp_path / "spoof"
    assert main(["spoof", "1", "3", *TINY_SPOOF, "-o", str(out)]) == 0
    elsewhere = tmp_path / "mine.png"
    elsewhere.write_text("mine\n")
    (out / "path-failure.png").unlink()
    (out / "path-failure.png").symlink_to(elsewhere)
    capsys.readouterr()
    assert main(["spoof", "1", *TINY_SPOOF, "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert (out / "path-failure.png").is_symlink() and elsewhere.read_text() == "mine\n"
    assert not (out / "paths.csv").exists()
    assert f"spoof: removed {out / 'paths.csv'}: the previous spoof run" in err


def test_cli_spoof_resumes_finished_runs(tmp_path, capsys, monkeypatch):
    import radiopose.security.runner as runner

    out = tmp_path / "spoof"
    args = ["spoof", "1", "--runs", "2", "--targets", "3", "--size-m", "8", "--step-m", "0.5"]
    args += ["--azimuth-step-deg", "10", "--min-distance-m", "2", "--workers", "0", "-o", str(out)]
    assert main(args) == 0
    first = (out / "targets.csv").read_text()
    assert sorted(p.name for p in (out / "parts").iterdir()) == ["match-000.json", "match-001.json"]
    # a killed run: one part missing, one left half-written by something else
    (out / "parts" / "match-001.json").unlink()
    (out / "parts" / "match-000.json").write_text('{"key": "other settings"')
    computed: list[list] = []
    real = runner.map_runs

    def spy(tasks, *a, **kw):
        computed.append(list(tasks))
        return real(tasks, *a, **kw)

    monkeypatch.setattr(runner, "map_runs", spy)
    capsys.readouterr()
    assert main(args) == 0
    assert computed == [[("match", 0), ("match", 1)]]  # nothing usable was stored
    assert (out / "targets.csv").read_text() == first
    # everything stored now: a third call computes nothing and writes the same tables
    assert main(args) == 0
    assert computed == [[("match", 0), ("match", 1)]]
    assert "resuming: 2 of 2 runs" in capsys.readouterr().err
    assert (out / "targets.csv").read_text() == first
    # other settings do not reuse the stored runs
    assert main([*args[:5], "4", *args[6:]]) == 0
    assert computed[-1] == [("match", 0), ("match", 1)]
