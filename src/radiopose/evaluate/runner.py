"""Running experiments: one task per (condition, run), on Dask, resumable.

A task (:class:`RunTask`) simulates one trace, runs every requested method on
that same trace (the pattern methods share one memoised likelihood scorer, so
each packet is scored once) and scores each method
(:func:`run_task` → one result row per method). Tasks are independent; they
run

* in this process (``workers=0``), or
* on a local Dask cluster (default: one single-threaded worker process per
  core, each with ``NUMBA_NUM_THREADS=1`` so that workers × numba threads
  does not oversubscribe the cores), or
* on an existing Dask cluster (``scheduler="tcp://host:8786"``; start its
  workers with ``NUMBA_NUM_THREADS=1`` and ``--nthreads 1`` for the same reason).

Seeds: run ``i`` of an experiment uses :func:`run_seed` ``(experiment seed, i)``
in every condition (common random numbers: the same receivers, patterns and
path at every σ, so differences between conditions are not sampling noise of
the geometry). A task's result depends only on its own configuration and seed,
so results are identical whatever the number of workers or the order in which
tasks finish (tested).

Resume: each task's rows are appended to ``OUT/parts/<experiment>.csv`` as
soon as it completes (one write, flushed and synced); a restart skips every
task whose key (:attr:`RunTask.key`, a hash of everything that determines its
result) already has all its rows, and a torn last line is discarded.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from radiopose.errors import InputError
from radiopose.evaluate.experiments import ANCHOR, KERNEL_AUTO, Experiment, format_value, is_3d
from radiopose.parallel import WORKER_ENV as WORKER_ENV  # re-exported: the old path
from radiopose.parallel import connect_scheduler as connect_scheduler  # re-exported
from radiopose.parallel import default_workers, run_on_dask
from radiopose.simulate import ScenarioConfig
from radiopose.tables import check_output_dir
from radiopose.tracker import TrackerConfig, get_method

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

    from radiopose.evaluate.method_runs import MethodRun
    from radiopose.likelihood import CandidateSpace, Scorer
    from radiopose.simulate import Simulation

DESCRIPTOR_COLUMNS: tuple[str, ...] = (
    "noise_db",
    "n_receivers",
    "interval_ms",
    "duration_s",
    "rotation",
)
"""Scenario settings recorded in every row, swept or not."""

METRIC_COLUMNS: tuple[str, ...] = (
    "n_packets",
    "n_estimates",
    "coverage",
    "position_mean_m",
    "position_median_m",
    "position_p95_m",
    "orientation_mean_deg",
    "orientation_median_deg",
    "orientation_p95_deg",
)
AXIS_COLUMNS: tuple[str, ...] = (
    "height_mean_m",
    "azimuth_mean_deg",
    "pitch_mean_deg",
    "roll_mean_deg",
)
"""Per-axis mean absolute errors of a 3-D run (``ScenarioConfig.pose = "3d"``; empty
for a method without orientation): height, and the wrapped azimuth, pitch and roll
differences (:mod:`radiopose.evaluate.pose3d`). Only 3-D experiments have them."""
TIMING_COLUMNS: tuple[str, ...] = ("run_time_s", "scoring_s", "task_s")
"""Wall times: differ between runs of the same task (everything else is identical)."""

_ID_COLUMNS = ("experiment", "condition", "condition_index", "run", "seed", "method")
_TAIL_COLUMNS = ("kernel", "task_key")


# ----------------------------------------------------------------------------- tasks
def run_seed(experiment_seed: int, run: int) -> int:
    """Seed of run ``run`` of an experiment: ``SeedSequence(seed).spawn(...)[run]`` as an int.

    Independent of the number of runs and of scheduling.
    """
    ss = np.random.SeedSequence(int(experiment_seed), spawn_key=(int(run),))
    return int(ss.generate_state(1, np.uint32)[0])


@dataclass(frozen=True)
class RunTask:
    """One simulated trace of one condition, all methods.

    Attributes
    ----------
    experiment
        Experiment name.
    condition_index, condition
        The condition's position in the sweep and its label.
    params
        ``(name, value)`` of the swept parameters.
    run
        Run index within the condition (0-based).
    seed
        Simulation seed (:func:`run_seed`).
    scenario, tracker
        What to simulate and how to track.
    methods
        Methods run on the trace.
    kernel
        Likelihood scorer (``"auto"`` = the fastest available; all give identical results).
    """

    experiment: str
    condition_index: int
    condition: str
    params: tuple[tuple[str, Any], ...]
    run: int
    seed: int
    scenario: ScenarioConfig
    tracker: TrackerConfig
    methods: tuple[str, ...]
    kernel: str = KERNEL_AUTO

    @property
    def key(self) -> str:
        """Hash of everything that determines the result (not the kernel: results are equal)."""
        blob = json.dumps(
            [
                self.experiment,
                self.condition,
                self.seed,
                asdict(self.scenario),
                asdict(self.tracker),
                list(self.methods),
            ],
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:20]

    @property
    def n_packets(self) -> int:
        """Packets of the simulated trace."""
        return round(self.scenario.duration_s / (self.scenario.interval_ms / 1000.0))


def plan(experiments: Iterable[Experiment]) -> list[RunTask]:
    """Every task of the experiments, in report order (experiment, condition, run)."""
    out = []
    for exp in experiments:
        for cond in exp.conditions:
            for r in range(exp.runs):
                out.append(
                    RunTask(
                        exp.name,
                        cond.index,
                        cond.label,
                        cond.params,
                        r,
                        run_seed(exp.seed, r),
                        cond.scenario,
                        cond.tracker,
                        exp.methods,
                        exp.kernel,
                    )
                )
    return out


def fastest_scorer(kernel: str, space: CandidateSpace) -> Scorer:
    """The named scorer; ``"auto"`` is the compiled one (``"numba"``), which falls
    back to ``"numpy"`` where the candidate set lacks its structure. All return
    the same candidates."""
    from radiopose.likelihood import make_scorer

    return make_scorer("numba" if kernel == KERNEL_AUTO else kernel, space)


def _nan(x: float | None) -> float:
    return float("nan") if x is None else float(x)


def _param_value(v: Any) -> Any:
    return format_value(v) if isinstance(v, tuple) else v


def run_task(task: RunTask) -> list[dict[str, Any]]:
    """Simulate the task's trace, run its methods on it, and score them.

    Returns
    -------
    One row per method (columns: :func:`columns_for`).
    """
    with ExitStack() as stack:
        if ANCHOR in task.methods:  # issue 15's anchor, told this run's σ
            from radiopose.evaluate.textbook_pf import registered_textbook

            stack.enter_context(registered_textbook(max(task.scenario.noise_db, 0.01)))
        return _run_task(task)


def _run_task(task: RunTask) -> list[dict[str, Any]]:
    from radiopose.evaluate.method_runs import run_methods
    from radiopose.evaluate.scoring import error_stats
    from radiopose.likelihood import MemoScorer, candidate_space
    from radiopose.packets import group_packets
    from radiopose.simulate import simulate
    from radiopose.tracker.filter import reads_site_scorer

    t0 = time.perf_counter()
    sim = simulate(task.scenario, task.seed)
    scorer = None
    kernel_name = ""
    scoring_s = 0.0
    scored = {m: reads_site_scorer(get_method(m), sim.site) for m in task.methods}
    if any(scored.values()):
        tx = sim.site.devices[0].transmitter
        inner = fastest_scorer(task.kernel, candidate_space(sim.site, tx))
        kernel_name = inner.name
        scorer = MemoScorer(inner)
        # Score every packet once up front, so that method run times exclude it.
        ts = time.perf_counter()
        for obs in group_packets(sim.packets):
            heard = scorer.space.heard(obs)
            if heard.n_heard >= task.tracker.min_receivers:
                scorer.score_heard(heard, task.tracker.k)
        scoring_s = time.perf_counter() - ts
    runs = run_methods(sim, task.methods, task.tracker, scorer)
    task_s = time.perf_counter() - t0
    sc = task.scenario
    base: dict[str, Any] = {
        "experiment": task.experiment,
        "condition": task.condition,
        "condition_index": task.condition_index,
        "run": task.run,
        "seed": task.seed,
    }
    descriptors = {
        "noise_db": sc.noise_db,
        "n_receivers": sc.n_receivers,
        "interval_ms": sc.interval_ms,
        "duration_s": sc.duration_s,
        "rotation": sc.motion.rotation,
    }
    extra = {k: _param_value(v) for k, v in task.params if k not in descriptors}
    rows = []
    for m in task.methods:
        r = runs[m]
        pos = error_stats(r.position_error_m)
        ori = error_stats(r.orientation_error_deg)
        axes = _axis_means(sim, r) if sc.pose == "3d" else {}
        rows.append(
            {
                **base,
                "method": m,
                **descriptors,
                **extra,
                "n_packets": r.n_packets,
                "n_estimates": len(r.estimates),
                "coverage": len(r.estimates) / r.n_packets if r.n_packets else 0.0,
                "position_mean_m": _nan(pos.mean),
                "position_median_m": _nan(pos.median),
                "position_p95_m": _nan(pos.p95),
                "orientation_mean_deg": _nan(ori.mean),
                "orientation_median_deg": _nan(ori.median),
                "orientation_p95_deg": _nan(ori.p95),
                **axes,
                "run_time_s": r.summary.elapsed_s,
                "scoring_s": scoring_s if scored[m] else 0.0,
                "task_s": task_s,
                "kernel": kernel_name if scored[m] else "",
                "task_key": task.key,
            }
        )
    return rows


def _axis_means(sim: Simulation, run: MethodRun) -> dict[str, float]:
    """:data:`AXIS_COLUMNS` of one method's run on a 3-D trace (NaN without orientation)."""
    from radiopose.evaluate.pose3d import axis_errors_of

    if run.orientation_error_deg.size == 0:
        return dict.fromkeys(AXIS_COLUMNS, math.nan)
    est, ok = run.estimates, run.truth_index
    e = axis_errors_of(
        est.position_m, est.orientation_deg,
        sim.truth.position_m[ok], sim.truth.orientation_deg[ok],
    )  # fmt: skip
    means = [e.height_m, e.azimuth_deg, e.pitch_deg, e.roll_deg]
    return {k: float(np.mean(v)) for k, v in zip(AXIS_COLUMNS, means, strict=True)}


