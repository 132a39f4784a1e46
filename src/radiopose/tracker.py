"""The streaming tracker and the batch run: packets in, pose estimates out.

Paper, "Enhanced Localisation Pipeline". For each packet of an enrolled device:

1. score every candidate pose and keep the top k (:mod:`radiopose.likelihood`);
2. weight the candidates by normalised, inverted MSE (:mod:`radiopose.clustering`);
3. cluster orientations per axis (wrap-aware DBSCAN) and 4. drop clusters the
   rotation model rejects (:mod:`radiopose.motion`);
5. cluster the surviving candidates' positions and drop clusters the movement
   model rejects;
6. score clusters (``Σ w²``), pick the best cluster of the *primary* quantity
   (position by default), keep only its candidates and take the weighted mean
   of the other quantity.

Methods (:data:`METHODS`, the paper's comparison): ``full`` (all of the above),
``location`` (position clustering + movement model only), ``orientation``
(orientation clustering + rotation model only), ``top`` (the best single
candidate) and ``lms`` (log-distance least squares, position only,
:mod:`radiopose.baselines`).

State is explicit: :func:`track_step` maps ``(state, candidates)`` to
``(state, outcome)`` without side effects; :class:`Tracker` keeps one
:class:`TrackState` per transmitter and dispatches packets. :func:`locate` runs a
whole packets table and returns the estimates with a :class:`RunSummary`.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from radiopose.baselines import LmsLocator
from radiopose.clustering import (
    AxisCluster,
    cluster_axis_deg,
    cluster_positions_m,
    cluster_score,
    inverted_weights,
    weighted_orientation_deg,
)
from radiopose.errors import InputError
from radiopose.estimates import Estimates, PoseEstimate
from radiopose.filtering import FilterConfig, FilterModel, FilterState, ParticleFilter
from radiopose.likelihood import (
    CandidateSpace,
    HeardRss,
    Scorer,
    TopK,
    candidate_space,
    make_scorer,
)
from radiopose.motion import PERIODIC_AXES, MovementModel, RotationModel
from radiopose.packets import PacketObservation, Packets, group_packets
from radiopose.site import Site
from radiopose.units import FloatArray

PAPER_METHODS: tuple[str, ...] = ("full", "location", "orientation", "top", "lms")
"""The paper's five comparison methods (the reproduction)."""
METHODS: tuple[str, ...] = (*PAPER_METHODS, "filter")
"""Every method: the paper's five and ``filter``, the Bayesian tracker
(:mod:`radiopose.filtering`, docs/filter.md)."""

SKIP_UNKNOWN_TRANSMITTER = "unknown transmitter"
SKIP_TOO_FEW_RECEIVERS = "too few receivers"
SKIP_OUT_OF_ORDER = "timestamp before previous packet"
SKIP_NO_CANDIDATES = "no scorable candidate"
SKIP_NO_ORIENTATION_CLUSTER = "no orientation cluster"
SKIP_ROTATION_MODEL = "rejected by rotation model"
SKIP_NO_POSITION_CLUSTER = "no position cluster"
SKIP_MOVEMENT_MODEL = "rejected by movement model"
SKIP_ACQUIRING = "acquiring (pooling packets)"
SKIP_NO_TRACK = "no track yet (needs a packet heard by 3 receivers)"


