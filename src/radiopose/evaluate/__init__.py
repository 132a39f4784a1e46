"""Evaluation: scoring estimates against truth, the demo pipeline and experiments."""

from radiopose.evaluate.scoring import ErrorStats, MethodScore, error_stats, match_truth, score

__all__ = ["ErrorStats", "MethodScore", "error_stats", "match_truth", "score"]

# Experiments (issue 7): TOML configs, the Dask runner (pandas/dask imported lazily).
from radiopose.evaluate.experiments import (
    SHIPPED,
    Experiment,
    FigureSpec,
    load_experiment,
)
from radiopose.evaluate.runner import RunTask, run_experiments, run_task

__all__ += [
    "SHIPPED",
    "Experiment",
    "FigureSpec",
    "RunTask",
    "load_experiment",
    "run_experiments",
    "run_task",
]