def columns_for(experiment: Experiment) -> list[str]:
    """Columns of an experiment's result rows (swept parameters after the descriptors;
    :data:`AXIS_COLUMNS` after the metrics for a 3-D experiment)."""
    extra = [k for k in experiment.sweep_keys if k not in DESCRIPTOR_COLUMNS]
    return [
        *_ID_COLUMNS,
        *DESCRIPTOR_COLUMNS,
        *extra,
        *METRIC_COLUMNS,
        *(AXIS_COLUMNS if is_3d(experiment) else ()),
        *TIMING_COLUMNS,
        *_TAIL_COLUMNS,
    ]


# ----------------------------------------------------------------------------- storage
class PartFile:
    """The append-only result file of one experiment (``OUT/parts/<name>.csv``).

    Opening keeps the complete rows already there (dropping a torn last line
    and rewriting the file if its header differs from ``columns``); any other
    line that is not a row of the header's width is an
    :class:`~radiopose.errors.InputError` naming it (the file was damaged).
    """

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self.path = Path(path)
        self.columns = list(columns)
        self.rows: list[dict[str, str]] = []
        self._torn = False
        if self.path.exists():
            self.rows = self._read()
            header = self._header()
            if header != self.columns or self._torn:
                self._rewrite()
        # else: the directory and the header are written with the first rows, so a
        # command that fails before any run ends (a scheduler that cannot be
        # reached) leaves nothing behind.

    def _header(self) -> list[str]:
        with open(self.path, newline="", encoding="utf-8") as fh:
            return next(csv.reader(fh), [])

    def _read(self) -> list[dict[str, str]]:
        text = self.path.read_text(encoding="utf-8")
        lines = text.splitlines(keepends=True)
        if lines and not lines[-1].endswith("\n"):
            lines = lines[:-1]  # interrupted mid-write
            self._torn = True
        if not lines:
            return []
        reader = csv.reader(lines)
        header = next(reader)
        out = []
        for fields_ in reader:
            if len(fields_) != len(header):  # only the last line can be torn (dropped above)
                raise InputError(
                    f"not a result row ({len(fields_)} fields, the header has {len(header)}): "
                    "the file was changed by hand or damaged; delete it to rerun the experiment",
                    path=self.path,
                    line=reader.line_num,
                )
            out.append(dict(zip(header, fields_, strict=True)))
        return out

    def _rewrite(self) -> None:
        body = [self.columns] + [[r.get(c, "") for c in self.columns] for r in self.rows]
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(self._csv_text(body), encoding="utf-8")
        os.replace(tmp, self.path)

    @staticmethod
    def _csv_text(rows: Iterable[Sequence[Any]]) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        for r in rows:
            w.writerow(["" if isinstance(v, float) and math.isnan(v) else v for v in r])
        return buf.getvalue()

    def _write_text(self, text: str, mode: str = "a") -> None:
        with open(self.path, mode, newline="", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())

    def done_keys(self, n_rows: dict[str, int]) -> set[str]:
        """Task keys with all their rows present (``n_rows``: key → expected rows)."""
        count: dict[str, int] = {}
        for r in self.rows:
            count[r.get("task_key", "")] = count.get(r.get("task_key", ""), 0) + 1
        return {k for k, n in n_rows.items() if count.get(k, 0) >= n}

    def append(self, rows: Sequence[dict[str, Any]]) -> None:
        """Append one task's rows in one synced write (the header first in a new file)."""
        body = [[r.get(c, "") for c in self.columns] for r in rows]
        if not self.path.exists():
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._write_text(self._csv_text([self.columns, *body]), mode="w")
        else:
            self._write_text(self._csv_text(body))
        self.rows.extend({c: str(r.get(c, "")) for c in self.columns} for r in rows)


