"""Simulation: channel model, trajectories, scenarios and their writers."""

from radiopose.simulate.channel import LogDistance, link_rss_dbm
from radiopose.simulate.scenario import ScenarioConfig, Simulation, seed_range, simulate
from radiopose.simulate.trajectories import MotionConfig

__all__ = [
    "LogDistance",
    "MotionConfig",
    "ScenarioConfig",
    "Simulation",
    "link_rss_dbm",
    "seed_range",
    "simulate",
]
