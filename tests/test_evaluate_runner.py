"""Runner: tidy rows, identical results on a 2-worker Dask cluster, resume after interruption."""

from __future__ import annotations

import time

import pytest

from radiopose.evaluate.experiments import parse_experiment
from radiopose.evaluate.runner import (
    TIMING_COLUMNS,
    collect,
    plan,
    run_experiments,
    write_results,
)

pd = pytest.importorskip("pandas")  # the eval extra
pytest.importorskip("distributed")

# A tiny experiment: 6 m area, 0.5 m grid, 10 packets per run.
DOC = {
    "name": "tiny",
    "seed": 4711,
    "runs": 2,
    "methods": ["full", "top", "lms"],
    "scenario": {"size_m": 6.0, "step_m": 0.5, "duration_s": 0.05, "min_receiver_spacing_m": 2.0},
    "sweep": {"scenario": {"noise_db": [0.5, 3.0]}},
}


def _tiny():
    return parse_experiment(DOC, "tiny.toml")


def _tiny_toml(
    name: str = "tiny", runs: int = 2, methods: str = '"full", "top", "lms"', sweep: bool = True
) -> str:
    """``DOC`` as an experiment file (the CLI tests), with a figure when swept."""
    text = (
        f'name = "{name}"\nseed = 4711\nruns = {runs}\nmethods = [{methods}]\n'
        "[scenario]\nsize_m = 6.0\nstep_m = 0.5\nduration_s = 0.05\n"
        "min_receiver_spacing_m = 2.0\n"
    )
    if sweep:
        text += (
            "[sweep]\nscenario.noise_db = [0.5, 3.0]\n"
            '[[figure]]\nkind = "error"\nx = "noise_db"\nquantity = "position"\n'
        )
    return text