# ----------------------------------------------------------------------------- running
@dataclass(frozen=True, eq=False)
class EvaluationRun:
    """What :func:`run_experiments` did.

    Attributes
    ----------
    results
        The tidy results of every planned task (one row per task and method).
    n_tasks, n_resumed
        Tasks planned, and those found finished in the output directory.
    elapsed_s
        Wall time of this call, seconds.
    workers
        Workers used (0 = in this process).
    scheduler
        ``"local"``, ``"serial"`` or the scheduler address.
    """

    results: pd.DataFrame
    n_tasks: int
    n_resumed: int
    elapsed_s: float
    workers: int
    scheduler: str


def _describe(task: RunTask) -> str:
    return f"{task.experiment} [{task.condition}] run {task.run} (seed {task.seed})"


def run_experiments(
    experiments: Sequence[Experiment],
    out_dir: str | os.PathLike[str],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> EvaluationRun:
    """Run every task of the experiments not yet finished in ``out_dir``.

    Parameters
    ----------
    experiments
        The experiments (names must be distinct).
    out_dir
        Output directory; result rows go to ``out_dir/parts/<experiment>.csv``
        as tasks complete.
    scheduler
        Address of an existing Dask scheduler; ``None`` starts a local cluster.
    workers
        Local cluster size (default: all cores); ``0`` runs in this process
        without Dask. Ignored with ``scheduler``.
    progress
        Called as ``progress(done, total, description)`` after each task
        (``done`` counts resumed tasks too).

    Returns
    -------
    The results of every planned task, in plan order, as read back from the part files.
    """
    t0 = time.perf_counter()
    names = [e.name for e in experiments]
    if len(set(names)) != len(names):
        raise InputError(f"experiment {next(n for n in names if names.count(n) > 1)!r} given twice")
    if workers is not None and workers < 0:  # before anything is written
        raise InputError(f"--workers must be >= 0, got {workers}")
    out = Path(out_dir)
    # A file where a directory goes fails now, not when the first run ends; nothing is
    # created (a command that fails before any run ends leaves nothing behind).
    check_output_dir(out, [f"parts/{name}.csv" for name in names], subdirs=["parts"])
    tasks = plan(experiments)
    parts = {e.name: PartFile(out / "parts" / f"{e.name}.csv", columns_for(e)) for e in experiments}
    done: set[str] = set()
    for e in experiments:
        need = {t.key: len(t.methods) for t in tasks if t.experiment == e.name}
        done |= parts[e.name].done_keys(need)
    pending = [t for t in tasks if t.key not in done]
    n_resumed = len(tasks) - len(pending)
    total = len(tasks)
    if progress is not None:
        progress(n_resumed, total, "resumed" if n_resumed else "starting")

    n_done = n_resumed

    def record(task: RunTask, rows: list[dict[str, Any]]) -> None:
        nonlocal n_done
        parts[task.experiment].append(rows)
        n_done += 1
        if progress is not None:
            progress(n_done, total, _describe(task))

    if workers is None:
        workers = default_workers()
    if workers < 0:
        raise InputError(f"--workers must be >= 0, got {workers}")
    if scheduler is None and workers == 0:
        for task in pending:
            record(task, run_task(task))
        used, where = 0, "serial"
    else:
        used = run_on_dask(
            run_task,
            pending,
            record,
            scheduler=scheduler,
            workers=workers,
            key=lambda t: f"radiopose-run-{t.key}",
            describe=_describe,
        )
        where = "local" if scheduler is None else scheduler
    results = collect(out, experiments, tasks)
    return EvaluationRun(results, total, n_resumed, time.perf_counter() - t0, used, where)


# ----------------------------------------------------------------------------- results
def collect(
    out_dir: str | os.PathLike[str],
    experiments: Sequence[Experiment],
    tasks: Sequence[RunTask] | None = None,
) -> pd.DataFrame:
    """The results of the planned tasks from the part files, in plan and method order."""
    import pandas as pd

    tasks = plan(experiments) if tasks is None else tasks
    order = {t.key: i for i, t in enumerate(tasks)}
    frames = []
    for e in experiments:
        path = Path(out_dir) / "parts" / f"{e.name}.csv"
        if not path.exists():
            continue
        df = pd.read_csv(
            path,
            dtype={"task_key": str, "kernel": str, "condition": str, "rotation": str},
            keep_default_na=False,
            na_values=[""],
        )
        df["kernel"] = df["kernel"].fillna("")
        df = df[df["task_key"].isin(order)]
        df = df.drop_duplicates(subset=["task_key", "method"], keep="first")
        m_order = {m: i for i, m in enumerate(e.methods)}
        df = df.assign(_t=df["task_key"].map(order), _m=df["method"].map(m_order))
        frames.append(df.sort_values(["_t", "_m"]).drop(columns=["_t", "_m"]))
    if not frames:
        return pd.DataFrame(columns=[*_ID_COLUMNS, *DESCRIPTOR_COLUMNS, *METRIC_COLUMNS])
    return pd.concat(frames, ignore_index=True, sort=False)


def write_results(results: pd.DataFrame, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write the tidy table as ``results.csv`` and ``results.parquet``; return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path, pq_path = out / "results.csv", out / "results.parquet"
    results.to_csv(csv_path, index=False)
    results.to_parquet(pq_path, index=False)
    return [csv_path, pq_path]
