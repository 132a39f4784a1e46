"""Radiation patterns: value object, CSV io, enrolment, importers, synthesis, plots.

Plots live in :mod:`radiopose.patterns.plot` (imported on demand: matplotlib).
"""

from radiopose.patterns.enrol import (
    EnrolConfig,
    Measurements,
    enrol,
    enrol_csv,
    read_measurements_csv,
    simulate_positioner_measurements,
    write_measurements_csv,
)
from radiopose.patterns.importers import (
    read_basta_json,
    read_mitll,
    read_mitll_measurements,
    read_msi,
)
from radiopose.patterns.pattern import (
    Pattern,
    mean_intensity,
    read_pattern_csv,
    write_pattern_csv,
)
from radiopose.patterns.synthetic import dipole, isotropic, smartphone_like

__all__ = [
    "EnrolConfig",
    "Measurements",
    "Pattern",
    "dipole",
    "enrol",
    "enrol_csv",
    "isotropic",
    "mean_intensity",
    "read_basta_json",
    "read_measurements_csv",
    "read_mitll",
    "read_mitll_measurements",
    "read_msi",
    "read_pattern_csv",
    "simulate_positioner_measurements",
    "smartphone_like",
    "write_measurements_csv",
    "write_pattern_csv",
]