def _comparable(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    return run_experiments([_tiny()], out, workers=0), out


def test_serial_rows_are_tidy(serial):
    run, out = serial
    df = run.results
    assert run.n_tasks == 4 and run.n_resumed == 0 and run.scheduler == "serial"
    assert len(df) == 4 * 3
    assert list(df["method"][:3]) == ["full", "top", "lms"]
    assert set(df["noise_db"]) == {0.5, 3.0}
    assert (df["n_packets"] == 10).all()
    assert df.loc[df["method"] == "top", "coverage"].eq(1.0).all()
    assert df.loc[df["method"] == "lms", "orientation_mean_deg"].isna().all()
    for col in (
        "experiment",
        "condition",
        "seed",
        "method",
        "position_mean_m",
        "position_median_m",
        "position_p95_m",
        "orientation_mean_deg",
        "orientation_median_deg",
        "orientation_p95_deg",
        "coverage",
        "run_time_s",
    ):
        assert col in df.columns
    # Both runs of a condition differ; the same run has the same seed in each condition.
    seeds = df[df["method"] == "top"].groupby("noise_db")["seed"].apply(list)
    assert seeds[0.5] == seeds[3.0] and len(set(seeds[0.5])) == 2
    csv_path, pq_path = write_results(df, out)
    back = pd.read_parquet(pq_path)
    pd.testing.assert_frame_equal(back, df)
    assert len(pd.read_csv(csv_path)) == len(df)


def test_two_dask_workers_give_the_serial_results(serial, tmp_path):
    t0 = time.perf_counter()
    run = run_experiments([_tiny()], tmp_path, workers=2)
    assert time.perf_counter() - t0 < 60
    assert run.workers == 2 and run.scheduler == "local"
    pd.testing.assert_frame_equal(_comparable(run.results), _comparable(serial[0].results))


def test_interrupted_run_resumes_without_redoing_finished_runs(serial, tmp_path):
    calls = []

    def stop_after_two(done, total, what):
        calls.append(done)
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_experiments([_tiny()], tmp_path, workers=0, progress=stop_after_two)
    part = tmp_path / "parts" / "tiny.csv"
    assert len(pd.read_csv(part)) == 2 * 3
    # A torn last line (killed mid-write) is discarded, not read as a result.
    with open(part, "a", encoding="utf-8") as fh:
        fh.write("tiny,noise_db=3,1,0,123,full,3.0")
    done = []
    run = run_experiments(
        [_tiny()], tmp_path, workers=0, progress=lambda d, t, w: done.append((d, w))
    )
    assert run.n_resumed == 2
    assert done[0] == (2, "resumed") and len(done) == 1 + 2
    pd.testing.assert_frame_equal(_comparable(run.results), _comparable(serial[0].results))
    # A finished run resumes everything and computes nothing.
    again = run_experiments([_tiny()], tmp_path, workers=0)
    assert again.n_resumed == 4
    pd.testing.assert_frame_equal(again.results, run.results)


def test_a_damaged_part_file_is_an_error_naming_its_line(serial, tmp_path):
    """A line inside the part file that is not a result row (a hand edit, a
    damaged disk) is not dropped silently (it once turned integer columns of
    results.csv into floats): the run stops at that line, nothing is computed."""
    from radiopose.errors import InputError

    run_experiments([_tiny()], tmp_path, workers=0)
    part = tmp_path / "parts" / "tiny.csv"
    good = part.read_text(encoding="utf-8")
    part.write_text(good + "garbage,row\n", encoding="utf-8")
    n_lines = good.count("\n") + 1
    with pytest.raises(InputError, match=rf"tiny\.csv:{n_lines}: not a result row"):
        run_experiments([_tiny()], tmp_path, workers=0)
    assert part.read_text(encoding="utf-8") == good + "garbage,row\n"  # left as found


def test_bad_workers_write_nothing(tmp_path):
    from radiopose.errors import InputError

    with pytest.raises(InputError, match="--workers must be >= 0"):
        run_experiments([_tiny()], tmp_path / "out", workers=-2)
    assert not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_writes_nothing(tmp_path):
    """The part files begin with the first finished run: a scheduler that cannot
    be reached leaves no directory or header-only file behind (it once left
    ``parts/<experiment>.csv`` with only its header)."""
    from radiopose.errors import InputError

    with pytest.raises(InputError, match="--scheduler notaurl: cannot connect"):
        run_experiments([_tiny()], tmp_path / "out", scheduler="notaurl")
    assert not (tmp_path / "out").exists()


def test_an_unusable_output_is_refused_before_any_run(tmp_path, capsys, monkeypatch):
    """``-o`` naming a file, a path below a file, or a directory where one of its
    outputs goes is a one-line error before the first run; it was found only when
    the first run's rows were written ('afile/parts: Not a directory'). Nothing is
    created, as with an unreachable scheduler."""
    from radiopose.cli import main
    from radiopose.evaluate import runner

    def no_run(task):
        raise AssertionError("a run started before the output directory was checked")

    monkeypatch.setattr(runner, "run_task", no_run)
    exp = tmp_path / "tiny.toml"
    exp.write_text(_tiny_toml(runs=1, methods='"lms"', sweep=False), encoding="utf-8")
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "parts").write_text("mine\n")
    (tmp_path / "e" / "parts" / "tiny.csv").mkdir(parents=True)
    (tmp_path / "f" / "report.md").mkdir(parents=True)
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "figures").write_text("mine\n")
    cases = {
        afile: f"{afile}: is a file, expected a directory",
        afile / "x": f"{afile / 'x'}: cannot create: a parent is not a directory",
        tmp_path / "d": f"{tmp_path / 'd' / 'parts'}: is a file, expected a directory",
        tmp_path / "e": f"{tmp_path / 'e' / 'parts' / 'tiny.csv'}: is a directory, "
        "expected a file path",
        tmp_path / "f": f"{tmp_path / 'f' / 'report.md'}: is a directory, expected a file path",
        tmp_path / "g": f"{tmp_path / 'g' / 'figures'}: is a file, expected a directory",
    }
    before = sorted(tmp_path.rglob("*"))
    for out, message in cases.items():
        assert main(["evaluate", str(exp), "--workers", "0", "-q", "-o", str(out)]) == 2, out
        assert capsys.readouterr().err == f"radiopose: {message}\n", out
    assert sorted(tmp_path.rglob("*")) == before  # nothing created
    # the library checks its part files too
    with pytest.raises(NotADirectoryError, match="is a file, expected a directory"):
        run_experiments([_tiny()], afile, workers=0)


def _two_experiments(tmp_path) -> tuple[str, str]:
    """Experiments ``a`` and ``b``, one run each, each with one figure."""
    for name in ("a", "b"):
        (tmp_path / f"{name}.toml").write_text(
            _tiny_toml(name, runs=1, methods='"lms"'), encoding="utf-8"
        )
    return str(tmp_path / "a.toml"), str(tmp_path / "b.toml")


