"""The processors this process may run on: the one count every pool sizes itself by.

:func:`available_cores` is read by the Dask runner's default size
(:func:`radiopose.parallel.default_workers`), the filter's forked offline passes
(:func:`radiopose.filtering.forked.effective_workers`) and the compiled kernel's
thread choice (:func:`radiopose.likelihood.compiled.free_cores`).
"""

from __future__ import annotations

import os

__all__ = ["available_cores"]


def available_cores() -> int:
    """Processors in this process's CPU affinity (Linux), else ``os.cpu_count()``; at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)
