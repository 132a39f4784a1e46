"""The paper's pipeline: the top-k methods ``full``, ``location``, ``orientation`` and ``top``.

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

``full`` is all of the above, ``location`` position clustering + movement model
only, ``orientation`` orientation clustering + rotation model only, ``top`` the
best single candidate. State is explicit: :func:`track_step` maps
``(state, candidates)`` to ``(state, outcome)`` without side effects; each
method is a :class:`PaperMethod` (the :class:`~radiopose.tracker.protocol.Method`
protocol) whose state is a :class:`TrackState`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from radiopose.clustering import (
    AxisCluster,
    cluster_axis_deg,
    cluster_positions_m,
    cluster_score,
    inverted_weights,
    weighted_orientation_deg,
)
from radiopose.likelihood import CandidateSpace, HeardRss, TopK
from radiopose.motion import PERIODIC_AXES
from radiopose.tracker.config import TrackerConfig
from radiopose.tracker.protocol import Device, Evidence, Outcome, Step, guard
from radiopose.tracker.reasons import (
    SKIP_ACQUIRING,
    SKIP_MOVEMENT_MODEL,
    SKIP_NO_CANDIDATES,
    SKIP_NO_ORIENTATION_CLUSTER,
    SKIP_NO_POSITION_CLUSTER,
    SKIP_ROTATION_MODEL,
)
from radiopose.units import FloatArray


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


@dataclass(frozen=True)
class _Grid:
    """A device's grid facts for bounded search."""

    half_diagonal_m: float
    """Half the candidate grid's cell diagonal, metres (the slack of the movement bound)."""
    n_azimuth: int


@dataclass(frozen=True)
class PaperMethod:
    """One of the paper's top-k methods (the :class:`~radiopose.tracker.protocol.Method`
    protocol; state :class:`TrackState`, replaced on every packet, never mutated).

    Attributes
    ----------
    name, label
        Registry name and one-line description.
    steps
        Steps 3–6 on one packet's top-k (:func:`step_full`, ...).
    bounds_position, bounds_orientation
        With ``TrackerConfig.search = "bounded"``: whether the previous valid
        position (orientation) restricts the grid searched (the quantity the
        method's motion model constrains).
    acquires
        Whether the acquisition window pools packets (all but ``top``).
    """

    name: str
    label: str
    steps: StepFunction
    bounds_position: bool
    bounds_orientation: bool
    acquires: bool = True
    evidence: frozenset[Evidence] = frozenset({Evidence.TOPK})
    estimates_orientation: bool = True
    lagged: bool = False
    state_type: type = field(default=TrackState)

    def prepare(self, device: Device) -> None:
        device.engine = _Grid(_grid_half_diagonal_m(device.space), _n_azimuth(device.space))

    def new_state(self, device: Device) -> TrackState:
        return TrackState()

    def step(
        self, device: Device, state: TrackState, heard: HeardRss, t_s: float, packet_id: str
    ) -> Step:
        skip = guard(state, heard, t_s, device.config.min_receivers)
        if skip is not None:
            return skip
        top = self.score(device, heard, t_s, state)
        cand = Candidates.from_topk(device.space, top)
        new, out = track_step(self, cand, t_s, state, device.config)
        return Step(new, out)

    def flush(self, device: Device, state: TrackState) -> tuple[()]:
        return ()

    def score(self, device: Device, heard: HeardRss, t_s: float, state: TrackState) -> TopK:
        """Top-k of one packet: the whole grid, or the motion-bounded window
        (``TrackerConfig.search``; needs a scorer that supports windows)."""
        cfg = device.config
        scorer = device.scorer
        assert scorer is not None
        if cfg.search != "bounded" or not scorer.supports_window:
            return scorer.score_heard(heard, cfg.k)
        space = device.space
        grid: _Grid = device.engine
        positions = None
        if self.bounds_position and state.position_m is not None:
            dt = t_s - float(state.position_time_s)  # type: ignore[arg-type]
            move = cfg.movement_model
            if dt <= move.max_gap_s:
                d = np.linalg.norm(space.positions_m - np.asarray(state.position_m), axis=1)
                positions = np.flatnonzero(d <= move.allowed_m(dt) + grid.half_diagonal_m)
        lo_deg, span_deg = 0.0, 360.0
        if self.bounds_orientation and state.orientation_deg is not None:
            dt = t_s - float(state.orientation_time_s)  # type: ignore[arg-type]
            rot = cfg.rotation_model
            if dt <= rot.gap_s:
                half = rot.allowed_deg(dt) + 0.5 * (360.0 / grid.n_azimuth)
                if half < 180.0:
                    lo_deg, span_deg = state.orientation_deg[0] - half, 2.0 * half
        if positions is None and span_deg >= 360.0:
            return scorer.score_heard(heard, cfg.k)
        if positions is None:
            positions = np.arange(space.n_positions)
        return scorer.score_window(heard, cfg.k, positions, lo_deg, span_deg)


def _grid_half_diagonal_m(space: CandidateSpace) -> float:
    xs = np.unique(space.positions_m[:, 0])
    ys = np.unique(space.positions_m[:, 1])
    dx = float(np.min(np.diff(xs))) if xs.size > 1 else 0.0
    dy = float(np.min(np.diff(ys))) if ys.size > 1 else 0.0
    return 0.5 * float(np.hypot(dx, dy))


def _n_azimuth(space: CandidateSpace) -> int:
    return int(np.unique(space.orientations_deg[:, 0]).size)


FULL = PaperMethod("full", "the paper's full pipeline (steps 1-6)", step_full, True, True)
LOCATION = PaperMethod(
    "location", "position clustering + movement model only", step_location, True, False
)
ORIENTATION = PaperMethod(
    "orientation", "orientation clustering + rotation model only", step_orientation, False, True
)
TOP = PaperMethod("top", "the best single candidate", step_top, False, False, acquires=False)
TOPK_METHODS: dict[str, PaperMethod] = {m.name: m for m in (FULL, LOCATION, ORIENTATION, TOP)}
"""The paper's methods that work on the top-k candidates (all but ``lms``)."""
PATTERN_STEPS: dict[str, StepFunction] = {name: m.steps for name, m in TOPK_METHODS.items()}
"""Their steps 3–6 by name."""


def _paper_method(method: str | PaperMethod) -> PaperMethod:
    return TOPK_METHODS[method] if isinstance(method, str) else method


def track_step(
    method: str | PaperMethod,
    cand: Candidates | None,
    t_s: float,
    state: TrackState,
    config: TrackerConfig,
) -> tuple[TrackState, Outcome]:
    """One pure pipeline step: ``(state, candidates) → (state, outcome)``."""
    m = _paper_method(method)
    if cand is None or len(cand) == 0:
        out = Outcome(reason=SKIP_NO_CANDIDATES)
    elif config.acquisition_window_s > 0 and m.acquires and acquiring(state, t_s, config):
        return _acquire(m, cand, t_s, state, config)
    else:
        out = m.steps(cand, t_s, state, config)
    return advance(state, t_s, out), out


def _acquire(
    method: PaperMethod, cand: Candidates, t_s: float, state: TrackState, config: TrackerConfig
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
    out = method.steps(Candidates.pooled(tuple(c for _, c in pool)), t_s, TrackState(), config)
    if out.ok:
        return advance(state, t_s, out), out  # a fresh state: nothing pending
    return replace(state, last_time_s=t_s, acquiring_since_s=since, pending=pool), out
