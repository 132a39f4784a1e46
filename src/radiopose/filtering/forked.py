"""Offline work on the second core: independent calls run in forked children.

Beyond the paper (issue 15, whole-process speed of offline ``filter``;
docs/performance.md, "Eighth pass"). The offline passes after the forward one
(the time-reversed pass, the offset selection's passes, the arbiter's
refinement of each candidate track) are independent of one another once their
inputs are known, and each is deterministic given them (its own seed, the
model's arrays; the scorer's threshold hints change only the speed). So each
may run in a child process forked from this one — the model and its tables are
shared copy-on-write, nothing is pickled but the inputs' closure-free results —
and its result is the one the same call gives in this process, bit for bit.

:class:`ForkedCall` runs one call in a forked child; :func:`map_forked` runs a
list of calls on ``workers`` processes (this one included). A child that fails
(killed, out of memory, an exception) is never an answer: the call is run
again here, so an error the call raises is raised from this process as if it
ran serially. Where ``fork`` is not available every call runs here.
"""

from __future__ import annotations

import multiprocessing
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Generic, TypeVar

from radiopose.cores import available_cores
from radiopose.errors import InputError

R = TypeVar("R")

MAX_OFFLINE_WORKERS = 64
"""Largest accepted ``FilterConfig.offline_workers``."""


def fork_available() -> bool:
    """Whether the offline passes may fork here: Linux only (macOS's system
    libraries are not fork-safe; Windows cannot fork), and not in a daemonic
    process (e.g. a Dask worker of ``radiopose evaluate``, which may not have
    children and already has its own core)."""
    return (
        sys.platform.startswith("linux")
        and "fork" in multiprocessing.get_all_start_methods()
        and not multiprocessing.current_process().daemon
        and numba_fork_safe()
    )


def numba_fork_safe() -> bool:
    """Whether this process may fork for the offline passes as far as numba is
    concerned: not once it has launched numba's threading layer as ``omp``.
    GNU OpenMP is not fork-safe: numba terminates a child that enters a
    parallel region after such a fork ("fork() called from a process already
    using GNU OpenMP"), and where a filter shares a paper method's parallel
    scorer (``radiopose demo``, ``evaluate``'s runs in one process) its passes
    would. Such a process runs the offline passes here, serially; a plain
    ``locate --method filter`` (the filter's own one-thread scorer) forks
    before any parallel region (docs/performance.md, "Eighth pass")."""
    try:
        import numba

        return bool(numba.threading_layer() != "omp")
    except ValueError:  # the threading layer was not launched in this process
        return True


def try_fork(fn: Callable[[], R]) -> ForkedCall[R] | None:
    """A :class:`ForkedCall` of ``fn``, or ``None`` if no child could be
    started (no fork here, out of processes or memory): the caller then runs
    ``fn`` itself."""
    if not fork_available():
        return None
    try:
        return ForkedCall(fn)
    except (OSError, AssertionError, ValueError):
        return None


def effective_workers(setting: int) -> int:
    """Processes the offline passes use: ``setting`` (``FilterConfig.offline_workers``),
    at most the cores available, 1 where fork is not available.

    Raises
    ------
    InputError
        ``setting`` is not an integer in ``[1, MAX_OFFLINE_WORKERS]``.
    """
    check_workers(setting)
    if setting <= 1 or not fork_available():
        return 1
    return max(1, min(setting, available_cores()))


def check_workers(setting: object, name: str = "filter setting offline_workers") -> int:
    """``setting`` if it is an integer in ``[1, MAX_OFFLINE_WORKERS]``.

    Raises
    ------
    InputError
        Otherwise (one line, naming ``name``).
    """
    if isinstance(setting, bool) or not (
        isinstance(setting, int) and 1 <= setting <= MAX_OFFLINE_WORKERS
    ):
        raise InputError(
            f"{name} = {setting!r} must be an integer in [1, {MAX_OFFLINE_WORKERS}] "
            "(1: every offline pass in this process)"
        )
    return setting


def _drop_pool() -> None:
    from radiopose.likelihood.compiled import drop_thread_pool

    drop_thread_pool()


def _claim(n: int) -> None:
    from radiopose.likelihood.compiled import claim_core

    claim_core(n)


class ChildFailedError(RuntimeError):
    """A forked child gave no result (it died, or its call raised)."""


def _child(send: Any, fn: Callable[[], Any]) -> None:
    """The child's body: run ``fn``, send ``(True, result)`` or ``(False, error)``.
    It never enters a numba parallel region (:func:`~radiopose.likelihood.exact.serial_only`;
    the filter's own scorer is one-thread), which GNU OpenMP does not allow
    after a fork."""
    from radiopose.likelihood.exact import serial_only

    serial_only()
    try:
        out: tuple[bool, Any] = (True, fn())
    except BaseException as exc:  # reported to the parent, which re-runs the call
        out = (False, f"{type(exc).__name__}: {exc}")
    try:
        send.send(out)
    except Exception as exc:  # e.g. an unpicklable result
        send.send((False, f"result not sent: {type(exc).__name__}: {exc}"))
    send.close()


