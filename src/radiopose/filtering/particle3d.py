"""The particle filter in 3-D: position with height, azimuth, pitch and roll.

Beyond the paper (docs/pose3d.md). The state, likelihood, power-offset belief,
σ estimate, re-entry and smoother are the 2-D filter's
(:mod:`radiopose.filtering.particle`, reused by subclassing); what changes:

* **Height** is a state (``Z_M``), a random walk of density
  ``height_noise_mps`` reflected at the site's candidate height range; the
  expected RSS reads the survey map moved to the particle's height by the
  height model (:mod:`radiopose.survey_height`: path loss in 3-D distance).
* **Pitch and roll** are random walks of ``tilt_noise_dps`` within the support
  of the site's candidate lists (padded by half their spacing). Roll is
  periodic: its support is an arc (the shortest covering the listed rolls),
  reflected at its ends, or the whole circle (wrapped) when the rolls cover
  it. Pitch is reflected at its support's ends; where the support reaches
  ±90° a step over the pole is the same rotation written the other way,
  ``(az, p, r) → (az + 180°, ±180° − p, r + 180°)`` (gimbal).
* **Acquisition** (a new track, and each re-entry) scores a **coarse grid**
  (``acquisition_step_m`` positions × up to ``acquisition_heights`` heights ×
  ``acquisition_azimuth_step_deg`` azimuths × the site's pitches × its rolls)
  against the window's median RSS: the expected RSS of every coarse pose is a
  table built once (:class:`CoarseGrid`), so a scoring is one pass over it
  with each pose's offset profiled out in closed form (compiled,
  :func:`coarse_costs`). Particles are drawn from the best ``acquisition_k``
  poses, spread over their cells, then **refined locally** by
  ``refine_steps`` rounds of tempered importance resampling on the same
  window (σ from ``acquisition_sigma_db`` down to the filter's) with a
  shrinking jitter. The per-packet cost is then that of the 2-D filter (the
  expected RSS per particle and receiver, plus the height correction).

* **Device-level power offset** (the offset bank, on by default): one
  member filter per offset hypothesis (``offset_bank_db``, each with a tight
  offset prior and its share of the particles); the members never exchange
  particles, and the estimate is that of the member with the largest
  marginal likelihood over the track (:class:`FilterState3d`).

Estimates: weighted mean position (height included), circular mean azimuth
and roll and mean pitch (the 2-D filter's summary, valid away from pitch
±90°, which hand-held motion does not reach), or the posterior's main mode
(``estimate = "mode"``). An optional hand-held heading prior couples azimuth
and walking direction (``heading_prior_deg``; off by default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import MIN_REENTRY_INTERVAL_S
from radiopose.filtering.kernels3d import (
    coarse_costs,
    expected3d_into,
    heading_prior,
    mode_pose,
    packet_update3d,
    tilt_height_step,
)
from radiopose.filtering.particle import (
    FilterConfig,
    FilterEstimate,
    FilterModel,
    FilterState,
    ParticleFilter,
)
from radiopose.geometry import orientation_matrices, pattern_angles_deg
from radiopose.likelihood import CandidateSpace, HeardRss, profile_offset_db
from radiopose.likelihood.compiled import spare_core_threads
from radiopose.patterns.pattern import Pattern
from radiopose.site import Site
from radiopose.survey_height import HeightModel, build_height_model, no_receiver_gain
from radiopose.units import FloatArray

if TYPE_CHECKING:
    from radiopose.filtering.refine3d import PoseBand

ESTIMATES = ("mode", "mean")
"""The values of :attr:`Pose3dConfig.estimate`."""
MAX_RESTARTS = 100
"""Most offline mid-track restarts (``Pose3dConfig.refine_restarts``)."""
MAX_PARTICLES = 1_000_000
"""Most particles per device (``Pose3dConfig.offline_n_particles``)."""
MAX_COARSE_PATHS = 8
"""Most coarse-HMM paths as refinement starts (``Pose3dConfig.refine_coarse_paths``)."""


@dataclass(frozen=True)
class Pose3dConfig:
    """What the 3-D filter adds to :class:`~radiopose.filtering.FilterConfig`.

    Attributes
    ----------
    n_particles
        Particles per device (replaces the 2-D default).
    angular_accel_noise_dps2
        White angular-acceleration density of the azimuth, °/s² per √Hz, for
        the 3-D filter and its batch refinement (replaces the 2-D filter's,
        which is 270 since 2026-11-27; the 3-D filter was measured with 90 and
        keeps it: docs/filter.md, "Angular noise").
    height_noise_mps
        Random-walk density of height, m/√s.
    tilt_noise_dps
        Random-walk density of pitch and roll, °/√s.
    acquisition_step_m, acquisition_azimuth_step_deg
        Coarse grid steps of position and azimuth.
    acquisition_heights
        Most coarse heights (taken evenly from the site's candidate heights).
    acquisition_sigma_db
        σ of the coarse scoring (covers the grid's coarseness), dB.
    acquisition_k
        Coarse poses from which particles are drawn.
    acquisition_tilts
        Most coarse pitches and most coarse rolls (taken evenly from the
        site's lists).
    reentry_interval_s
        How often coarse hypotheses re-enter (replaces the 2-D default: a
        coarse scoring costs more than the 2-D kernel's).
    proposal_window_s
        The re-entry's evidence window (replaces the 2-D default): one packet
        of six receivers leaves a one-parameter family of poses that fit it
        (six readings, six pose angles and coordinates plus the offset), so
        hypotheses are compared over a longer stretch of motion.
    sigma_floor_db
        Lower bound of the σ estimate (replaces the 2-D default): the 3-D
        expected RSS carries the bilinear map's error, up to ~0.5 dB near a
        receiver, and a σ below it starves the particles.
    refine_steps
        Rounds of tempered resampling after drawing.
    max_table_entries
        Bound on the coarse table (poses × receivers); the position step is
        widened until it fits.
    estimate
        ``"mean"`` (default): the 2-D filter's per-axis summary (weighted mean
        position, circular mean azimuth and roll, mean pitch), which lands
        between the modes of a bimodal cloud; ``"mode"``: each estimate
        (causal and smoothed) is the posterior's main mode — the heaviest
        cluster of particles (within ``mode_radius_m`` and a rotation angle
        ``mode_radius_deg``), its mean position and the chordal L2 mean of its
        rotations (:func:`~radiopose.filtering.kernels3d.mode_pose`). On the
        tuning seeds the two agree to 0.2° (the clouds the filter keeps are
        unimodal: a wrong estimate is a wrong cloud), and the mode costs 16 %
        of the causal filter's rate, so the mean stays the default
        (docs/pose3d.md, "Accuracy").
    mode_radius_m, mode_radius_deg
        Extent of a cluster for ``estimate = "mode"``: position, metres, and
        rotation angle, degrees.
    mode_centres
        Candidate cluster centres drawn by weight.
    heading_prior_deg
        Optional hand-held motion prior (``0``: off): the phone's azimuth
        follows its walking direction (the top ahead, as a phone held in front
        while walking) within a von Mises spread of this many degrees, its
        weight growing with speed (:func:`~radiopose.filtering.kernels3d.heading_prior`).
        A modelling assumption about hand-held use, not about radio: wrong
        for a phone carried sideways, pocketed or looked at while walking
        backwards.
    heading_prior_time_s
        Correlation time of the heading's deviation from the walking
        direction, s: each packet applies ``dt / τ`` of the prior, so it
        counts once per ``τ`` of data, not once per packet.
    heading_prior_speed_mps
        Speed at which the coupling reaches half its strength, m/s.
    offset_bank_db
        Optional device-level power offset (empty: off): one member filter per
        listed offset (dB from the offset prior's centre), each with
        ``n_particles / len(offset_bank_db)`` particles and a tight offset
        prior (``offset_bank_sd_db``) around its offset; the estimate is the
        member with the largest marginal likelihood over the track so far
        (its summed per-packet evidence, plus the device prior's
        ``log N(b; 0, offset_prior_sd_db²)``). Members never exchange
        particles, so each keeps searching its own poses.
    offset_bank_sd_db
        Offset prior σ within a member, dB.
    refine
        Offline only (batch ``locate`` with a smoothing lag; never the causal
        or live filter): after the last packet, refine each track of the
        smoothed estimates by batch MAP (:mod:`radiopose.filtering.refine3d`:
        the same likelihood and the filter's motion model as a prior,
        initialised at the smoothed track and the chosen member's offset).
    refine_max_nfev
        Bound on the refinement's residual evaluations per track.
    refine_from_members
        With the offset bank: also refine from each member's own smoothed
        track (and offset) and keep, per track, the refined track of the
        lowest MAP objective (the same objective for all: only the likelihood
        and the priors choose; with a constant-rate prior, see
        ``refine_polish_switch``).
    refine_height_accel_noise_mps2, refine_tilt_accel_noise_dps2
        The refinement's own motion prior for height and for pitch and roll
        (0: the filter's random walks, ``height_noise_mps`` and
        ``tilt_noise_dps``): when > 0, a nearly-constant-rate model with white
        acceleration of this density, m/s²·√s and °/s²·√s (a hand moves a
        phone smoothly; docs/pose3d.md, "Refinement prior, 2026-11-26"). The
        causal filter never reads them. Default 1 m/s²·√s and 400 °/s²·√s
        (chosen on tuning seeds 7100–7119, confirmed on 7120–7139 and at 4
        and 8 receivers on 7100–7109).
    refine_polish_starts
        With a constant-rate refinement prior: how many of the refined tracks
        (lowest objective first, found with the random walks) are polished
        with it; the lowest polished objective is kept. 0: every start is
        refined with the constant-rate prior directly. Only distinct modes
        are polished (a refined track within 0.1 m and 2° of a lower one is
        skipped: :func:`radiopose.filtering.refine3d.same_track`).
    refine_polish_margin
        Polish only refined tracks whose random-walk objective is within this
        of the lowest (σ² units, the objective's; ``refine_polish_starts``
        caps their number): the wrong mode often has the lower random-walk
        objective and the right one a lower constant-rate objective
        (docs/pose3d.md, "Mode choice, 2026-11-27").
    refine_polish_switch
        The polish of the lowest random-walk track is kept unless another
        polished mode's constant-rate objective is lower by more than this
        (σ² units: a log-likelihood ratio, nats; 0: the lowest polished
        objective wins). Default since 2026-11-27: up to 3 modes within 10,
        switch 5 (chosen on tuning seeds 7100–7119, held on 7120–7139; before:
        1, any margin, 0); since 2026-11-28 (session 19) up to 5 modes within
        50, switch 5 (docs/pose3d.md, "A wider polish margin": tuning
        9186–9215 5.31° → 4.83°, held-out 1390–1419 6.32° → 6.24°, one run
        changed in each).
    refine_reverse_pass
        Offline only (with ``refine``): also run the filter over the
        time-reversed packets (a fresh state, its own seed;
        :func:`radiopose.filtering.reverse.reversed_tracks3d`) and refine its
        smoothed track as one more start (docs/pose3d.md, "Reversed pass,
        2026-11-27"): a wrong mode over the start or end of the forward track
        is entered from the other side. The causal filter and the live server
        never run it. Default since 2026-11-27 (on after held-out seeds
        1150–1179: 12.9° → 9.7°; confirmed on fresh seeds, docs/pose3d.md).
    refine_reverse_members
        With ``refine_reverse_pass`` and the offset bank: also refine from
        each of the reversed pass's bank members' own smoothed tracks.
    refine_restarts
        Offline only (with ``refine``): restart the filter this many times
        inside the track (0: off). A restart at a point runs a fresh filter
        forward from it to the end and one over the time-reversed packets
        from it back to the start, each acquiring afresh there; their smoothed
        tracks, spliced at the point, are one more refinement start
        (:func:`radiopose.filtering.restart3d.midtrack_tracks3d`;
        docs/pose3d.md, "Mid-track restarts, 2026-11-27"). The points are at
        ``1/(n+1), …, n/(n+1)`` of the file's time span.
    refine_restart_members
        With ``refine_restarts`` and the offset bank: also refine from each
        bank member's spliced track (member ``k`` of the reversed half with
        member ``k`` of the forward half). Off: on tuning seed 7124 these
        starts led the mode choice to a 155° mode (docs/pose3d.md).
    offline_n_particles
        Offline only (batch ``locate`` with a smoothing lag): particles per
        device of every offline pass — the forward pass, the reversed pass and
        the mid-track restarts (0: ``n_particles``). Offline has no streaming
        speed goal, so its passes can afford more particles; the causal
        filter, the streaming ``Tracker`` and the live server never read it
        (docs/pose3d.md, "Offline particles, 2026-11-27").
    refine_anneal_sigma
        Offline refinement (session 12; default empty: off): factors > 1,
        largest first; each start of the refinement's search is first refined
        with σ times each factor in turn, each from the last one's optimum,
        then at σ (a graduated continuation: a larger σ weighs the data less
        against the motion prior; docs/pose3d.md, "Annealed refinement").
    refine_anneal_keep_direct
        With ``refine_anneal_sigma``: also refine each start at σ directly and
        keep the lower objective of the two (default off).
    refine_coarse_path
        Offline refinement: also refine from the most likely path of a
        whole-file coarse HMM over (x, y, azimuth) on the acquisition grid,
        height, pitch and roll minimised per cell, at the offset of the HMM's
        largest evidence (:func:`radiopose.filtering.coarse3d.coarse_paths3d`;
        docs/pose3d.md, "A coarse-path start, 2026-11-28"): a start that no
        particle filter's acquisition decides. Default since 2026-11-28 (61
        tuning seeds 9.30° → 8.41°; held-out 1240–1269 8.04° → 7.61°).
    refine_coarse_walk_m, refine_coarse_walk_deg
        The coarse HMM's random walk per 0.1 s window: position (m) and
        azimuth (°) standard deviations.
    refine_coarse_paths
        With ``refine_coarse_path``: the paths at up to this many local maxima
        of the coarse HMM's evidence over the device offset, the largest
        first (1: the best offset's path only).
    refine_heading_deg
        Offline, with ``refine`` (0: off; default 30 since 2026-11-28): the refinement's mode
        choice adds the hand-held heading prior's cost of each refined track
        (:func:`radiopose.filtering.refine3d.heading_cost`: the azimuth
        within a von Mises spread of this many degrees of the walking
        direction, with ``heading_prior_time_s`` and
        ``heading_prior_speed_mps``) to its objective, both where the modes to
        polish are picked and where the polished one is chosen. The tracks
        themselves are refined without it. The same modelling assumption as
        ``heading_prior_deg`` — a phone held in front while walking; set 0
        for one carried sideways or pocketed (docs/pose3d.md, "Heading in
        the mode choice, 2026-11-28": tuning 8.41° → 6.36°, held-out
        7.84° → 7.79°).
    refine_escalate_ratio, refine_escalate_restarts
        Offline, with ``refine`` and without ``refine_restarts`` (0: off;
        default 1.3 since 2026-11-28): when the refined file's
        :func:`radiopose.filtering.refine3d.segment_misfit_ratio` (0.5 s
        segments) is above this ratio, ``refine_escalate_restarts`` mid-track
        restarts (:mod:`radiopose.filtering.restart3d`) are run and the file is
        refined again with them as more starts (docs/pose3d.md, "Session 17").
    refine_orientation_path
        Offline, with ``refine``: after the mode choice, a Viterbi search over a
        fine orientation grid along the kept track's positions
        (:mod:`radiopose.filtering.orientation_path`) gives one more start,
        refined and polished; it replaces the kept track when its objective is
        lower by more than ``refine_polish_switch`` (docs/pose3d.md, "An
        orientation path, 2026-11-28").
    hand_height_m, hand_pitch_deg
        A hand-held band prior (empty: off;
        :class:`radiopose.filtering.refine3d.PoseBand`): flat for a height
        inside ``[low, high]`` metres and a pitch inside ``[low, high]``
        degrees, ``½ (dt/τ) (d/sd)²`` nats per packet outside (``τ =
        heading_prior_time_s``, ``d`` the distance to the band). It enters
        every offline refinement solve (with ``refine``) and, with
        ``hand_band_filter``, the particle filter's weights at each packet
        (every pass: causal, live and offline). A modelling assumption about a
        phone held in the hand, not about radio: wrong for a phone on a table
        or in a pocket (docs/pose3d.md, "A hand-held band, 2026-11-28").
    hand_height_sd_m, hand_pitch_sd_deg
        The band prior's spread outside the band: metres and degrees.
    hand_band_filter
        Whether the particle filter weighs the band too (the refinement always
        does when a band is set).
    survey_detrend
        The height model's maps interpolate the survey with its fitted path
        loss removed and add the path loss back at each pose's exact 3-D
        distance (:func:`radiopose.survey_height.build_height_model`; the
        default since 2026-11-28); off: the survey's own map, moved along 3-D
        distance (docs/pose3d.md, "Detrended survey maps").
    survey_receiver_gain
        The height model removes each receiver's own directivity (its pattern
        and orientation from ``receivers.csv``) from the survey before
        interpolating and adds it back toward each pose's exact position
        (:class:`radiopose.survey_height.ReceiverGain`; docs/pose3d.md, "The
        receiver's gain in the height model").
    """

    n_particles: int = 2000
    angular_accel_noise_dps2: float = 90.0
    height_noise_mps: float = 0.2
    tilt_noise_dps: float = 20.0
    acquisition_step_m: float = 1.0
    acquisition_azimuth_step_deg: float = 15.0
    acquisition_heights: int = 4
    acquisition_sigma_db: float = 3.0
    acquisition_k: int = 2000
    acquisition_tilts: int = 4
    reentry_interval_s: float = 0.5
    proposal_window_s: float = 0.5
    sigma_floor_db: float = 0.5
    refine_steps: int = 6
    max_table_entries: int = 20_000_000
    estimate: str = "mean"
    mode_radius_m: float = 1.0
    mode_radius_deg: float = 30.0
    mode_centres: int = 32
    heading_prior_deg: float = 0.0
    heading_prior_time_s: float = 1.0
    heading_prior_speed_mps: float = 0.3
    offset_bank_db: tuple[float, ...] = (-6.0, -3.0, 0.0, 3.0, 6.0)
    offset_bank_sd_db: float = 1.5
    refine: bool = True
    refine_max_nfev: int = 100
    refine_from_members: bool = True
    refine_hybrid_segment_s: float = 0.5
    refine_height_accel_noise_mps2: float = 1.0
    refine_tilt_accel_noise_dps2: float = 400.0
    refine_polish_starts: int = 5
    refine_polish_margin: float = 50.0
    refine_polish_switch: float = 5.0
    refine_reverse_pass: bool = True
    refine_reverse_members: bool = False
    refine_restarts: int = 0
    refine_restart_members: bool = False
    offline_n_particles: int = 0
    refine_anneal_sigma: tuple[float, ...] = ()
    refine_anneal_keep_direct: bool = False
    refine_coarse_path: bool = True
    refine_coarse_walk_m: float = 0.35
    refine_coarse_walk_deg: float = 9.0
    refine_coarse_paths: int = 1
    refine_heading_deg: float = 30.0
    refine_escalate_ratio: float = 1.3
    refine_escalate_restarts: int = 2
    refine_orientation_path: bool = True
    hand_height_m: tuple[float, ...] = ()
    hand_height_sd_m: float = 0.1
    hand_pitch_deg: tuple[float, ...] = ()
    hand_pitch_sd_deg: float = 10.0
    hand_band_filter: bool = False
    survey_detrend: bool = True
    survey_receiver_gain: bool = False

    def hand_band(self) -> PoseBand | None:
        """The hand-held band prior of the refinement and, with
        ``hand_band_filter``, of the filter's weights (``None``: both bands off)."""
        from radiopose.filtering.refine3d import PoseBand

        h, pt = self.hand_height_m, self.hand_pitch_deg
        if not h and not pt:
            return None
        return PoseBand(
            height_m=(float(h[0]), float(h[1])) if h else None,
            height_sd_m=self.hand_height_sd_m,
            pitch_deg=(float(pt[0]), float(pt[1])) if pt else None,
            pitch_sd_deg=self.hand_pitch_sd_deg,
            time_s=self.heading_prior_time_s,
        )

    def offline(self) -> Pose3dConfig:
        """These settings for an offline pass (batch ``locate`` with a smoothing
        lag): ``n_particles`` replaced by ``offline_n_particles`` when that is set."""
        if self.offline_n_particles == 0:
            return self
        return replace(self, n_particles=self.offline_n_particles)

    def __post_init__(self) -> None:
        check_setting_types(self, "3-D filter")
        if self.reentry_interval_s < MIN_REENTRY_INTERVAL_S:
            raise InputError(
                f"3-D filter setting reentry_interval_s = {self.reentry_interval_s!r} must be "
                f"at least {MIN_REENTRY_INTERVAL_S:g} s"
            )
        for name in (
            "angular_accel_noise_dps2", "height_noise_mps", "tilt_noise_dps", "acquisition_step_m",
            "acquisition_azimuth_step_deg", "acquisition_sigma_db", "mode_radius_m",
            "heading_prior_time_s", "heading_prior_speed_mps", "offset_bank_sd_db",
            "refine_coarse_walk_m", "refine_coarse_walk_deg", "hand_height_sd_m",
            "hand_pitch_sd_deg", "proposal_window_s", "sigma_floor_db",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"3-D filter setting {name} = {v!r} must be a positive number")
        if min(
            self.n_particles - 9, self.acquisition_heights, self.acquisition_k,
            self.acquisition_tilts, self.mode_centres,
        ) < 1:  # fmt: skip
            raise InputError(
                "3-D filter settings: n_particles >= 10; acquisition_heights, acquisition_k, "
                "acquisition_tilts and mode_centres >= 1"
            )
        if self.offline_n_particles != 0 and not (10 <= self.offline_n_particles <= MAX_PARTICLES):
            n = self.offline_n_particles
            raise InputError(
                f"3-D filter setting offline_n_particles = {n!r} must be 0 (off) "
                f"or in [10, {MAX_PARTICLES}]"
            )
        if self.refine_max_nfev < 1:
            raise InputError("3-D filter setting refine_max_nfev must be >= 1")
        if not (0 <= self.refine_hybrid_segment_s < math.inf):
            raise InputError(
                "3-D filter setting refine_hybrid_segment_s = "
                f"{self.refine_hybrid_segment_s!r} must be >= 0"
            )
        for name in ("refine_height_accel_noise_mps2", "refine_tilt_accel_noise_dps2"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"3-D filter setting {name} = {v!r} must be >= 0 (0: off)")
        for name in ("refine_polish_margin", "refine_polish_switch"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"3-D filter setting {name} = {v!r} must be >= 0")
        if not (0 <= self.refine_restarts <= MAX_RESTARTS):
            n = self.refine_restarts
            raise InputError(
                f"3-D filter setting refine_restarts = {n!r} must be in [0, {MAX_RESTARTS}]"
            )
        if not all(
            isinstance(f, int | float) and math.isfinite(f) and 1 < f <= 100
            for f in self.refine_anneal_sigma
        ) or list(self.refine_anneal_sigma) != sorted(self.refine_anneal_sigma, reverse=True):
            raise InputError(
                f"3-D filter setting refine_anneal_sigma = {list(self.refine_anneal_sigma)!r} "
                "must be factors in (1, 100], largest first"
            )
        if not (1 <= self.refine_coarse_paths <= MAX_COARSE_PATHS):
            n = self.refine_coarse_paths
            raise InputError(
                f"3-D filter setting refine_coarse_paths = {n!r} must be in [1, {MAX_COARSE_PATHS}]"
            )
        if self.refine_polish_starts < 0:
            n = self.refine_polish_starts
            raise InputError(f"3-D filter setting refine_polish_starts = {n!r} must be >= 0")
        if self.refine_steps < 0 or self.max_table_entries < 1000:
            raise InputError("3-D filter settings: refine_steps >= 0, max_table_entries >= 1000")
        if self.estimate not in ESTIMATES:
            raise InputError(
                f"3-D filter setting estimate = {self.estimate!r} is not one of {ESTIMATES}"
            )
        if not (0 <= self.refine_heading_deg <= 180.0):
            raise InputError(
                f"3-D filter setting refine_heading_deg = {self.refine_heading_deg!r} "
                "must be in [0, 180]"
            )
        if not (0 <= self.refine_escalate_ratio < math.inf) or not (
            1 <= self.refine_escalate_restarts <= 100
        ):
            raise InputError(
                f"3-D filter settings refine_escalate_ratio = {self.refine_escalate_ratio!r} "
                f"must be >= 0 and refine_escalate_restarts = {self.refine_escalate_restarts!r} "
                "in [1, 100]"
            )
        if not (0 <= self.heading_prior_deg < math.inf):
            raise InputError(
                f"3-D filter setting heading_prior_deg = {self.heading_prior_deg!r} must be >= 0"
            )
        if not all(math.isfinite(b) for b in self.offset_bank_db) or (
            self.offset_bank_db
            and min(self.n_particles, self.offline_n_particles or self.n_particles)
            // len(self.offset_bank_db)
            < 10
        ):
            raise InputError(
                f"3-D filter setting offset_bank_db = {self.offset_bank_db!r}: finite offsets, "
                "at least 10 particles each"
            )
        for name, lo, hi in (
            ("hand_height_m", -1e6, 1e6),
            ("hand_pitch_deg", -90.0, 90.0),
        ):
            b = getattr(self, name)
            if b and not (
                len(b) == 2
                and all(isinstance(v, int | float) and lo <= v <= hi for v in b)
                and b[0] <= b[1]
            ):
                raise InputError(
                    f"3-D filter setting {name} = {list(b)!r} must be empty (off) or "
                    f"[low, high] with {lo:g} <= low <= high <= {hi:g}"
                )
        if not (0 < self.mode_radius_deg <= 180 and self.mode_centres >= 1):
            raise InputError("3-D filter settings: mode_radius_deg in (0, 180], mode_centres >= 1")


# ----------------------------------------------------------------------------- model
def _support(values_deg: tuple[float, ...], lo: float, hi: float) -> tuple[float, float]:
    """``[min − pad, max + pad]`` of listed angles clipped to ``[lo, hi]`` degrees,
    ``pad`` half the smallest spacing (0 for one value)."""
    v = np.sort(np.asarray(values_deg, float))
    pad = 0.5 * float(np.min(np.diff(v))) if v.size > 1 else 0.0
    return max(float(v[0]) - pad, lo), min(float(v[-1]) + pad, hi)


def roll_support_deg(roll_deg: tuple[float, ...]) -> tuple[float, float]:
    """``(centre, half_width)`` degrees of the shortest arc covering the listed
    rolls, padded by half their smallest circular spacing; half width 180 (the
    whole circle) when the padded arc reaches it, 0 for one roll."""
    r = np.sort(np.asarray(roll_deg, float) % 360.0)
    if r.size == 1:
        return float(r[0]), 0.0
    gaps = np.diff(np.concatenate([r, [r[0] + 360.0]]))  # gap after each roll
    pad = 0.5 * float(gaps.min())
    j = int(np.argmax(gaps))  # the arc is the circle less the largest gap
    arc = 360.0 - float(gaps[j]) + 2 * pad
    start = float(r[(j + 1) % r.size]) - pad
    if arc >= 360.0 - 1e-9:
        return 0.0, 180.0
    return (start + 0.5 * arc + 180.0) % 360.0 - 180.0, 0.5 * arc


def _evenly(values: FloatArray, n: int) -> FloatArray:
    """At most ``n`` of ``values`` taken evenly (first and last kept)."""
    v = np.asarray(values, float)
    if v.size <= n:
        return v
    return v[np.unique(np.round(np.linspace(0, v.size - 1, n)).astype(int))]


@dataclass(frozen=True, eq=False)
class CoarseGrid:
    """The acquisition grid: coarse poses and their expected RSS (built once).

    Attributes
    ----------
    positions_m
        ``(n_p, 3)`` coarse positions, metres.
    orientations_deg
        ``(n_o, 3)`` coarse orientations (azimuth, pitch, roll), degrees.
    table_dbm
        ``(n_o · n_p, n_rx)`` float32 expected RSS without offset; row
        ``o · n_p + p``.
    cell
        Half-widths of a cell: ``[x, y, z (m), azimuth, pitch, roll (deg)]``.
    """

    positions_m: FloatArray
    orientations_deg: FloatArray
    table_dbm: np.ndarray
    cell: FloatArray

    @classmethod
    def build(
        cls, site: Site, height: HeightModel, tx_power_dbm: float, pattern: Pattern,
        cfg: Pose3dConfig,
    ) -> CoarseGrid:  # fmt: skip
        """The grid of a site's device (its pattern and power) under ``cfg``."""
        a = site.area
        n_rx = len(site.receivers)
        z_all = a.z_levels_m()
        nz = min(cfg.acquisition_heights, z_all.size)
        z = _evenly(z_all, nz)
        n_az = max(1, round(360.0 / cfg.acquisition_azimuth_step_deg))
        az = np.arange(n_az) * (360.0 / n_az)
        o = site.orientations
        pitches = _evenly(np.sort(np.asarray(o.pitch_deg, float)), cfg.acquisition_tilts)
        rolls = _evenly(np.asarray(o.roll_deg, float), cfg.acquisition_tilts)
        p, r, zz = np.meshgrid(pitches, rolls, az, indexing="ij")
        orient = np.column_stack([zz.ravel(), p.ravel(), r.ravel()])
        step = cfg.acquisition_step_m
        while True:
            xs = np.arange(a.x_min_m, a.x_max_m + 1e-9, step)
            ys = np.arange(a.y_min_m, a.y_max_m + 1e-9, step)
            if xs.size * ys.size * z.size * orient.shape[0] * n_rx <= cfg.max_table_entries:
                break
            if xs.size == 1 and ys.size == 1:  # one position and still too large
                raise InputError(
                    f"3-D filter setting max_table_entries = {cfg.max_table_entries} is too "
                    f"small for this site: one position's heights, orientations and receivers "
                    f"alone are {z.size * orient.shape[0] * n_rx} entries"
                )
            step *= 1.25
        gx, gy, gz = np.meshgrid(xs, ys, z, indexing="ij")
        pos = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
        chan = height.channel_db(pos) + tx_power_dbm  # (n_p, n_rx)
        rot = orientation_matrices(orient[:, 0], orient[:, 1], orient[:, 2])
        rx = site.receiver_positions_m()
        table = np.empty((orient.shape[0], pos.shape[0], n_rx), np.float32)
        chunk = max(1, 2_000_000 // max(pos.shape[0] * n_rx, 1))
        for s in range(0, orient.shape[0], chunk):
            phi, theta = pattern_angles_deg(pos, rot[s : s + chunk], rx)  # (n_p, m, k)
            table[s : s + chunk] = (pattern.lookup_dbi(phi, theta) + chan[:, None, :]).transpose(
                1, 0, 2
            )
        spacing = [
            float(np.min(np.diff(np.sort(v)))) if len(v) > 1 else 0.0 for v in (z, pitches, rolls)
        ]
        cell = np.array(
            [0.5 * step, 0.5 * step, 0.5 * spacing[0], 0.5 * 360.0 / n_az, 0.5 * spacing[1],
             0.5 * spacing[2]]
        )  # fmt: skip
        return cls(pos, orient, table.reshape(-1, n_rx), cell)


@dataclass(frozen=True, eq=False)
class FilterModel3d(FilterModel):
    """:class:`FilterModel` with height: the height model's maps, the coarse grid
    and the tilt and height supports. ``channel_db``/``grid`` are the 2-D map
    (unused by the 3-D kernels); ``maps_db`` ``(L, n_rx, nx, ny)`` at
    ``layers_z_m``, with the survey's path loss removed when ``detrended``
    and the receivers' directivity when ``receiver_gain`` has rows
    (:class:`radiopose.survey_height.HeightModel`, :meth:`ReceiverGain.kernel_arrays
    <radiopose.survey_height.ReceiverGain.kernel_arrays>`)."""

    maps_db: FloatArray = field(default_factory=lambda: np.zeros((1, 1, 1, 1)))
    layers_z_m: FloatArray = field(default_factory=lambda: np.zeros(1))
    exponent: float = 2.0
    detrended: bool = False
    receiver_gain: tuple[FloatArray, FloatArray, FloatArray] = field(
        default_factory=no_receiver_gain
    )
    coarse: CoarseGrid | None = None
    tilt_rad: FloatArray = field(default_factory=lambda: np.zeros(4))
    z_box_m: FloatArray = field(default_factory=lambda: np.zeros(2))

    @classmethod
    def build3d(cls, site: Site, space: CandidateSpace, cfg: Pose3dConfig) -> FilterModel3d:
        """The device's arrays (``space`` names the device: pattern, power, receivers)."""
        base = FilterModel.build(site, space, _NoScorer())  # type: ignore[arg-type]
        height = build_height_model(
            site, detrend=cfg.survey_detrend, receiver_gain=cfg.survey_receiver_gain
        )
        coarse = CoarseGrid.build(site, height, float(space.tx_power_dbm), space.pattern, cfg)
        o = site.orientations
        p_lo, p_hi = _support(o.pitch_deg, -90.0, 90.0)
        r_c, r_w = roll_support_deg(o.roll_deg)
        z = site.area.z_levels_m()
        parts = {f: getattr(base, f) for f in base.__dataclass_fields__}
        return cls(
            **parts,
            maps_db=np.ascontiguousarray(height.maps_db, dtype=np.float64),
            layers_z_m=np.ascontiguousarray(height.layers_z_m, dtype=np.float64),
            exponent=float(height.exponent),
            detrended=bool(height.detrended),
            receiver_gain=(
                no_receiver_gain()
                if height.receiver_gain is None
                else height.receiver_gain.kernel_arrays()
            ),
            coarse=coarse,
            tilt_rad=np.deg2rad([p_lo, p_hi, r_c, r_w]),
            z_box_m=np.array([z.min(), z.max()], float),
        )

    def expected(self, S: FloatArray, heard_index: np.ndarray) -> FloatArray:
        """Expected RSS ``(n, h)`` dBm without the offset (height model, full sphere)."""
        heard = np.ascontiguousarray(heard_index, dtype=np.int64)
        out = np.empty((S.shape[0], heard.size))
        with spare_core_threads():
            expected3d_into(np.ascontiguousarray(S), heard, *self.arrays3d(), out)
        return out

    def arrays3d(self) -> tuple[Any, ...]:
        """``(rx, maps, layers_z, exponent, detrended, rg_rot, rg_d, rg_ax, grid,
        tx_dbm, d, pat)`` of the kernels."""
        return (
            self.receivers_m, self.maps_db, self.layers_z_m, self.exponent, self.detrended,
            *self.receiver_gain, self.grid,
            self.tx_power_dbm, self.pattern_dbi, self.pattern_axes,
        )  # fmt: skip


class _NoScorer:
    """The 3-D filter scores its own coarse grid, never the site's scorer."""


@dataclass(eq=False)
class FilterState3d(FilterState):
    """:class:`FilterState` with the offset bank (:attr:`Pose3dConfig.offset_bank_db`):
    ``bank`` the members' states, ``bank_log_evidence`` their summed evidence;
    ``last_log_evidence`` the log evidence of this state's last packet."""

    bank: list[FilterState3d] = field(default_factory=list)
    bank_log_evidence: FloatArray = field(default_factory=lambda: np.zeros(0))
    last_log_evidence: float = 0.0
    # offline batch refinement (Pose3dConfig.refine_from_members): every member's
    # own smoothed estimates, ``None`` unless the offline tracker records them
    bank_smoothed: list[list[tuple[object, FilterEstimate]]] | None = None


def _band_prior(S: FloatArray, logw: FloatArray, band: PoseBand, dt_s: float) -> None:
    """Add the hand-held band prior's ``−½ (dt/τ) (d/sd)²`` to ``logw`` in place."""
    logw -= 0.5 * dt_s / band.time_s * band.excess_sq(S[:, K.Z_M], S[:, K.PITCH_RAD])


class ParticleFilter3d(ParticleFilter):
    """The 3-D filter for one device (see the module docstring).

    Parameters
    ----------
    model
        :meth:`FilterModel3d.build3d`.
    config
        The 2-D filter's parameters (motion, likelihood, σ, re-entry, smoother).
    lag_s
        As :class:`ParticleFilter`.
    pose3d
        What 3-D adds (:class:`Pose3dConfig`); its ``n_particles`` replaces
        ``config``'s.
    """

    def __init__(
        self,
        model: FilterModel3d,
        config: FilterConfig,
        lag_s: float | None = None,
        pose3d: Pose3dConfig | None = None,
    ):
        self.pose3d = pose3d or Pose3dConfig()
        cfg = replace(
            config,
            n_particles=self.pose3d.n_particles,
            angular_accel_noise_dps2=self.pose3d.angular_accel_noise_dps2,
            reentry_interval_s=self.pose3d.reentry_interval_s,
            proposal_window_s=self.pose3d.proposal_window_s,
            sigma_floor_db=self.pose3d.sigma_floor_db,
        )
        super().__init__(model, cfg, lag_s)
        self.model3d = model
        self._motion = np.array(
            [
                cfg.accel_noise_mps2,
                math.radians(cfg.angular_accel_noise_dps2),
                math.radians(self.pose3d.tilt_noise_dps),
                cfg.max_speed_mps,
                math.radians(cfg.max_rate_dps),
                self.pose3d.height_noise_mps,
            ]
        )
        self._band = self.pose3d.hand_band() if self.pose3d.hand_band_filter else None
        bank = self.pose3d.offset_bank_db
        member = replace(
            self.pose3d, offset_bank_db=(), n_particles=self.pose3d.n_particles // max(len(bank), 1)
        )
        member_cfg = replace(config, offset_prior_sd_db=self.pose3d.offset_bank_sd_db)
        self._members = [ParticleFilter3d(model, member_cfg, lag_s, member) for _ in bank]

    def new_state(self, seed: int = 0) -> FilterState3d:
        base = super().new_state(seed)
        st = FilterState3d(**{f: getattr(base, f) for f in FilterState.__dataclass_fields__})
        if self._members:
            seeds = np.random.SeedSequence(seed).spawn(len(self._members))
            st.bank = [
                m.new_state(int(s.generate_state(1, np.uint64)[0] >> np.uint64(1)))
                for m, s in zip(self._members, seeds, strict=True)
            ]
            for b, ms in zip(self.pose3d.offset_bank_db, st.bank, strict=True):
                ms.offset_prior_db = st.offset_prior_db + b
            sd = self.config.offset_prior_sd_db
            st.bank_log_evidence = np.array(
                [-0.5 * (b / sd) ** 2 for b in self.pose3d.offset_bank_db]
            )
        return st

    # ------------------------------------------------------------------ offset bank
    def _best_member(self, st: FilterState3d) -> int:
        return int(np.argmax(st.bank_log_evidence))

    def _bank_step(
        self, st: FilterState3d, t_s: float, heard: HeardRss, key: object
    ) -> FilterEstimate | None:
        """One packet through every member; the estimate (and the smoothed ones
        emitted now) of the member with the largest marginal likelihood."""
        ests = []
        for j, (m, ms) in enumerate(zip(self._members, st.bank, strict=True)):
            ms.last_log_evidence = 0.0
            ests.append(m.step(ms, t_s, heard, key))
            st.bank_log_evidence[j] += ms.last_log_evidence
        st.last_time_s = t_s
        self._take_bank_smoothed(st)
        return ests[self._best_member(st)]

    def _take_bank_smoothed(self, st: FilterState3d) -> None:
        """The members emit the same packets (they see the same ones): the best
        member's smoothed estimates are this filter's."""
        emitted = [m.take_smoothed() for m in self._members]
        self._smoothed.extend(emitted[self._best_member(st)])
        if st.bank_smoothed is not None:
            for kept, e in zip(st.bank_smoothed, emitted, strict=True):
                kept.extend(e)

    def flush(self, st: FilterState) -> None:
        """Emit every pending smoothed estimate (end of the data)."""
        if isinstance(st, FilterState3d) and self._members:
            for m, ms in zip(self._members, st.bank, strict=True):
                m.flush(ms)
            self._take_bank_smoothed(st)
            return
        super().flush(st)

    def _finish_step(
        self,
        st: FilterState,
        t_s: float,
        heard: HeardRss,
        key: object,
        pred: FloatArray,
        lse0: float,
        lse1: float,
    ) -> FilterEstimate | None:
        if isinstance(st, FilterState3d) and math.isfinite(lse1):
            st.last_log_evidence += lse1 - lse0
        return super()._finish_step(st, t_s, heard, key, pred, lse0, lse1)

    # ------------------------------------------------------------------ acquisition
    def _draw(
        self, st: FilterState, heard: HeardRss, m: int, offsets_db: list[float], n_packets: int
    ) -> tuple[FloatArray, FloatArray, float] | None:
        """``m`` particles from the coarse grid's best poses for ``heard`` (one
        reading per receiver standing for ``n_packets``), refined locally; the
        offset is profiled around the prior (``offsets_db`` is not needed: the
        coarse scoring profiles each pose's offset in closed form)."""
        cfg, p3, mod = self.config, self.pose3d, self.model3d
        coarse = mod.coarse
        assert coarse is not None
        idx = np.ascontiguousarray(heard.receiver_index, dtype=np.int64)
        rss = np.ascontiguousarray(heard.rss_dbm, dtype=np.float64)
        cost = np.empty(coarse.table_dbm.shape[0])
        with spare_core_threads():
            coarse_costs(coarse.table_dbm, idx, rss, p3.acquisition_sigma_db,
                         st.offset_prior_db, cfg.offset_prior_sd_db, cost)  # fmt: skip
        ok = np.isfinite(cost)
        if not ok.any():
            return None
        cost = np.where(ok, cost, np.inf)
        k = min(p3.acquisition_k, int(ok.sum()))
        top = np.argpartition(cost, k - 1)[:k]
        p = np.exp(-(cost[top] - cost[top].min()))
        pick = top[st.rng.choice(k, size=m, p=p / p.sum())]
        n_p = coarse.positions_m.shape[0]
        pos = coarse.positions_m[pick % n_p]
        ori = coarse.orientations_deg[pick // n_p]
        c = coarse.cell
        S = np.zeros((m, K.N_COLUMNS))
        u = st.rng.uniform(-1.0, 1.0, (m, 6))
        S[:, K.X_M] = pos[:, 0] + u[:, 0] * c[0]
        S[:, K.Y_M] = pos[:, 1] + u[:, 1] * c[1]
        S[:, K.Z_M] = pos[:, 2] + u[:, 2] * c[2]
        S[:, K.AZIMUTH_RAD] = np.deg2rad(ori[:, 0] + u[:, 3] * c[3]) % (2 * np.pi)
        S[:, K.PITCH_RAD] = np.deg2rad(ori[:, 1] + u[:, 4] * c[4])
        S[:, K.ROLL_RAD] = np.deg2rad(ori[:, 2] + u[:, 5] * c[5])
        self._clamp(S)
        sigma = math.sqrt(st.sigma2_db2)
        for s in range(p3.refine_steps):
            frac = (s + 1) / p3.refine_steps
            sig = p3.acquisition_sigma_db ** (1 - frac) * max(sigma, 0.5) ** frac
            best, cst, _ = self._profile(st, S, heard, n_packets, sig)
            ok = np.isfinite(cst)
            if not ok.any():
                return None
            w = np.where(ok, np.exp(-(cst - cst[ok].min())), 0.0)
            S = S[st.rng.choice(m, size=m, p=w / w.sum())]
            shrink = 0.5 ** (s + 1)
            j = st.rng.normal(0.0, 1.0, (m, 6)) * shrink
            S[:, K.X_M] += j[:, 0] * 2 * c[0]
            S[:, K.Y_M] += j[:, 1] * 2 * c[1]
            S[:, K.Z_M] += j[:, 2] * 2 * c[2]
            S[:, K.AZIMUTH_RAD] = (S[:, K.AZIMUTH_RAD] + np.deg2rad(j[:, 3] * 2 * c[3])) % (
                2 * np.pi
            )
            S[:, K.PITCH_RAD] += np.deg2rad(j[:, 4] * 2 * c[4])
            S[:, K.ROLL_RAD] += np.deg2rad(j[:, 5] * 2 * c[5])
            self._clamp(S)
        best, cst, prec = self._profile(st, S, heard, n_packets, sigma)
        if not np.isfinite(cst).any():
            return None
        return S, best, prec

    def _profile(
        self, st: FilterState, S: FloatArray, heard: HeardRss, n_packets: int, sigma_db: float
    ) -> tuple[FloatArray, FloatArray, float]:
        e = heard.rss_dbm[None, :] - self.model3d.expected(S, heard.receiver_index)
        return profile_offset_db(
            e, n_packets * heard.n_heard, sigma_db, st.offset_prior_db,
            self.config.offset_prior_sd_db,
        )  # fmt: skip

    def _clamp(self, S: FloatArray) -> None:
        """Particles into the supports: area, heights, pitch (gimbal-aware) and roll."""
        mod = self.model3d
        b = mod.box_m
        S[:, K.X_M] = np.clip(S[:, K.X_M], b[0], b[1])
        S[:, K.Y_M] = np.clip(S[:, K.Y_M], b[2], b[3])
        zero = np.zeros(S.shape[0])
        tilt_height_step(S, np.zeros((S.shape[0], 2)), zero, 1.0, 0.0, 0.0, mod.tilt_rad,
                         mod.z_box_m)  # fmt: skip
        S[:, K.Z_M] = np.clip(S[:, K.Z_M], mod.z_box_m[0], mod.z_box_m[1])

    # ------------------------------------------------------------------ step
    def step(
        self, st: FilterState, t_s: float, heard: HeardRss, key: object = None
    ) -> FilterEstimate | None:
        """Process one packet (as :meth:`ParticleFilter.step`, with the 3-D kernels)."""
        if self._members and isinstance(st, FilterState3d):
            return self._bank_step(st, t_s, heard, key)
        mod = self.model3d
        dt_s = self._advance_clock(st, t_s, heard)
        if dt_s is None:
            return None
        dt = dt_s
        S, logw = st.particles, st.log_weights
        assert S is not None and logw is not None
        n, h = S.shape[0], heard.n_heard
        work = self._buffers(n)
        noise_z = np.empty(n)
        if dt > 0:
            st.rng.standard_normal(out=work.noise)
            st.rng.standard_normal(out=noise_z)
        pred = work.pred[: n * h].reshape(n, h)
        sigma = math.sqrt(st.sigma2_db2)
        p3 = self.pose3d
        if p3.heading_prior_deg > 0 and dt > 0:
            heading_prior(
                S, logw, dt / p3.heading_prior_time_s,
                1.0 / math.radians(p3.heading_prior_deg) ** 2, p3.heading_prior_speed_mps,
            )  # fmt: skip
        band = self._band
        if band is not None and dt > 0:
            _band_prior(S, logw, band, dt)
        with spare_core_threads():
            lse0, lse1 = packet_update3d(
                S, logw, work.noise, noise_z, dt, self._motion, mod.box_m, mod.tilt_rad,
                mod.z_box_m, np.ascontiguousarray(heard.receiver_index, dtype=np.int64),
                *mod.arrays3d(), np.ascontiguousarray(heard.rss_dbm, dtype=np.float64), sigma,
                self._likelihood_parameter(sigma), pred, work.w,
            )  # fmt: skip
        est = self._finish_step(st, t_s, heard, key, pred, lse0, lse1)
        if est is None or self.pose3d.estimate != "mode" or self.lag_s is not None:
            return est  # (smoothing: the smoother's estimates take the mode, _emit)
        work = self._buffers(st.particles.shape[0] if st.particles is not None else n)
        return self._mode_estimate(work.rows, work.w, est)

    # ------------------------------------------------------------------ estimates
    def _mode_estimate(
        self, rows: FloatArray, w: FloatArray, est: FilterEstimate
    ) -> FilterEstimate:
        """``est`` with its pose replaced by the main mode of the pose rows
        ``rows`` weighted by ``w`` (:func:`~radiopose.filtering.kernels3d.mode_pose`);
        its spread, offset and σ are kept."""
        p3 = self.pose3d
        out = np.empty(7)
        mode_pose(
            rows, w, p3.mode_centres, p3.mode_radius_m,
            math.cos(math.radians(0.5 * p3.mode_radius_deg)), 2, out,
        )  # fmt: skip
        x, y, z, az, pitch, roll, _ = out.tolist()
        return replace(
            est,
            position_m=(x, y, z),
            orientation_deg=(math.degrees(az), math.degrees(pitch), math.degrees(roll)),
        )

    def _emit(self, st: FilterState, w: FloatArray, upto_s: float | None) -> None:
        """The smoother's estimates (as :meth:`ParticleFilter._emit`), each
        replaced by the main mode of its packet's ancestors under ``estimate =
        "mode"``."""
        lin = st.lineage
        if self.pose3d.estimate != "mode" or lin is None:
            super()._emit(st, w, upto_s)
            return
        moments = self._buffers(lin.n).lineage_moments
        while st.pending and (upto_s is None or st.pending[0][0] <= upto_s):
            k = lin.head
            rows = lin.rows[k, : int(lin.n_rows[k])]
            wa = np.bincount(lin.anc[k], weights=w, minlength=rows.shape[0]).astype(np.float64)
            _, key, causal = st.pending.popleft()
            est = self._mode_estimate(rows, wa, causal)  # before the slot is reused
            lin.pop_moments(w, moments)
            # the spread, offset and σ are the filter's own at that packet (as in 2-D)
            self._smoothed.append((key, est))
