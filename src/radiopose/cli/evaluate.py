"""``radiopose evaluate``: the paper's experiments (or your own) on Dask, with a report."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app


def _version() -> str:
    """radiopose version, with the git commit when run from a checkout."""
    import subprocess

    from radiopose import __version__

    root = Path(__file__).resolve().parents[3]
    try:
        r = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return __version__
    commit = r.stdout.strip()
    return f"{__version__} (commit {commit})" if r.returncode == 0 and commit else __version__


def _command(
    experiments: list[str],
    out: Path,
    runs: int | None,
    quick: bool,
    scheduler: str | None,
    workers: int | None,
) -> str:
    parts = ["radiopose", "evaluate", *experiments]
    if quick:
        parts.append("--quick")
    if runs is not None:
        parts += ["--runs", str(runs)]
    if scheduler is not None:
        parts += ["--scheduler", scheduler]
    if workers is not None:
        parts += ["--workers", str(workers)]
    parts += ["-o", str(out)]
    return " ".join(shlex.quote(p) for p in parts)


@app.command(short_help="Run the paper's evaluation; write a report.")
def evaluate(
    out: Annotated[
        Path, typer.Option("-o", "--out", help="Output directory (created; resumed if present).")
    ],
    experiments: Annotated[
        list[str] | None,
        typer.Argument(
            help="Shipped experiments (noise, receivers, interval, motion, bounds; beyond the "
            "paper: 3d, anchor) or experiment TOML files; default: the paper's five.",
            show_default=False,
        ),
    ] = None,
    runs: Annotated[
        int | None, typer.Option("--runs", help="Runs per condition (default: the file's).")
    ] = None,
    quick: Annotated[
        bool,
        typer.Option(
            "--quick", help="Fewer runs, conditions and shorter traces (each file's quick table)."
        ),
    ] = False,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", help="Address of an existing Dask scheduler (tcp://host:8786)."
        ),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            "--workers", help="Local Dask workers (default: all cores; 0 = in this process)."
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress output.")] = False,
) -> None:
    """Run experiments, then write results.csv/.parquet, figures and report.md/.html to DIR.

    Every run's rows are written as it finishes; running the same command again
    resumes, skipping finished runs.
    """
    from radiopose.errors import InputError
    from radiopose.evaluate.experiments import SHIPPED, load_experiment

    names = list(experiments or SHIPPED)
    if runs is not None and runs < 1:
        raise InputError(f"--runs must be at least 1, got {runs}")
    exps = [load_experiment(n, quick=quick, runs=runs) for n in names]
    try:
        import distributed  # noqa: F401
        import pandas  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as exc:
        raise InputError(
            f"radiopose evaluate needs {exc.name}: pip install 'radiopose[eval]'"
        ) from None
    from radiopose.evaluate.report import (
        Invocation,
        RunInfo,
        read_invocations,
        record_invocation,
        write_report,
    )
    from radiopose.evaluate.runner import plan, run_experiments, write_results
    from radiopose.tables import (
        check_output_dir,
        outputs_manifest,
        removed_outputs_note,
        replace_outputs,
    )

    # Before any run (run_experiments checks parts/): nothing is created here.
    outputs = ["results.csv", "results.parquet", "report.md", "report.html", "invocations.jsonl"]
    check_output_dir(out, [*outputs, outputs_manifest("evaluate")], subdirs=["figures"])
    command = _command(list(experiments or []), out, runs, quick, scheduler, workers)
    show_bar = not quiet and sys.stderr.isatty()
    if show_bar:
        from radiopose.cli import count_progress

        with count_progress("evaluate", description=True) as bar:
            task_id = bar.add_task("starting", total=None)

            def progress(done: int, total: int, what: str) -> None:
                bar.update(task_id, completed=done, total=total, description=what)

            result = run_experiments(
                exps, out, scheduler=scheduler, workers=workers, progress=progress
            )
    else:

        def progress(done: int, total: int, what: str) -> None:
            if not quiet:
                print(f"evaluate: {done}/{total} {what}", file=sys.stderr, flush=True)

        result = run_experiments(exps, out, scheduler=scheduler, workers=workers, progress=progress)
    paths = write_results(result.results, out)
    record_invocation(
        out,
        Invocation(
            round(result.elapsed_s, 1),
            result.n_tasks - result.n_resumed,
            result.workers,
            result.scheduler,
        ),
    )
    info = RunInfo(command, _version(), quick, result.n_tasks, read_invocations(out))
    full = None
    if quick or runs is not None:
        full = plan([load_experiment(n) for n in names])
    report = write_report(result.results, exps, out, info, full_tasks=full)
    paths += report[:2]
    # What the previous run into out wrote and this one did not (other experiments'
    # figures) goes: only files its manifest lists; parts/ keeps every experiment's rows.
    stale = replace_outputs(out, "evaluate", [*paths, *report[2:]])
    print(
        f"{result.n_tasks} runs ({result.n_resumed} resumed) in {result.elapsed_s:.0f} s on "
        f"{result.workers or 'no'} worker{'s' if result.workers != 1 else ''} "
        f"({result.scheduler})",
        file=sys.stderr,
    )
    for p in paths:
        print(f"wrote {p}", file=sys.stderr)
    if stale:
        print(removed_outputs_note("evaluate", out, stale), file=sys.stderr)