class ForkedCall(Generic[R]):
    """``fn()`` running in a child forked now (``fn`` may be a closure: it is not
    pickled; its result is, through a pipe).

    :meth:`result` waits for it; :meth:`cancel` kills the child. The child is a
    daemon: it dies with this process.
    """

    def __init__(self, fn: Callable[[], R]) -> None:
        ctx = multiprocessing.get_context("fork")
        self._recv, send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_child, args=(send, fn), daemon=True)
        # a core taken: neither this process's compiled work nor the child's
        # (which inherits the claim) starts a second thread meanwhile
        _claim(1)
        try:
            _drop_pool()
            with warnings.catch_warnings():
                # Python ≥ 3.12 warns when a process with several OS threads
                # forks. Ours has none of its own at this point (the pool is
                # dropped above, calls run from the main thread between
                # compiled calls); numba's threads, if a parallel kernel ran,
                # belong to its workqueue layer, which numba documents as
                # fork-safe (numba/np/ufunc/parallel.py). docs/performance.md,
                # "Eighth pass".
                warnings.filterwarnings(
                    "ignore", r".*fork\(\) may lead to deadlocks", DeprecationWarning
                )
                self._proc.start()
        except BaseException:
            _claim(-1)
            raise
        send.close()
        self._done = False

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        return self._proc.pid

    def ready(self) -> bool:
        """Whether the result has arrived (or the child ended): :meth:`result`
        would not wait."""
        return self._done or bool(self._recv.poll(0))

    def result(self) -> R:
        """The call's result, once the child sends it.

        Raises
        ------
        ChildFailedError
            The child died without a result, or the call raised (the message
            names the exception).
        """
        if self._done:
            raise ChildFailedError("the result was taken already or the call was cancelled")
        self._done = True
        _claim(-1)
        try:
            ok, value = self._recv.recv()
        except (EOFError, OSError) as exc:
            raise ChildFailedError(f"the child exited without a result ({exc!r})") from None
        finally:
            self._recv.close()
            self._proc.join()
            self._proc.close()
        if not ok:
            raise ChildFailedError(str(value))
        return value

    def cancel(self) -> None:
        """Kill the child (if still running) and forget its result."""
        if self._done:
            return
        self._done = True
        _claim(-1)
        self._proc.kill()
        self._proc.join()
        self._recv.close()
        self._proc.close()


def result_or_none(job: ForkedCall[R] | None) -> R | None:
    """``job``'s result (:meth:`ForkedCall.result`), or ``None`` without a job
    or when its child failed: the caller then runs the call itself."""
    if job is None:
        return None
    try:
        return job.result()
    except ChildFailedError:
        return None


def _run_bin(fns: Sequence[Callable[[], R]], idx: Sequence[int]) -> list[R]:
    return [fns[i]() for i in idx]


def _bin_call(fns: Sequence[Callable[[], R]], idx: Sequence[int]) -> Callable[[], list[R]]:
    return lambda: _run_bin(fns, idx)


def map_forked(
    fns: Sequence[Callable[[], R]], workers: int, weights: Sequence[float] | None = None
) -> list[R]:
    """``[fn() for fn in fns]``, the calls spread over ``workers`` processes.

    The calls are split into ``workers`` bins by ``weights`` (their expected
    costs; equal by default), heaviest first into the lightest bin; each bin but
    the first runs in a forked child (:class:`ForkedCall`), the first here. A
    bin whose child fails (or cannot be started) is run here afterwards. With
    ``workers`` ≤ 1, one call, or no fork, every call runs here in order.
    """
    n = len(fns)
    if workers <= 1 or n <= 1 or not fork_available():
        return [fn() for fn in fns]
    w = [1.0] * n if weights is None else [float(x) for x in weights]
    bins: list[list[int]] = [[] for _ in range(min(workers, n))]
    load = [0.0] * len(bins)
    for i in sorted(range(n), key=lambda i: (-w[i], i)):
        lightest = min(range(len(bins)), key=lambda j: (load[j], j))
        bins[lightest].append(i)
        load[lightest] += w[i]
    away = [b for b in bins[1:] if b]
    children = [try_fork(_bin_call(fns, b)) for b in away]
    out: list[Any] = [None] * n
    try:
        here = _run_bin(fns, bins[0])
    except BaseException:
        for child in children:
            if child is not None:
                child.cancel()
        raise
    for i, r in zip(bins[0], here, strict=True):
        out[i] = r
    for b, child in zip(away, children, strict=True):
        res = result_or_none(child)
        if res is None:  # not started or failed: the same calls here (their error, if any)
            res = _run_bin(fns, b)
        for i, r in zip(b, res, strict=True):
            out[i] = r
    return out


__all__ = [
    "MAX_OFFLINE_WORKERS",
    "ChildFailedError",
    "ForkedCall",
    "available_cores",
    "check_workers",
    "effective_workers",
    "fork_available",
    "map_forked",
    "result_or_none",
    "try_fork",
]
