"""Radiation patterns: value object, CSV io, enrolment, importers, synthesis, plots."""

from radiopose.patterns.pattern import (
    Pattern,
    mean_intensity,
    read_pattern_csv,
    write_pattern_csv,
)
from radiopose.patterns.synthetic import dipole, isotropic, smartphone_like

__all__ = [
    "Pattern",
    "dipole",
    "isotropic",
    "mean_intensity",
    "read_pattern_csv",
    "smartphone_like",
    "write_pattern_csv",
]