@dataclass(frozen=True)
class TrackerConfig:
    """Every parameter of the pipeline; defaults are the paper's values, except
    ``acquisition_window_s``: the paper leaves open how a track starts.

    Attributes
    ----------
    k
        Candidates kept per packet (step 2).
    orientation_eps_deg, orientation_min_samples
        DBSCAN on each rotation axis (step 3): 2°, 10.
    wrap_duplication
        Duplicate angles at ±360° before clustering (step 3). Off only for ablation.
    max_rotation_deg, rotation_period_s
        Rotation model (step 4): at most 180° per 0.5 s on any axis.
    max_orientation_gap_s
        Re-acquire orientation without constraint past this gap since the
        previous valid orientation; ``None`` = ``rotation_period_s / 2`` (the paper's ``t/2``).
    use_rotation_model
        Apply step 4 (off only for ablation).
    position_eps_m, position_min_samples
        DBSCAN on positions (step 5): 0.5 m, 10.
    max_speed_mps
        Movement model (step 5): 10 m/s.
    max_position_gap_s
        Re-acquire position without constraint past this gap since the previous
        valid position; ``None`` = ``rotation_period_s / 2``: the paper caps the
        gap between valid *estimates* at ``t/2``, so both models lapse together.
    use_movement_model
        Apply the movement model (off only for ablation).
    primary
        Which clustering decides when position and orientation clusters are
        not one-to-one (step 6): ``"position"`` (default) or ``"orientation"``.
    min_receivers
        Packets heard by fewer receivers are skipped (3: two receivers leave
        a whole curve of positions equally likely).
    kernel
        Likelihood scorer (:data:`radiopose.likelihood.SCORERS`).
    acquisition_window_s
        How (re-)acquisition pools packets, seconds. While no previous
        estimate constrains the track — at the start, and past the gap cap —
        the first packet opens a window; the pose is taken at the first packet
        at least this long after it, from the top-k of every packet of the last
        ``acquisition_window_s`` pooled and clustered together without motion
        constraints (the packets before yield no estimate; if the pool gives
        no pose, every following packet tries again with its own window).
        With sparse packets the window holds one packet and this is the
        single-packet rule. Default 0.1 s (20 packets at the paper's 5 ms),
        chosen and checked on seeds the accuracy table does not use. ``0``:
        every packet on its own, the paper's pipeline applied literally. The
        paper does not say how a track starts or restarts; see
        docs/pipeline.md, "Acquisition".
    search
        ``"full"`` (default): every packet's top-k comes from the whole
        candidate grid, as in the paper's pipeline description. ``"bounded"``:
        while the previous valid position / orientation is fresher than the gap
        cap, score only positions within the movement bound (plus half a grid
        cell's diagonal, so the cell of the previous position is always in) and
        azimuths within the rotation bound (plus half a step) — the paper's
        "Performance" remark; otherwise, and for ``top``, the whole grid
        (re-acquisition). Needs a scorer with ``score_window`` (the compiled one);
        others search the whole grid.
    filter
        Parameters of the ``filter`` method (:class:`radiopose.filtering.FilterConfig`);
        its motion prior's support is ``max_speed_mps`` and twice the rotation
        bound (:func:`filter_config`).
    smoothing_lag_s
        ``filter`` in batch :func:`locate`: the fixed-lag smoother's lag, seconds
        (``None``: causal, as the live server runs it). The streaming
        :class:`Tracker` is always causal.
    seed
        Seeds the ``filter``'s random numbers (with the transmitter id), so runs repeat.
    """

    k: int = 100
    orientation_eps_deg: float = 2.0
    orientation_min_samples: int = 10
    wrap_duplication: bool = True
    max_rotation_deg: float = 180.0
    rotation_period_s: float = 0.5
    max_orientation_gap_s: float | None = None
    use_rotation_model: bool = True
    position_eps_m: float = 0.5
    position_min_samples: int = 10
    max_speed_mps: float = 10.0
    max_position_gap_s: float | None = None
    use_movement_model: bool = True
    primary: Literal["position", "orientation"] = "position"
    min_receivers: int = 3
    kernel: str = "numba"
    search: Literal["full", "bounded"] = "full"
    acquisition_window_s: float = 0.1
    filter: FilterConfig = field(default_factory=FilterConfig)
    smoothing_lag_s: float | None = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        checks = [
            ("k", self.k >= 1),
            ("orientation_eps_deg", self.orientation_eps_deg > 0),
            ("orientation_min_samples", self.orientation_min_samples >= 1),
            ("max_rotation_deg", self.max_rotation_deg > 0),
            ("rotation_period_s", self.rotation_period_s > 0),
            (
                "max_orientation_gap_s",
                self.max_orientation_gap_s is None or self.max_orientation_gap_s >= 0,
            ),
            ("position_eps_m", self.position_eps_m > 0),
            ("position_min_samples", self.position_min_samples >= 1),
            ("max_speed_mps", self.max_speed_mps > 0),
            ("max_position_gap_s", self.max_position_gap_s is None or self.max_position_gap_s >= 0),
            ("primary", self.primary in ("position", "orientation")),
            ("min_receivers", self.min_receivers >= 1),
            ("search", self.search in ("full", "bounded")),
            ("acquisition_window_s", 0 <= self.acquisition_window_s < math.inf),
            (
                "smoothing_lag_s",
                self.smoothing_lag_s is None or 0 <= self.smoothing_lag_s < math.inf,
            ),
            ("seed", 0 <= self.seed < 2**63),
        ]
        for name, ok in checks:
            if not ok:
                raise InputError(
                    f"tracker setting {name} = {getattr(self, name)!r} is out of range"
                )

    @property
    def rotation_model(self) -> RotationModel:
        return RotationModel(
            self.max_rotation_deg, self.rotation_period_s, self.max_orientation_gap_s
        )

    @property
    def movement_model(self) -> MovementModel:
        gap = self.max_position_gap_s
        return MovementModel(
            self.max_speed_mps, self.rotation_period_s / 2.0 if gap is None else gap
        )


