"""The tracker: packets in, pose estimates out, by a registered method.

Layout (one module per concern):

* :mod:`~radiopose.tracker.config` — :class:`TrackerConfig`, every parameter;
* :mod:`~radiopose.tracker.protocol` — the :class:`Method` protocol (state, step,
  evidence, orientation, acquisition, lag) and its types;
* :mod:`~radiopose.tracker.registry` — :data:`METHODS`, the one registry every
  front end reads, and the live server's default (:func:`default_live_method`:
  :data:`DEFAULT_LIVE_METHOD` at a 2-D site, :data:`DEFAULT_LIVE_METHOD_3D` at
  a 3-D one);
* :mod:`~radiopose.tracker.paper` — the paper's top-k methods ``full``,
  ``location``, ``orientation``, ``top`` (steps 3–6, :class:`TrackState`);
* :mod:`~radiopose.tracker.lms` — the ``lms`` baseline;
* :mod:`~radiopose.tracker.filter` — ``filter``, the adapter onto
  :class:`radiopose.filtering.ParticleFilter`;
* :mod:`~radiopose.tracker.stream` — :class:`Tracker`, the streaming tracker;
* :mod:`~radiopose.tracker.batch` — :func:`locate`, a whole packets table.

Methods (:data:`METHODS`, the paper's comparison plus one): ``full`` (the paper's
pipeline), ``location`` (position clustering + movement model only),
``orientation`` (orientation clustering + rotation model only), ``top`` (the best
single candidate), ``lms`` (log-distance least squares, position only,
:mod:`radiopose.baselines`) and ``filter`` (the Bayesian tracker, docs/filter.md).
docs/methods.md shows how to add one.
"""

from __future__ import annotations

from radiopose.tracker.batch import SKIP_NEVER_EMITTED, LocateResult, RunSummary, locate
from radiopose.tracker.config import TrackerConfig, filter_config
from radiopose.tracker.filter import FilterMethod, filter_seed
from radiopose.tracker.lms import LmsMethod
from radiopose.tracker.paper import (
    PATTERN_STEPS,
    TOPK_METHODS,
    Candidates,
    PaperMethod,
    StepFunction,
    TrackState,
    acquiring,
    advance,
    orientation_clusters,
    step_full,
    step_location,
    step_orientation,
    step_top,
    track_step,
)
from radiopose.tracker.protocol import (
    Delayed,
    Device,
    Evidence,
    Method,
    Outcome,
    Step,
    needs_scorer,
)
from radiopose.tracker.reasons import (
    PENDING,
    SKIP_ACQUIRING,
    SKIP_DUPLICATE,
    SKIP_ENGINE_UNRECORDED,
    SKIP_METHOD_FAILED,
    SKIP_MOVEMENT_MODEL,
    SKIP_NO_CANDIDATES,
    SKIP_NO_ORIENTATION_CLUSTER,
    SKIP_NO_POSITION_CLUSTER,
    SKIP_NO_TRACK,
    SKIP_OUT_OF_ORDER,
    SKIP_ROTATION_MODEL,
    SKIP_SITE_CHANGED,
    SKIP_TOO_FEW_RECEIVERS,
    SKIP_UNKNOWN_TRANSMITTER,
)
from radiopose.tracker.registry import (
    DEFAULT_LIVE_METHOD,
    DEFAULT_LIVE_METHOD_3D,
    METHOD_NAMES,
    METHODS,
    PAPER_METHODS,
    PLUGIN_GROUP,
    PLUGINS_ENV,
    RESERVED_NAMES,
    default_live_method,
    get_method,
    load_plugins,
    register_method,
)
from radiopose.tracker.stream import Tracker

__all__ = [
    "DEFAULT_LIVE_METHOD",
    "DEFAULT_LIVE_METHOD_3D",
    "METHODS",
    "METHOD_NAMES",
    "PAPER_METHODS",
    "PATTERN_STEPS",
    "PENDING",
    "PLUGINS_ENV",
    "PLUGIN_GROUP",
    "RESERVED_NAMES",
    "SKIP_ACQUIRING",
    "SKIP_DUPLICATE",
    "SKIP_ENGINE_UNRECORDED",
    "SKIP_METHOD_FAILED",
    "SKIP_MOVEMENT_MODEL",
    "SKIP_NEVER_EMITTED",
    "SKIP_NO_CANDIDATES",
    "SKIP_NO_ORIENTATION_CLUSTER",
    "SKIP_NO_POSITION_CLUSTER",
    "SKIP_NO_TRACK",
    "SKIP_OUT_OF_ORDER",
    "SKIP_ROTATION_MODEL",
    "SKIP_SITE_CHANGED",
    "SKIP_TOO_FEW_RECEIVERS",
    "SKIP_UNKNOWN_TRANSMITTER",
    "TOPK_METHODS",
    "Candidates",
    "Delayed",
    "Device",
    "Evidence",
    "FilterMethod",
    "LmsMethod",
    "LocateResult",
    "Method",
    "Outcome",
    "PaperMethod",
    "RunSummary",
    "Step",
    "StepFunction",
    "TrackState",
    "Tracker",
    "TrackerConfig",
    "acquiring",
    "advance",
    "default_live_method",
    "filter_config",
    "filter_seed",
    "get_method",
    "load_plugins",
    "locate",
    "needs_scorer",
    "orientation_clusters",
    "register_method",
    "step_full",
    "step_location",
    "step_orientation",
    "step_top",
    "track_step",
]

# Methods of other packages and of the modules named in RADIOPOSE_METHODS
# (docs/methods.md, "Methods from outside the package"): registered here, after
# every name above is bound, so that a plugin may import radiopose.tracker.
load_plugins()
