"""Where the live pipeline runs: :class:`LiveWorker`, a thread or a child process.

The pipeline itself (:class:`~radiopose.server.live.LivePipeline`) is a
plain object stepped over the database; this module only keeps it stepping,
restarts it from its last checkpoint after an error and stops it with the
server.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from radiopose.server.db import Database
from radiopose.server.live import LiveConfig, LivePipeline

__all__ = ["LiveWorker"]

log = logging.getLogger("radiopose.server.live")  # the pipeline's own logger


class LiveWorker:
    """Runs a :class:`~radiopose.server.live.LivePipeline` until :meth:`stop`, in a thread or a
    child process.

    ``mode="process"`` (what ``radiopose serve`` uses) runs the pipeline in a
    child process with its own database connection, so tracking never
    competes with the API for the interpreter lock; the child exits when its
    parent dies (even by ``kill -9``). ``mode="thread"`` keeps it in this
    process (tests). ``wake()`` (called after a batch is stored) cuts the
    polling delay. Any error is logged and the pipeline restarts from its
    last checkpoint, after a wait that doubles with each failure in a row (1 s
    to 60 s); ``/health`` reports the failure until the partition commits
    again.
    """

    def __init__(
        self, db: Database, config: LiveConfig | None = None, mode: str = "thread"
    ) -> None:
        if mode not in ("thread", "process"):
            raise ValueError(f"mode must be 'thread' or 'process', got {mode!r}")
        self.db = db
        self.config = config or LiveConfig()
        self.mode = mode
        self.pipeline: LivePipeline | None = None
        if mode == "process":
            import multiprocessing

            ctx = multiprocessing.get_context("spawn")
            self._stop: Any = ctx.Event()
            self._wake: Any = ctx.Event()
            self._runner: Any = ctx.Process(
                target=_process_main,
                args=(db.url, self.config, self._stop, self._wake),
                name="radiopose-live",
                daemon=True,
            )
        else:
            self._stop = threading.Event()
            self._wake = threading.Event()
            self._runner = threading.Thread(target=self._run, name="radiopose-live", daemon=True)

    def start(self) -> None:
        self._runner.start()

    def wake(self) -> None:
        self._wake.set()

    def stop(self, timeout_s: float = 10.0) -> None:
        # A child process killed inside a wait (a SIGKILL) still counts as waiting
        # on the events, and setting them would then wait for it forever: only a
        # live child is told; a dead one is only joined.
        if self.mode == "thread" or self._runner.ident is None or self._runner.is_alive():
            self._stop.set()
            self._wake.set()
        if self._runner.ident is not None:
            self._runner.join(timeout_s)
        if self.mode == "process" and self._runner.is_alive():
            self._runner.terminate()
            self._runner.join(timeout_s)
        started = self._runner.ident is not None
        if self.mode == "process" and started and not self._runner.is_alive():
            self._release_events()

    def _release_events(self) -> None:
        """Free the child's events now rather than at interpreter exit: uvicorn
        ends a signalled server by re-raising the signal, so multiprocessing's exit
        handlers never run and its resource tracker would report the events'
        semaphores as leaked. Later ``wake``/``stop`` calls are no-ops."""
        import gc
        import threading

        self._runner._args = ()  # the Process keeps its arguments (the events) until freed
        self._stop, self._wake = threading.Event(), threading.Event()
        gc.collect()

    def _run(self) -> None:
        _loop(self.db, self.config, self._stop, self._wake, self)


def _loop(
    db: Database,
    config: LiveConfig,
    stop: Any,
    wake: Any,
    holder: LiveWorker | None = None,
    terminated: list[bool] | None = None,
) -> None:
    import os

    parent = os.getppid()
    pipeline: LivePipeline | None = None
    failures = 0
    while not stop.is_set() and not (terminated and terminated[0]):
        if holder is None and os.getppid() != parent:  # the server died: so do we
            return
        try:
            if pipeline is None:
                pipeline = LivePipeline(db, config)
                if holder is not None:
                    holder.pipeline = pipeline
            n = pipeline.step()
            failures = 0
        except Exception as exc:
            failures += 1
            wait_s = min(60.0, 2.0 ** (failures - 1))
            log.exception(
                "live pipeline step failed (%d in a row); resuming from the last checkpoint "
                "in %g s",
                failures,
                wait_s,
            )
            try:  # /health reports it until the partition commits again
                db.note_pipeline_error(config.partition_key, f"{type(exc).__name__}: {exc}")
            except Exception:  # the database itself may be what fails
                log.exception("could not record the failure in the database")
            pipeline = None
            stop.wait(wait_s)
            continue
        if n == 0:
            wake.wait(config.poll_s)
            wake.clear()


def method_missing(config: LiveConfig) -> str | None:
    """Why the pipeline process cannot run ``config.method``, or ``None``. The
    process imported the registry afresh (spawn): a method the server found may
    be missing here — a plugin registered only by the parent's own script, not
    by an entry point or ``RADIOPOSE_METHODS`` (docs/methods.md) — or a
    plugin may fail to load."""
    if config.method is None:
        return None
    from radiopose.errors import RadioposeError

    try:
        from radiopose.tracker import get_method

        get_method(config.method)
    except RadioposeError as exc:
        return (
            f"{exc} (a plugin's method reaches this process only through an entry point "
            "or RADIOPOSE_METHODS; docs/methods.md)"
        )
    return None


def _process_main(url: str, config: LiveConfig, stop: Any, wake: Any) -> None:
    import signal

    from radiopose.server.jsonlog import configure_logging

    # A SIGTERM to the whole process group (systemd's default, ``kill -- -PGID``)
    # reaches this child too. Dying inside ``wake.wait`` would leave it counted
    # as a waiter of the event, and the server's own shutdown would then block in
    # ``stop.set()`` forever; so the signal only ends the loop after its wait.
    terminated = [False]

    def on_term(signum: int, frame: object) -> None:
        terminated[0] = True

    signal.signal(signal.SIGTERM, on_term)
    configure_logging("info")
    db = Database(url, create=False)
    missing = method_missing(config)
    if missing is not None:  # say so once (log and /health) and stop, not fail every step
        log.critical("live pipeline not started: %s", missing)
        try:
            db.note_pipeline_error(config.partition_key, f"not started: {missing}")
        finally:
            db.close()
        return
    try:
        _loop(db, config, stop, wake, terminated=terminated)
    except KeyboardInterrupt:
        pass
    finally:
        db.close()
