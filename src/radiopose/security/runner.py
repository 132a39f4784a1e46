"""Where the spoofing runs execute: in this process, or on Dask like the evaluation.

:func:`map_runs` runs ``run_experiment(experiment, run, config)`` for every
task — serially for ``workers=0``, otherwise on the same kind of Dask cluster as
the evaluation sweeps, through the one runner both use
(:func:`radiopose.parallel.run_on_dask`): a local cluster of single-threaded
worker processes (``NUMBA_NUM_THREADS=1`` …), or an existing scheduler
(``scheduler=``). Without
``dask.distributed`` installed it falls back to a local process pool. Results do
not depend on the number of workers: every run is seeded by its index.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from radiopose.errors import InputError, RadioposeError
from radiopose.parallel import default_workers as default_workers  # re-exported: CLI
from radiopose.parallel import run_on_dask
from radiopose.security.experiments import RunOutput, SpoofConfig, run_experiment


def map_runs(
    tasks: Sequence[tuple[str, int]],
    config: SpoofConfig,
    workers: int = 0,
    on_done: Callable[[RunOutput], None] | None = None,
    scheduler: str | None = None,
) -> tuple[list[RunOutput], str]:
    """Run every ``(experiment, run)`` task; return outputs in task order and where they ran.

    Parameters
    ----------
    tasks
        ``(experiment, run)`` pairs (:func:`~radiopose.security.experiments.plan_tasks`).
    config
        Settings shared by every run.
    workers
        Local worker processes; 0 runs in this process. Ignored with ``scheduler``.
    on_done
        Called with each finished run (e.g. to advance a progress bar).
    scheduler
        Address of an existing Dask scheduler.
    """
    if workers < 0:
        raise InputError(f"--workers must be >= 0, got {workers}")
    out: dict[tuple[str, int], RunOutput] = {}

    def record(res: RunOutput) -> None:
        out[(res.experiment, res.run)] = res
        if on_done is not None:
            on_done(res)

    if scheduler is None and (workers == 0 or len(tasks) <= 1):
        for exp, run in tasks:
            record(run_experiment(exp, run, config))
        where = "serial"
    else:
        try:
            import distributed  # noqa: F401
        except ImportError:
            if scheduler is not None:
                raise RadioposeError(
                    "dask.distributed is not installed: cannot use --scheduler"
                ) from None
            where = _run_pool(tasks, config, workers, record)
        else:
            where = _run_dask(tasks, config, workers, record, scheduler)
    return [out[t] for t in tasks], where


def _run_pool(
    tasks: Sequence[tuple[str, int]],
    config: SpoofConfig,
    workers: int,
    record: Callable[[RunOutput], None],
) -> str:
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
        futures = [pool.submit(run_experiment, exp, run, config) for exp, run in tasks]
        for fut in as_completed(futures):
            record(fut.result())
    return f"process pool ({workers})"


def _run_dask(
    tasks: Sequence[tuple[str, int]],
    config: SpoofConfig,
    workers: int,
    record: Callable[[RunOutput], None],
    scheduler: str | None,
) -> str:
    n = min(workers, len(tasks))
    run_on_dask(
        functools.partial(_run_task, config=config),
        tasks,
        lambda _task, res: record(res),
        scheduler=scheduler,
        workers=n,
        key=lambda task: f"radiopose-spoof-{task[0]}-{task[1]}",
        describe=lambda task: f"spoof {task[0]} run {task[1]}",
        dashboard_address=None,
    )
    return scheduler if scheduler is not None else f"dask local ({n} workers)"


def _run_task(task: tuple[str, int], config: SpoofConfig) -> RunOutput:
    return run_experiment(task[0], task[1], config)


class RunStore:
    """Finished runs of one output directory, one JSON file each, for resuming.

    ``DIR/parts/<experiment>-<run>.json`` holds a run's tables and a key of
    everything that determines them (the settings, the experiment, the run), so
    a file written under other settings is ignored and recomputed.

    Parameters
    ----------
    out
        The command's output directory.
    config
        The settings shared by every run.
    """

    def __init__(self, out: os.PathLike[str] | str, config: SpoofConfig) -> None:
        from pathlib import Path

        self.dir = Path(out) / "parts"
        self._config = repr(config)

    def key(self, experiment: str, run: int) -> str:
        """Hash of the settings, the experiment and the run."""
        import hashlib

        text = repr((self._config, experiment, int(run)))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:24]

    def _path(self, experiment: str, run: int):
        return self.dir / f"{experiment}-{int(run):03d}.json"

    def load(self, tasks: Sequence[tuple[str, int]]) -> dict[tuple[str, int], RunOutput]:
        """The stored runs among ``tasks`` whose key matches (unreadable files are ignored)."""
        import json

        done: dict[tuple[str, int], RunOutput] = {}
        for exp, run in tasks:
            path = self._path(exp, run)
            try:
                data = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if not isinstance(data, dict) or data.get("key") != self.key(exp, run):
                continue
            done[(exp, run)] = RunOutput(exp, run, data["tables"], float(data["elapsed_s"]))
        return done

    def save(self, res: RunOutput) -> None:
        """Write one finished run (atomically: a killed write leaves no partial file)."""
        import json

        from radiopose.tables import atomic_writer

        self.dir.mkdir(parents=True, exist_ok=True)
        payload = {
            "key": self.key(res.experiment, res.run),
            "experiment": res.experiment,
            "run": res.run,
            "elapsed_s": res.elapsed_s,
            "tables": res.tables,
        }
        text = json.dumps(payload, default=_plain)
        with atomic_writer(self._path(res.experiment, res.run)) as fh:
            fh.write(text)


def _plain(value: object) -> object:
    """numpy scalars and arrays → plain JSON values."""
    item = getattr(value, "tolist", None)
    if item is not None:
        return item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
