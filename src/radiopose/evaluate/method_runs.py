"""Every method on one simulation, with each estimate's errors against the truth.

:func:`run_methods` runs tracker methods (by default the paper's five and the
filter) on one :class:`~radiopose.simulate.Simulation`, scoring each packet
once (the pattern methods share one memoised scorer from :func:`build_scorer`),
and returns a :class:`MethodRun` per method. The experiment runner, the demo,
the accuracy tests and scripts all go through it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from radiopose.estimates import Estimates
from radiopose.evaluate.scoring import match_truth
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import MemoScorer, Scorer, candidate_space, make_scorer
from radiopose.packets import group_packets
from radiopose.simulate import Simulation
from radiopose.tracker import (
    METHOD_NAMES,
    METHODS,
    RunSummary,
    TrackerConfig,
    get_method,
    locate,
)
from radiopose.tracker.filter import reads_site_scorer
from radiopose.units import FloatArray

__all__ = ["MethodRun", "build_scorer", "run_methods"]


@dataclass(frozen=True, eq=False)
class MethodRun:
    """One method on one simulation: estimates, summary and per-estimate errors.

    Attributes
    ----------
    method
        Method name.
    estimates
        The estimates.
    summary
        The run summary (coverage, skips).
    position_error_m
        ``(n_est,)`` metres.
    orientation_error_deg
        ``(n_est,)`` degrees (empty for position-only methods).
    truth_index
        ``(n_est,)`` truth row of each estimate.
    n_packets
        Packets in the simulation.
    """

    method: str
    estimates: Estimates
    summary: RunSummary
    position_error_m: FloatArray
    orientation_error_deg: FloatArray
    truth_index: np.ndarray
    n_packets: int


def build_scorer(sim: Simulation, kernel: str = "numpy") -> Scorer:
    """The (unmemoised) scorer of the simulation's device."""
    tx = sim.site.devices[0].transmitter
    return make_scorer(kernel, candidate_space(sim.site, tx))


def run_methods(
    sim: Simulation,
    methods: Sequence[str] = METHOD_NAMES,
    config: TrackerConfig | None = None,
    scorer: Scorer | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, MethodRun]:
    """Run methods on a simulation and compute each estimate's errors.

    Parameters
    ----------
    sim
        The simulation (its site, packets and truth).
    methods
        Names of :data:`radiopose.tracker.METHODS` to run (default: the built-in
        six, :data:`~radiopose.tracker.METHOD_NAMES`).
    config
        Pipeline parameters (paper defaults).
    scorer
        A prebuilt scorer for the simulation's device at its site (reused
        across simulations that share the site); built if omitted.
    progress
        Called as ``progress(method, done, total)``.
    """
    cfg = config or TrackerConfig()
    tx = sim.site.devices[0].transmitter
    scorers = None
    if any(reads_site_scorer(get_method(m), sim.site) for m in methods):
        inner = scorer if scorer is not None else build_scorer(sim, cfg.kernel)
        scorers = {tx: MemoScorer(inner)}
    n_packets = len(group_packets(sim.packets))
    out = {}
    for m in methods:
        cb = None if progress is None else (lambda d, t, m=m: progress(m, d, t))
        res = locate(sim.site, sim.packets, m, cfg, cb, scorers)
        est = res.estimates
        idx = match_truth(sim.truth, est)
        pos = np.linalg.norm(est.position_m - sim.truth.position_m[idx], axis=1)
        if not METHODS[m].estimates_orientation or len(est) == 0:
            ori = np.empty(0)
        else:
            ori = orientation_error_deg(est.orientation_deg, sim.truth.orientation_deg[idx])
        out[m] = MethodRun(m, est, res.summary, pos, ori, idx, n_packets)
    return out
