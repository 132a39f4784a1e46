"""Bayesian tracking (beyond the paper): a particle filter over position, velocity,
orientation, turn rate and transmit-power offset.

:mod:`~radiopose.filtering.particle` holds the filter (configuration, state,
step, fixed-lag smoother); :mod:`~radiopose.filtering.kernels` its compiled
per-particle kernels. The tracker registers it as the method ``filter``
(docs/filter.md).
"""

from radiopose.filtering.particle import (
    FilterConfig,
    FilterEstimate,
    FilterModel,
    FilterState,
    ParticleFilter,
)

__all__ = ["FilterConfig", "FilterEstimate", "FilterModel", "FilterState", "ParticleFilter"]
