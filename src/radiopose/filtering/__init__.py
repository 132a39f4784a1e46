"""Bayesian tracking (beyond the paper): a particle filter over position, velocity,
orientation, turn rate and transmit-power offset.

:mod:`~radiopose.filtering.particle` holds the filter (state, step, re-entry,
fixed-lag smoother), :mod:`~radiopose.filtering.config` its configuration and
result, :mod:`~radiopose.filtering.model` a device's arrays at a site,
:mod:`~radiopose.filtering.kernels` its compiled per-particle kernels and
:mod:`~radiopose.filtering.lineage` the smoother's genealogy,
:mod:`~radiopose.filtering.reverse` the offline time-reversed pass; in 3-D (height,
pitch, roll) :mod:`~radiopose.filtering.particle3d` and
:mod:`~radiopose.filtering.kernels3d`. The tracker registers it as the method ``filter``
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
