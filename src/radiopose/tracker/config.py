"""The tracker's parameters (:class:`TrackerConfig`): the paper's values by default."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

from radiopose.errors import InputError, check_setting_types
from radiopose.filtering import FilterConfig
from radiopose.filtering.config import MAX_LAG_S, lag_in_range
from radiopose.filtering.particle3d import Pose3dConfig
from radiopose.motion import MovementModel, RotationModel

MAX_K = 1000
"""Most candidates per packet (:attr:`TrackerConfig.k`; the paper's 100): the
acquisition window's DBSCAN holds every pooled candidate's neighbours, about
1.5 GB at k = 2000 on a 5° azimuth grid."""


@dataclass(frozen=True)
class TrackerConfig:
    """Every parameter of the pipeline; defaults are the paper's values, except
    ``acquisition_window_s``: the paper leaves open how a track starts.

    Attributes
    ----------
    k
        Candidates kept per packet (step 2), at most :data:`MAX_K`.
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
    pose3d
        What the ``filter`` adds at a 3-D site (a height range or several
        pitches or rolls; :class:`radiopose.filtering.particle3d.Pose3dConfig`,
        ``[filter.pose3d]`` of a site's ``tracker.toml``); unused elsewhere.
    smoothing_lag_s
        A lagged method (``filter``) in batch :func:`locate`: the fixed-lag
        smoother's lag, seconds (``None``: causal). The streaming
        :class:`Tracker` takes its lag as an argument (causal by default; the
        live server uses ``LiveConfig.live_lag_s``, at most 0.25 s).
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
    pose3d: Pose3dConfig = field(default_factory=Pose3dConfig)
    smoothing_lag_s: float | None = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_setting_types(self, "tracker")
        from radiopose.likelihood import SCORERS

        if self.kernel not in SCORERS:
            raise InputError(
                f"tracker setting kernel = {self.kernel!r} is not one of {', '.join(SCORERS)}"
            )
        checks = [
            ("k", 1 <= self.k <= MAX_K),
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
            ("seed", 0 <= self.seed < 2**63),
        ]
        lag = self.smoothing_lag_s
        if lag is not None and not lag_in_range(lag):
            raise InputError(
                f"tracker setting smoothing_lag_s = {lag!r} must be in [0, {MAX_LAG_S:g}] s "
                "(or None: causal)"
            )
        for name, ok in checks:
            if not ok:
                raise InputError(
                    f"tracker setting {name} = {getattr(self, name)!r} is out of range"
                    + (f" [1, {MAX_K}]" if name == "k" else "")
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


def filter_config(config: TrackerConfig) -> FilterConfig:
    """The ``filter``'s parameters with the motion prior's support from the
    tracker's limits: ``max_speed_mps`` and twice the rotation bound
    (``max_rotation_deg / rotation_period_s``, 360°/s by default) — a prior,
    not a veto: rotation beyond the paper's bound is followed."""
    rate_dps = config.max_rotation_deg / config.rotation_period_s
    return replace(config.filter, max_speed_mps=config.max_speed_mps, max_rate_dps=2.0 * rate_dps)
