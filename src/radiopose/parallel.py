"""Where independent seeded runs execute: one Dask runner for evaluation and security.

Both :mod:`radiopose.evaluate.runner` (accuracy sweeps) and
:mod:`radiopose.security.runner` (spoofing runs) map a function over a list of
independent tasks, each seeded by its own index, so results never depend on
the number of workers. :func:`run_on_dask` runs them on a local cluster of
single-threaded worker processes (:data:`WORKER_ENV`) or on an existing
scheduler; :func:`default_workers` is the local cluster's default size.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from typing import TYPE_CHECKING, TypeVar

from radiopose.cores import available_cores
from radiopose.errors import InputError, RadioposeError

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["WORKER_ENV", "connect_scheduler", "default_workers", "run_on_dask"]

T = TypeVar("T")
R = TypeVar("R")

WORKER_ENV: dict[str, str] = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
"""Environment of local Dask workers: one thread each (one worker per core)."""


def default_workers() -> int:
    """Worker processes by default: the cores available to this process."""
    return available_cores()


def connect_scheduler(stack: ExitStack, scheduler: str) -> Client:
    """A Dask client of the existing scheduler at ``scheduler``, closed with ``stack``.

    Raises
    ------
    InputError
        The scheduler cannot be reached within 10 s (one line).
    """
    from distributed import Client

    try:
        return stack.enter_context(Client(scheduler, timeout="10s"))
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None


def run_on_dask(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    record: Callable[[T, R], None],
    *,
    scheduler: str | None,
    workers: int,
    key: Callable[[T], str],
    describe: Callable[[T], str],
    dashboard_address: str | None = ":0",
) -> int:
    """Run ``fn(task)`` for every task on Dask, calling ``record(task, result)`` as each ends.

    Parameters
    ----------
    fn
        A picklable function of one task.
    tasks
        The tasks (may be empty: the cluster is still started, so the caller
        learns how many workers it has).
    record
        Called in this process, in completion order.
    scheduler
        Address of an existing scheduler; ``None`` starts a local cluster of
        ``workers`` single-threaded processes with :data:`WORKER_ENV`.
    workers
        Local cluster size (ignored with ``scheduler``).
    key
        The Dask key of a task (unique among the tasks).
    describe
        A task in a failure message (``"<describe> failed: <error>"``).
    dashboard_address
        The local cluster's dashboard (``":0"``: a free port; ``None``: none).

    Returns
    -------
    int
        Workers used (the scheduler's count with ``scheduler``).

    Raises
    ------
    RadioposeError
        ``dask.distributed`` is missing, or a task failed (the others are cancelled).
    """
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise RadioposeError(
            "dask.distributed is not installed: pip install 'radiopose[eval]', or use "
            "--workers 0 to run in this process"
        ) from None

    with ExitStack() as stack:
        if scheduler is not None:
            client = connect_scheduler(stack, scheduler)
            used = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        else:
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=dashboard_address,
                    silence_logs=logging.ERROR,
                    env=dict(WORKER_ENV),
                )
            )
            client = stack.enter_context(Client(cluster))
            used = workers
        if not tasks:
            return used
        futures = {client.submit(fn, t, key=key(t), pure=False): t for t in tasks}
        try:
            for fut in as_completed(futures):
                task = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:
                    raise RadioposeError(
                        f"{describe(task)} failed: {type(exc).__name__}: {exc}"
                    ) from exc
                record(task, result)
                fut.release()
        finally:
            client.cancel(list(futures))
    return used