@dataclass(frozen=True)
class TrackState:
    """What the tracker remembers about one transmitter between packets.

    Attributes
    ----------
    last_time_s
        Time of the last packet processed (estimated or not).
    position_time_s, position_m
        Time and ``(x, y, z)`` of the previous valid position.
    orientation_time_s, orientation_deg
        Time and ``(azimuth, pitch, roll)`` of the previous valid orientation.
    acquiring_since_s
        While acquiring with ``TrackerConfig.acquisition_window_s > 0``: when
        the acquisition window opened.
    pending
        The times and top-k of the packets of the current window.
    """

    last_time_s: float | None = None
    position_time_s: float | None = None
    position_m: tuple[float, float, float] | None = None
    orientation_time_s: float | None = None
    orientation_deg: tuple[float, float, float] | None = None
    acquiring_since_s: float | None = None
    pending: tuple[tuple[float, Candidates], ...] = ()


@dataclass(frozen=True, eq=False)
class Candidates:
    """The top-k of one packet as poses.

    Attributes
    ----------
    positions_m
        ``(k, 3)`` metres.
    orientations_deg
        ``(k, 3)`` (azimuth, pitch, roll), degrees.
    mse_db2
        ``(k,)`` MSE, dB², best first.
    """

    positions_m: FloatArray
    orientations_deg: FloatArray
    mse_db2: FloatArray

    @classmethod
    def from_topk(cls, space: CandidateSpace, top: TopK) -> Candidates:
        return cls(
            space.candidate_positions_m(top.candidate_idx),
            space.candidate_orientations_deg(top.candidate_idx),
            top.mse_db2,
        )

    def __len__(self) -> int:
        return int(self.mse_db2.size)

    @classmethod
    def pooled(cls, parts: tuple[Candidates, ...]) -> Candidates:
        """The candidates of several packets as one set, best first (stable)."""
        mse = np.concatenate([c.mse_db2 for c in parts])
        order = np.argsort(mse, kind="stable")
        return cls(
            np.concatenate([c.positions_m for c in parts])[order],
            np.concatenate([c.orientations_deg for c in parts])[order],
            mse[order],
        )


@dataclass(frozen=True)
class Outcome:
    """Result of one step: a pose, or the reason there is none."""

    position_m: tuple[float, float, float] | None = None
    orientation_deg: tuple[float, float, float] | None = None
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.position_m is not None


# ----------------------------------------------------------------------------- steps
@dataclass(frozen=True, eq=False)
class _OrientationCluster:
    centroid_deg: FloatArray  # (3,)
    members: np.ndarray


def orientation_clusters(
    orientations_deg: FloatArray, weights: FloatArray, config: TrackerConfig
) -> list[_OrientationCluster]:
    """Orientation clusters: per-axis DBSCAN, combined by intersecting members.

    An axis on which every candidate has the same value (e.g. pitch with a
    single grid value) is one cluster of all candidates — what DBSCAN returns
    when there are at least ``min_samples`` of them — without running DBSCAN.
    """
    o = np.asarray(orientations_deg, dtype=np.float64).reshape(-1, 3)
    n = o.shape[0]
    per_axis: list[tuple[AxisCluster, ...]] = []
    for axis in range(3):
        vals = o[:, axis]
        if n >= config.orientation_min_samples and np.all(vals == vals[0]):
            per_axis.append((AxisCluster(float(vals[0]), np.arange(n, dtype=np.int64)),))
            continue
        per_axis.append(
            cluster_axis_deg(
                vals,
                weights,
                eps_deg=config.orientation_eps_deg,
                min_samples=config.orientation_min_samples,
                periodic=PERIODIC_AXES[axis],
                wrap_duplication=config.wrap_duplication,
            )
        )
    out = []
    for ca in per_axis[0]:
        for cp in per_axis[1]:
            for cr in per_axis[2]:
                members = _meet(_meet(ca.members, cp.members, n), cr.members, n)
                if members.size:
                    c = np.array([ca.centroid_deg, cp.centroid_deg, cr.centroid_deg])
                    out.append(_OrientationCluster(c, members))
    return out


