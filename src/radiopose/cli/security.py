"""``radiopose spoof``: the paper's spoofing experiments (``docs/security.md``)."""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app


@app.command(short_help="Run the spoofing experiments; write a report.")
def spoof(
    experiments: Annotated[
        list[str] | None,
        typer.Argument(
            help="Experiments to run: 1 match, 2 pattern, 3 path, 4 e2e (default: all); "
            "or 'detect' alone: the spoofing detector's ROC (DIR/detection.csv)."
        ),
    ] = None,
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")] = Path(
        "radiopose-spoof"
    ),
    runs: Annotated[
        int | None, typer.Option(help="Runs per experiment (default 20; 3 with --quick).")
    ] = None,
    quick: Annotated[
        bool, typer.Option("--quick", help="A fast look: 3 runs, 25 targets, ≤ 200-packet paths.")
    ] = False,
    targets: Annotated[
        int | None, typer.Option(help="Random targets per run (experiments 1–2; default 100).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Base seed; run j simulates its site with seed+j.")] = 0,
    min_distance_m: Annotated[
        float, typer.Option("--min-distance-m", help="d: attacker at least this far, m.")
    ] = 5.0,
    power_range_db: Annotated[
        float, typer.Option("--power-range-db", help="Attacker power within P_tx ± this, dB.")
    ] = 10.0,
    target_noise_db: Annotated[
        float,
        typer.Option("--target-noise-db", help="σ of noise on the target RSS (0: expected RSS)."),
    ] = 0.0,
    size_m: Annotated[
        float, typer.Option("--size-m", help="Side of the simulated area, m.")
    ] = 20.0,
    step_m: Annotated[float, typer.Option("--step-m", help="Candidate grid step, m.")] = 0.1,
    azimuth_step_deg: Annotated[
        float, typer.Option("--azimuth-step-deg", help="Candidate azimuth step, degrees.")
    ] = 1.0,
    workers: Annotated[
        int | None,
        typer.Option(help="Local Dask worker processes (default: all cores; 0: this process)."),
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Address of an existing Dask scheduler (tcp://host:8786).")
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Spoofing experiments: match probability, different pattern, path attack, end to end.

    Writes tidy CSVs (targets, paths, end_to_end, summary, …), PNG figures and
    report.md into DIR, and prints the summary. ``radiopose spoof detect``
    instead runs the spoofing detector against four attacks and genuine
    traffic and writes DIR/detection.csv and DIR/roc.csv (docs/security.md).
    """
    if experiments and experiments[0].strip().lower() == "detect":
        if len(experiments) > 1:
            from radiopose.errors import InputError

            raise InputError("spoof detect takes no experiment names: run it on its own")
        _spoof_detect(out, quick, runs, seed, workers, quiet)
        return
    from contextlib import nullcontext
    from dataclasses import replace

    from radiopose.cli import count_progress
    from radiopose.errors import InputError
    from radiopose.security.experiments import (
        RunOutput,
        SpoofConfig,
        parse_experiments,
        plan_tasks,
    )
    from radiopose.security.figures import make_figures
    from radiopose.security.report import (
        collect,
        output_names,
        render_report,
        summarise,
        write_report,
        write_tables,
    )
    from radiopose.security.runner import RunStore, default_workers, map_runs
    from radiopose.simulate import ScenarioConfig
    from radiopose.tables import check_output_dir, removed_outputs_note, replace_outputs

    exps = parse_experiments(tuple(experiments or ()))
    n_runs = runs if runs is not None else (3 if quick else 20)
    if n_runs < 1:
        raise InputError(f"--runs must be at least 1, got {n_runs}")
    if min_distance_m < 0 or power_range_db < 0:
        raise InputError("--min-distance-m and --power-range-db must be >= 0")
    scenario = ScenarioConfig(
        size_m=size_m,
        step_m=step_m,
        azimuth_step_deg=azimuth_step_deg,
        duration_s=0.005,
        min_receiver_spacing_m=min(4.0, size_m / 4),
    )
    scenario.validate()
    from radiopose.security.attacker import AttackerModel

    config = SpoofConfig(
        scenario=scenario,
        attacker=AttackerModel(min_distance_m, power_range_db),
        target_noise_db=target_noise_db,
        seed=seed,
    )
    if quick:
        config = config.quick()
    if targets is not None:
        if targets < 1:
            raise InputError(f"--targets must be at least 1, got {targets}")
        config = replace(config, n_targets=targets)
    check_output_dir(out, output_names(), subdirs=("parts",))  # before the runs, not after
    tasks = plan_tasks(exps, n_runs)
    n_workers = default_workers() if workers is None else workers
    t0 = time.perf_counter()
    store = RunStore(out, config)
    stored = store.load(tasks)
    todo = [t for t in tasks if t not in stored]
    if stored and not quiet:
        print(
            f"spoof: resuming: {len(stored)} of {len(tasks)} runs already in {store.dir}",
            file=sys.stderr,
        )
    show = not quiet and sys.stderr.isatty()
    done = [len(stored)]
    with count_progress(f"spoof ({', '.join(exps)})") if show else nullcontext() as bar:
        task = None if bar is None else bar.add_task("runs", total=len(tasks), completed=done[0])

        def finished(res: RunOutput) -> None:
            store.save(res)  # as each run completes: an interrupted command resumes here
            done[0] += 1
            if bar is not None:
                bar.advance(task)
            elif not quiet:  # a log file, CI: one line per finished run
                print(
                    f"spoof: {done[0]}/{len(tasks)} {res.experiment} run {res.run} "
                    f"({res.elapsed_s:.0f} s)",
                    file=sys.stderr,
                    flush=True,
                )

        if todo:
            computed, where = map_runs(todo, config, n_workers, finished, scheduler)
        else:
            computed, where = [], "nothing left to compute (every run resumed)"
    by_task = {**stored, **{(r.experiment, r.run): r for r in computed}}
    outputs = [by_task[t] for t in tasks]
    wall = time.perf_counter() - t0
    tables = collect(outputs)
    summary = summarise(tables, exps)
    out.mkdir(parents=True, exist_ok=True)
    written = write_tables(out, tables, summary)
    figures = make_figures(tables, summary, out)
    parts = ["radiopose", "spoof", *(experiments or []), "--runs", str(n_runs)]
    parts += ["--quick"] if quick else []
    defaults = {
        "--targets": (targets, None),
        "--seed": (seed, 0),
        "--min-distance-m": (min_distance_m, 5.0),
        "--power-range-db": (power_range_db, 10.0),
        "--target-noise-db": (target_noise_db, 0.0),
        "--size-m": (size_m, 20.0),
        "--step-m": (step_m, 0.1),
        "--azimuth-step-deg": (azimuth_step_deg, 1.0),
    }
    for flag, (value, default) in defaults.items():
        if value != default:
            parts += [flag, f"{value:g}"]
    command = shlex.join([*parts, "-o", str(out)])
    text = render_report(
        summary, tables, config, exps, n_runs, command, [f.name for f in figures], wall, where
    )
    report = write_report(out / "report.md", text)
    # What the previous run into out wrote and this one did not (other experiments, a
    # table left empty) goes, so that the directory is this report's: only files its
    # manifest lists, never the user's; parts/ stays (the earlier runs stay resumable).
    stale = replace_outputs(out, "spoof", [*written, *figures, report])
    for r in summary:
        ci = f" ± {r['ci95']:.3f}" if r["ci95"] == r["ci95"] else ""
        print(f"{r['experiment']:<8} {r['metric']:<44} {r['value']:.3f}{ci}")
    print(
        f"wrote {len(written)} tables, {len(figures)} figures and {report} in {wall:.0f} s",
        file=sys.stderr,
    )
    if stale:
        print(removed_outputs_note("spoof", out, stale), file=sys.stderr)


def _spoof_detect(
    out: Path, quick: bool, runs: int | None, seed: int, workers: int | None, quiet: bool
) -> None:
    """``radiopose spoof detect``: attacks and genuine traffic through the detector;
    writes ``DIR/detection.csv`` and ``DIR/roc.csv`` (docs/security.md)."""
    from dataclasses import replace

    from radiopose.errors import InputError
    from radiopose.security.detect_experiment import (
        DETECTION_COLUMNS,
        DetectPlan,
        detection_rows,
        genuine_hours,
        roc_rows,
        run_tracks,
        write_csv,
    )
    from radiopose.security.detection import DetectorConfig
    from radiopose.security.runner import default_workers
    from radiopose.tables import check_output_dir

    plan = DetectPlan.quick(20_000 + seed) if quick else DetectPlan(seed=20_000 + seed)
    if runs is not None:
        if runs < 1:
            raise InputError(f"--runs must be at least 1, got {runs}")
        plan = replace(plan, attack_runs=runs)
    check_output_dir(out, ["detection.csv", "roc.csv"])  # before the runs, not after
    n_workers = default_workers() if workers is None else workers
    t0 = time.perf_counter()
    n_tasks = len(plan.sigmas_db) * (len(plan.attacks) * plan.attack_runs + plan.genuine_chunks)
    done = [0]

    def finished(track: object) -> None:
        done[0] += 1
        if not quiet and (done[0] % 10 == 0 or done[0] == n_tasks):
            print(
                f"spoof detect: {done[0]}/{n_tasks} tracks ({time.perf_counter() - t0:.0f} s)",
                file=sys.stderr,
                flush=True,
            )

    tracks = run_tracks(plan, n_workers, finished)
    config = DetectorConfig()
    rows = detection_rows(tracks, config, plan.window_s)
    base = config.threshold_nats
    sweep = sorted({base * f for f in (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0)})
    roc = roc_rows(tracks, config, sweep, plan.window_s)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "detection.csv", rows, DETECTION_COLUMNS)
    write_csv(out / "roc.csv", roc, ("threshold_nats", *DETECTION_COLUMNS))
    for r in rows:
        delay, alarms = r["median_detection_delay_s"], r["false_alarms_per_hour"]
        print(
            f"{r['attack']:<7} σ={r['sigma_db']:<4g} runs={r['runs']:<3} "
            f"P(detect ≤ {plan.window_s:g} s)={r['detection_probability']:.2f} "
            + (f"delay={delay:.3f} s " if delay == delay else "delay=– (none detected) ")
            + (f"false alarms/h={alarms:.2f}" if alarms == alarms else "false alarms/h=–")
        )
    hours = ", ".join(f"σ {s:g}: {genuine_hours(tracks, s) * 60:.1f} min" for s in plan.sigmas_db)
    print(
        f"genuine traffic behind the false-alarm rates: {hours}; wrote {out / 'detection.csv'} "
        f"and {out / 'roc.csv'} in {time.perf_counter() - t0:.0f} s",
        file=sys.stderr,
    )