def test_cli_evaluate_rerun_with_fewer_experiments_keeps_only_its_figures(tmp_path, capsys):
    """Running one experiment into the directory of an earlier run of two rewrote
    results.csv and the report for the one, but left the other's figures in
    figures/, which the report did not show. The files the earlier run's manifest
    lists and this run did not write now go, with a note naming them; parts/ and
    files the earlier run did not write (the user's own PNG too) stay."""
    from radiopose.cli import main

    a, b = _two_experiments(tmp_path)
    out = tmp_path / "out"
    figures = out / "figures"
    figures.mkdir(parents=True)
    (figures / "mine.png").write_text("mine\n")
    assert main(["evaluate", a, b, "--workers", "0", "-q", "-o", str(out)]) == 0
    assert sorted(p.name for p in figures.iterdir()) == [
        "a-error_position_vs_noise_db.png",
        "b-error_position_vs_noise_db.png",
        "mine.png",
    ]
    (figures / "notes.txt").write_text("mine\n")
    capsys.readouterr()
    assert main(["evaluate", a, "--workers", "0", "-q", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert sorted(p.name for p in figures.iterdir()) == [
        "a-error_position_vs_noise_db.png",
        "mine.png",
        "notes.txt",
    ]
    assert (
        f"evaluate: removed {figures / 'b-error_position_vs_noise_db.png'}: the previous "
        "evaluate run into this directory wrote it and this one did not, so it is not in its "
        f"report; that run's results stay in {out / 'parts'}/, from which the earlier "
        "command, run again, resumes them"
    ) in err.splitlines()
    assert sorted(p.name for p in (out / "parts").iterdir()) == ["a.csv", "b.csv"]
    assert "b-error" not in (out / "report.md").read_text(encoding="utf-8")
    assert main(["evaluate", a, "--workers", "0", "-q", "-o", str(out)]) == 0
    assert "removed" not in capsys.readouterr().err


def test_cli_evaluate_does_not_follow_a_linked_figures_directory(tmp_path, capsys):
    """With DIR/figures a symbolic link (to ~/Pictures, say), a run removed every
    PNG there it had not written, the user's own included. Now the figures are
    written through the link as before, but nothing below it is removed: neither
    the user's PNG nor the earlier run's figure its manifest lists."""
    from radiopose.cli import main

    a, b = _two_experiments(tmp_path)
    pictures = tmp_path / "Pictures"
    pictures.mkdir()
    (pictures / "holiday.png").write_text("mine\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "figures").symlink_to(pictures)
    assert main(["evaluate", a, b, "--workers", "0", "-q", "-o", str(out)]) == 0
    assert main(["evaluate", a, "--workers", "0", "-q", "-o", str(out)]) == 0
    assert "removed" not in capsys.readouterr().err
    assert sorted(p.name for p in pictures.iterdir()) == [
        "a-error_position_vs_noise_db.png",
        "b-error_position_vs_noise_db.png",
        "holiday.png",
    ]
    assert (pictures / "holiday.png").read_text() == "mine\n"


def test_issue_15s_anchor_runs_beside_the_methods_and_leaves_the_registry(tmp_path):
    """``textbook`` (issue 15's anchor, evaluation only) may be listed in an
    experiment's methods: each run registers it told that run's σ, it gets its
    rows, and the registry is as before (no site or front end can run it)."""
    from radiopose.evaluate.experiments import ANCHOR
    from radiopose.evaluate.figures import METHOD_STYLE
    from radiopose.tracker import METHODS

    exp = parse_experiment({**DOC, "runs": 1, "methods": ["full", ANCHOR]}, "tiny.toml")
    run = run_experiments([exp], tmp_path, workers=0)
    rows = run.results[run.results["method"] == ANCHOR]
    assert sorted(rows["noise_db"]) == [0.5, 3.0]
    assert (rows["coverage"] > 0.9).all() and rows["orientation_mean_deg"].notna().all()
    assert ANCHOR not in METHODS
    # its own colour and marker in the figures (not the fallback's, which filter had)
    assert len({METHOD_STYLE[m] for m in ("full", "top", "lms", "filter", ANCHOR)}) == 5


def test_changed_config_does_not_reuse_stale_rows(serial, tmp_path):
    run_experiments([_tiny()], tmp_path, workers=0)
    doc = {**DOC, "scenario": {**DOC["scenario"], "duration_s": 0.04}}
    changed = parse_experiment(doc, "tiny.toml")
    run = run_experiments([changed], tmp_path, workers=0)
    assert run.n_resumed == 0
    assert (run.results["n_packets"] == 8).all()
    assert len(collect(tmp_path, [changed], plan([changed]))) == 12


def test_cli_evaluate_writes_results_and_report(tmp_path, capsys):
    from radiopose.cli import main

    exp = tmp_path / "tiny.toml"
    exp.write_text(_tiny_toml(), encoding="utf-8")
    out = tmp_path / "out"
    assert main(["evaluate", str(exp), "--workers", "0", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "4 runs (0 resumed)" in err and "evaluate: 4/4" in err
    for name in ("results.csv", "results.parquet", "report.md", "report.html"):
        assert (out / name).exists(), name
    md = (out / "report.md").read_text(encoding="utf-8")
    assert f"radiopose evaluate {exp} --workers 0 -o {out}" in md
    assert (out / "figures" / "tiny-error_position_vs_noise_db.png").exists()
    assert len(pd.read_csv(out / "results.csv")) == 12
    # Running it again resumes everything.
    assert main(["evaluate", str(exp), "--workers", "0", "-o", str(out), "-q"]) == 0
    assert "4 runs (4 resumed)" in capsys.readouterr().err