def _meet(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Intersection of two increasing index sets drawn from ``0 … n−1``."""
    if a.size == n:
        return b
    if b.size == n:
        return a
    return np.intersect1d(a, b, assume_unique=True)


def _dt(t_s: float, since_s: float | None) -> float:
    return 0.0 if since_s is None else t_s - since_s


def _position_stage(
    cand: Candidates,
    w: FloatArray,
    subset: np.ndarray,
    state: TrackState,
    t_s: float,
    config: TrackerConfig,
) -> tuple[list[tuple[FloatArray, np.ndarray]], str | None]:
    """Position clusters of ``subset`` surviving the movement model, as (centroid, members)."""
    clusters = cluster_positions_m(
        cand.positions_m[subset],
        w[subset],
        eps_m=config.position_eps_m,
        min_samples=config.position_min_samples,
    )
    if not clusters:
        return [], SKIP_NO_POSITION_CLUSTER
    centroids = np.array([c.centroid_m for c in clusters])
    if config.use_movement_model:
        prev = None if state.position_m is None else np.asarray(state.position_m)
        ok = config.movement_model.valid(centroids, prev, _dt(t_s, state.position_time_s))
    else:
        ok = np.ones(len(clusters), dtype=bool)
    kept = [(c.centroid_m, subset[c.members]) for c, good in zip(clusters, ok, strict=True) if good]
    return kept, (None if kept else SKIP_MOVEMENT_MODEL)


def _orientation_stage(
    cand: Candidates, w: FloatArray, state: TrackState, t_s: float, config: TrackerConfig
) -> tuple[list[_OrientationCluster], str | None]:
    clusters = orientation_clusters(cand.orientations_deg, w, config)
    if not clusters:
        return [], SKIP_NO_ORIENTATION_CLUSTER
    if config.use_rotation_model:
        prev = None if state.orientation_deg is None else np.asarray(state.orientation_deg)
        ok = config.rotation_model.valid(
            np.array([c.centroid_deg for c in clusters]), prev, _dt(t_s, state.orientation_time_s)
        )
        clusters = [c for c, good in zip(clusters, ok, strict=True) if good]
    return clusters, (None if clusters else SKIP_ROTATION_MODEL)


def _pose(position: FloatArray, orientation: FloatArray) -> Outcome:
    return Outcome(
        tuple(float(x) for x in position),  # type: ignore[arg-type]
        tuple(float(x) for x in orientation),  # type: ignore[arg-type]
    )


def step_full(cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig) -> Outcome:
    """The paper's full pipeline (steps 3–6) on one packet's top-k."""
    w = inverted_weights(cand.mse_db2)
    oclusters, why = _orientation_stage(cand, w, state, t_s, config)
    if why:
        return Outcome(reason=why)
    survivors = np.unique(np.concatenate([c.members for c in oclusters]))
    pclusters, why = _position_stage(cand, w, survivors, state, t_s, config)
    if why:
        return Outcome(reason=why)
    if config.primary == "position":
        centroid, members = max(pclusters, key=lambda pc: cluster_score(w, pc[1]))
        orient = weighted_orientation_deg(cand.orientations_deg[members], w[members], PERIODIC_AXES)
        return _pose(centroid, orient)
    in_position = np.unique(np.concatenate([m for _, m in pclusters]))
    for oc in sorted(oclusters, key=lambda c: -cluster_score(w, c.members)):
        members = np.intersect1d(oc.members, in_position)
        if members.size:
            wm = w[members] if float(w[members].sum()) > 0 else np.ones(members.size)
            pos = np.average(cand.positions_m[members], axis=0, weights=wm)
            return _pose(pos, oc.centroid_deg)
    return Outcome(reason=SKIP_NO_POSITION_CLUSTER)  # unreachable: pclusters ⊂ survivors


def step_location(
    cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig
) -> Outcome:
    """Location clustering + movement model only; orientation = weighted mean of the cluster."""
    w = inverted_weights(cand.mse_db2)
    pclusters, why = _position_stage(cand, w, np.arange(len(cand)), state, t_s, config)
    if why:
        return Outcome(reason=why)
    centroid, members = max(pclusters, key=lambda pc: cluster_score(w, pc[1]))
    orient = weighted_orientation_deg(cand.orientations_deg[members], w[members], PERIODIC_AXES)
    return _pose(centroid, orient)


def step_orientation(
    cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig
) -> Outcome:
    """Orientation clustering + rotation model only; position = weighted mean of the cluster."""
    w = inverted_weights(cand.mse_db2)
    oclusters, why = _orientation_stage(cand, w, state, t_s, config)
    if why:
        return Outcome(reason=why)
    best = max(oclusters, key=lambda c: cluster_score(w, c.members))
    wm = w[best.members] if float(w[best.members].sum()) > 0 else np.ones(best.members.size)
    pos = np.average(cand.positions_m[best.members], axis=0, weights=wm)
    return _pose(pos, best.centroid_deg)


def step_top(cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig) -> Outcome:
    """The best single candidate."""
    return _pose(cand.positions_m[0], cand.orientations_deg[0])


StepFunction = Callable[[Candidates, float, TrackState, TrackerConfig], Outcome]
PATTERN_STEPS: dict[str, StepFunction] = {
    "full": step_full,
    "location": step_location,
    "orientation": step_orientation,
    "top": step_top,
}
"""Methods that work on the top-k candidates (all but ``lms``)."""


def advance(state: TrackState, t_s: float, outcome: Outcome) -> TrackState:
    """The state after a packet at ``t_s`` with ``outcome`` (pure)."""
    if not outcome.ok:
        return replace(state, last_time_s=t_s)
    return TrackState(t_s, t_s, outcome.position_m, t_s, outcome.orientation_deg)


def acquiring(state: TrackState, t_s: float, config: TrackerConfig) -> bool:
    """Whether no previous estimate constrains a packet at ``t_s``: none yet, or
    the last one is past both models' gap caps."""
    since = state.position_time_s
    if since is None:
        return True
    gap_s = max(config.rotation_model.gap_s, config.movement_model.max_gap_s)
    return t_s - since > gap_s


def track_step(
    method: str, cand: Candidates | None, t_s: float, state: TrackState, config: TrackerConfig
) -> tuple[TrackState, Outcome]:
    """One pure pipeline step: ``(state, candidates) → (state, outcome)``."""
    if cand is None or len(cand) == 0:
        out = Outcome(reason=SKIP_NO_CANDIDATES)
    elif config.acquisition_window_s > 0 and method != "top" and acquiring(state, t_s, config):
        return _acquire(method, cand, t_s, state, config)
    else:
        out = PATTERN_STEPS[method](cand, t_s, state, config)
    return advance(state, t_s, out), out


def _acquire(
    method: str, cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig
) -> tuple[TrackState, Outcome]:
    """Pool this packet into the acquisition window; once the window has run
    its length, run the method's steps on the pooled top-k without motion
    constraints (see ``TrackerConfig.acquisition_window_s``)."""
    window_s = config.acquisition_window_s
    since = t_s if state.acquiring_since_s is None else state.acquiring_since_s
    pool = (*(p for p in state.pending if t_s - p[0] <= window_s), (t_s, cand))
    if t_s - since < window_s:
        waiting = replace(state, last_time_s=t_s, acquiring_since_s=since, pending=pool)
        return waiting, Outcome(reason=SKIP_ACQUIRING)
    out = PATTERN_STEPS[method](
        Candidates.pooled(tuple(c for _, c in pool)), t_s, TrackState(), config
    )
    if out.ok:
        return advance(state, t_s, out), out  # a fresh state: nothing pending
    return replace(state, last_time_s=t_s, acquiring_since_s=since, pending=pool), out


# ----------------------------------------------------------------------------- tracker
@dataclass
class _Device:
    space: CandidateSpace
    scorer: Scorer | None
    cell_m: float = 0.0  # half the candidate grid's cell diagonal (bounded search)
    n_azimuth: int = 1
    particle_filter: ParticleFilter | None = None

    def __post_init__(self) -> None:
        self.cell_m = _grid_half_diagonal_m(self.space)
        self.n_azimuth = int(np.unique(self.space.orientations_deg[:, 0]).size)


class Tracker:
    """Streaming tracker: one packet in, zero or one pose out.

    Parameters
    ----------
    site
        The site.
    method
        One of :data:`METHODS`.
    config
        Pipeline parameters.
    scorers
        Optional prebuilt scorers by transmitter (lower case); otherwise built
        on first use with ``config.kernel``.

    Notes
    -----
    ``states`` holds one :class:`TrackState` per transmitter (lower-case
    address); it is replaced, never mutated, on every packet.
    """

    def __init__(
        self,
        site: Site,
        method: str = "full",
        config: TrackerConfig | None = None,
        scorers: Mapping[str, Scorer] | None = None,
    ) -> None:
        if method not in METHODS:
            raise InputError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
        self.site = site
        self.method = method
        self.config = config or TrackerConfig()
        self.states: dict[str, TrackState] = {}
        self._scorers = {k.lower(): v for k, v in (scorers or {}).items()}
        self._devices: dict[str, _Device] = {}
        self._lms: LmsLocator | None = None
        self.lag_s: float | None = None  # the filter's smoothing lag (batch locate sets it)

    def _device(self, transmitter: str) -> _Device:
        key = transmitter.lower()
        dev = self._devices.get(key)
        if dev is None:
            scorer = self._scorers.get(key)
            space = scorer.space if scorer is not None else candidate_space(self.site, transmitter)
            if scorer is None and self.method in (*PATTERN_STEPS, "filter"):
                scorer = make_scorer(self.config.kernel, space)
            dev = _Device(space, scorer)
            if self.method == "filter":
                assert scorer is not None
                model = FilterModel.build(self.site, space, scorer)
                dev.particle_filter = ParticleFilter(model, filter_config(self.config), self.lag_s)
            self._devices[key] = dev
        return dev

    def is_enrolled(self, transmitter: str) -> bool:
        key = transmitter.lower()
        return any(d.transmitter.lower() == key for d in self.site.devices)

    def update(self, packet: PacketObservation) -> tuple[PoseEstimate | None, str | None]:
        """Process one packet; return ``(estimate, None)`` or ``(None, reason)``.

        Raises
        ------
        InputError
            The packet names a receiver that is not in the site.
        """
        if not self.is_enrolled(packet.transmitter):
            return None, SKIP_UNKNOWN_TRANSMITTER
        key = packet.transmitter.lower()
        dev = self._device(packet.transmitter)
        heard = dev.space.heard(packet)
        t = float(packet.timestamp_s)
        if self.method == "filter":
            return self._filter_update(dev, key, heard, t, packet.packet_id)
        state = self.states.get(key, TrackState())
        if not isinstance(state, TrackState):
            state = TrackState()
        if state.last_time_s is not None and t < state.last_time_s:
            return None, SKIP_OUT_OF_ORDER
        if heard.n_heard < self.config.min_receivers:
            self.states[key] = replace(state, last_time_s=t)
            return None, SKIP_TOO_FEW_RECEIVERS
        if self.method == "lms":
            if self._lms is None:
                self._lms = LmsLocator.for_site(self.site)
            pos = self._lms.locate(heard.receiver_index, heard.rss_dbm, dev.space.tx_power_dbm)
            out = Outcome(tuple(float(x) for x in pos), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
            self.states[key] = advance(state, t, out)
        else:
            assert dev.scorer is not None
            top = self._score(dev, heard, t, state)
            cand = Candidates.from_topk(dev.space, top)
            self.states[key], out = track_step(self.method, cand, t, state, self.config)
        if not out.ok:
            return None, out.reason
        est = PoseEstimate(
            t,
            dev.space.transmitter,
            packet.packet_id,
            out.position_m,
            out.orientation_deg,
            self.method,  # type: ignore[arg-type]
        )
        return est, None

    def _filter_update(
        self, dev: _Device, key: str, heard: HeardRss, t_s: float, packet_id: str
    ) -> tuple[PoseEstimate | None, str | None]:
        """One packet through the device's particle filter (causal estimate; with a
        smoothing lag the smoothed estimates are collected by :func:`locate`)."""
        pf = dev.particle_filter
        assert pf is not None
        state = self.states.get(key)
        if not isinstance(state, FilterState):
            state = pf.new_state(_filter_seed(self.config.seed, key))
            self.states[key] = state  # type: ignore[assignment]
        if state.last_time_s is not None and t_s < state.last_time_s:
            return None, SKIP_OUT_OF_ORDER
        if heard.n_heard == 0:
            return None, SKIP_TOO_FEW_RECEIVERS
        est = pf.step(state, t_s, heard, (key, packet_id))
        if est is None:
            return None, SKIP_NO_TRACK
        return _filter_pose(t_s, dev.space.transmitter, packet_id, est), None

    def _score(self, dev: _Device, heard: HeardRss, t_s: float, state: TrackState) -> TopK:
        """Top-k of one packet: the whole grid, or the motion-bounded window."""
        cfg = self.config
        window = getattr(dev.scorer, "score_window", None)
        if cfg.search != "bounded" or window is None or self.method == "top":
            return dev.scorer.score_heard(heard, cfg.k)  # type: ignore[union-attr]
        space = dev.space
        positions = None
        if self.method in ("full", "location") and state.position_m is not None:
            dt = t_s - float(state.position_time_s)  # type: ignore[arg-type]
            move = cfg.movement_model
            if dt <= move.max_gap_s:
                d = np.linalg.norm(space.positions_m - np.asarray(state.position_m), axis=1)
                positions = np.flatnonzero(d <= move.allowed_m(dt) + dev.cell_m)
        lo_deg, span_deg = 0.0, 360.0
        if self.method in ("full", "orientation") and state.orientation_deg is not None:
            dt = t_s - float(state.orientation_time_s)  # type: ignore[arg-type]
            rot = cfg.rotation_model
            if dt <= rot.gap_s:
                half = rot.allowed_deg(dt) + 0.5 * (360.0 / dev.n_azimuth)
                if half < 180.0:
                    lo_deg, span_deg = state.orientation_deg[0] - half, 2.0 * half
        if positions is None and span_deg >= 360.0:
            return dev.scorer.score_heard(heard, cfg.k)  # type: ignore[union-attr]
        if positions is None:
            positions = np.arange(space.n_positions)
        return window(heard, cfg.k, positions, lo_deg, span_deg)


def _grid_half_diagonal_m(space: CandidateSpace) -> float:
    xs = np.unique(space.positions_m[:, 0])
    ys = np.unique(space.positions_m[:, 1])
    dx = float(np.min(np.diff(xs))) if xs.size > 1 else 0.0
    dy = float(np.min(np.diff(ys))) if ys.size > 1 else 0.0
    return 0.5 * float(np.hypot(dx, dy))


def filter_config(config: TrackerConfig) -> FilterConfig:
    """The ``filter``'s parameters with the motion prior's support from the
    tracker's limits: ``max_speed_mps`` and twice the rotation bound
    (``max_rotation_deg / rotation_period_s``, 360°/s by default) — a prior,
    not a veto: rotation beyond the paper's bound is followed."""
    rate_dps = config.max_rotation_deg / config.rotation_period_s
    return replace(config.filter, max_speed_mps=config.max_speed_mps, max_rate_dps=2.0 * rate_dps)


def _filter_seed(seed: int, transmitter_key: str) -> int:
    import zlib

    return (seed * 1_000_003 + zlib.crc32(transmitter_key.encode())) % 2**63


def _filter_pose(t_s: float, transmitter: str, packet_id: str, est) -> PoseEstimate:  # type: ignore[no-untyped-def]
    return PoseEstimate(
        t_s,
        transmitter,
        packet_id,
        est.position_m,
        est.orientation_deg,
        "filter",
        est.position_std_m,
        est.azimuth_std_deg,
    )


# ----------------------------------------------------------------------------- batch
@dataclass(frozen=True)
class RunSummary:
    """What a batch run did.

    Attributes
    ----------
    method
        The method run.
    packets_in
        Packets read (distinct transmitter + packet id).
    estimates_out
        Estimates written.
    skipped
        ``(reason, count)`` pairs, most frequent first.
    elapsed_s
        Wall time, seconds.
    """

    method: str
    packets_in: int
    estimates_out: int
    skipped: tuple[tuple[str, int], ...] = field(default=())
    elapsed_s: float = 0.0

    @property
    def coverage(self) -> float:
        """Estimates ÷ packets (0 for no packets)."""
        return self.estimates_out / self.packets_in if self.packets_in else 0.0

    def lines(self) -> list[str]:
        """Human-readable summary lines."""
        out = [
            f"method {self.method}: {self.packets_in} packets in, {self.estimates_out} estimates "
            f"out (coverage {100 * self.coverage:.1f} %) in {self.elapsed_s:.1f} s"
        ]
        out += [f"  skipped {n}: {reason}" for reason, n in self.skipped]
        return out


@dataclass(frozen=True, eq=False)
class LocateResult:
    """Estimates of a batch run and its summary."""

    estimates: Estimates
    summary: RunSummary


def _check_packets(site: Site, packets: Packets) -> list[PacketObservation]:
    if len(packets) == 0:
        raise InputError(
            "no packets (the file has a header but no rows)", path=packets.path, line=2
        )
    known = set(site.receiver_ids)
    for i, rid in enumerate(packets.receiver_id):
        if rid not in known:
            line = None if packets.lines is None else int(packets.lines[i])
            raise InputError(
                f"receiver {rid!r} is not in the site (site receivers: "
                f"{', '.join(site.receiver_ids)})",
                path=packets.path,
                line=line,
                column="receiver_id",
            )
    obs = group_packets(packets)
    last: dict[str, tuple[float, str]] = {}
    for o in obs:
        seen: dict[str, int] = {}
        for k, rid in enumerate(o.receiver_ids):
            if rid in seen:
                raise InputError(
                    f"packet {o.packet_id!r} of {o.transmitter} has two rows for receiver "
                    f"{rid!r} (the first on line {o.line_of(seen[rid])})",
                    path=packets.path,
                    line=o.line_of(k),
                    column="receiver_id",
                )
            seen[rid] = k
        key = o.transmitter.lower()
        prev = last.get(key)
        if prev is not None and o.timestamp_s < prev[0]:
            raise InputError(
                f"timestamp {o.timestamp_s:.9g} s of packet {o.packet_id!r} is earlier than the "
                f"previous packet {prev[1]!r} of {o.transmitter} ({prev[0]:.9g} s); packets of "
                "a transmitter must be in time order",
                path=packets.path,
                line=o.line,
                column="timestamp_s",
            )
        last[key] = (o.timestamp_s, o.packet_id)
    enrolled = {d.transmitter.lower() for d in site.devices}
    if not any(o.transmitter.lower() in enrolled for o in obs):
        raise InputError(
            f"no packet is from an enrolled transmitter (first: {obs[0].transmitter!r}; "
            f"devices.csv has {', '.join(d.transmitter for d in site.devices) or 'none'})",
            path=packets.path,
            column="transmitter",
        )
    return obs


def _smoothed(
    tracker: Tracker, obs: list[PacketObservation], causal: list[PoseEstimate | None]
) -> list[PoseEstimate | None]:
    """Replace the filter's causal estimates by its fixed-lag smoothed ones."""
    best: dict[tuple[str, str], object] = {}
    for key, dev in tracker._devices.items():
        pf = dev.particle_filter
        state = tracker.states.get(key)
        if pf is None or not isinstance(state, FilterState):
            continue
        pf.flush(state)
        best.update(pf.take_smoothed())  # type: ignore[arg-type]
    out: list[PoseEstimate | None] = []
    for o, c in zip(obs, causal, strict=True):
        e = best.get((o.transmitter.lower(), o.packet_id))
        if c is not None and e is not None:
            c = _filter_pose(c.timestamp_s, c.transmitter, c.packet_id, e)
        out.append(c)
    return out


def locate(
    site: Site,
    packets: Packets,
    method: str = "full",
    config: TrackerConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    scorers: Mapping[str, Scorer] | None = None,
) -> LocateResult:
    """Run a method over a packets table.

    Parameters
    ----------
    site
        The site.
    packets
        Synchronised packets (``packets.csv`` rows).
    method
        One of :data:`METHODS`.
    config
        Pipeline parameters (paper defaults).
    progress
        Called as ``progress(done, total)`` after each packet.
    scorers
        Optional prebuilt scorers by transmitter (see :class:`Tracker`).

    Returns
    -------
    The estimates (one per packet with a valid estimate) and a run summary.

    Raises
    ------
    InputError
        Empty table, a receiver not in the site, a receiver twice in one packet,
        time going backwards within a transmitter, or no enrolled transmitter at
        all. Packets of unknown transmitters and packets heard by too few
        receivers are skipped and counted in the summary.
    """
    t0 = time.perf_counter()
    obs = _check_packets(site, packets)
    tracker = Tracker(site, method, config, scorers)
    if method == "filter":
        tracker.lag_s = tracker.config.smoothing_lag_s
    found: list[PoseEstimate | None] = []
    skipped: Counter[str] = Counter()
    for i, o in enumerate(obs):
        est, reason = tracker.update(o)
        found.append(est)
        if est is None:
            skipped[reason or "unknown"] += 1
        if progress is not None:
            progress(i + 1, len(obs))
    if method == "filter" and tracker.lag_s is not None:
        found = _smoothed(tracker, obs, found)
    poses = [p for p in found if p is not None]
    summary = RunSummary(
        method, len(obs), len(poses), tuple(skipped.most_common()), time.perf_counter() - t0
    )
    return LocateResult(Estimates.from_poses(poses), summary)
