"""The particle filter's configuration and its per-packet result.

:class:`FilterConfig` (every setting with its unit and default, validated on
construction) and :class:`FilterEstimate` (one packet's pose with its stated
uncertainty); :mod:`radiopose.filtering.particle` runs the filter they describe.
"""

from __future__ import annotations

import ast
import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from radiopose.errors import InputError, check_setting_types
from radiopose.filtering.forked import check_workers

if TYPE_CHECKING:
    import argparse

LIKELIHOODS = ("mixture", "huber")
"""The values of :attr:`FilterConfig.likelihood`."""

SMOOTHERS = ("lineage", "backward")
"""The values of :attr:`FilterConfig.smoother` (issue 15, the offline smoother)."""

MAX_LAG_S = 10.0
"""Longest smoothing lag, seconds (``TrackerConfig.smoothing_lag_s``,
``tracker.toml``'s ``smoothing_lag_s``, the streaming ``Tracker``'s ``lag_s``):
the smoother holds every particle of every packet within the lag, so its
memory grows with lag × packet rate × particles (about 0.4 GB at 10 s, 200
packets/s and the 2-D default)."""

LIVE_RESOLVE_TIMES_S = (0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.75, 1.0, 1.25, 1.5)
"""The live filter's re-solves of a track's start, seconds after its first
packet (``FilterConfig.live_resolve_times_s``; the default since session 25,
extended to 1.5 s in session 26: docs/filter.md, "The live re-solve")."""

MAX_LIVE_RESOLVES = 20
"""Most re-solves of a track's start the live filter may be set to
(``FilterConfig.live_resolve_times_s``)."""


def lag_in_range(lag_s: object) -> bool:
    """Whether ``lag_s`` is a smoothing lag: a number of seconds in [0,
    :data:`MAX_LAG_S`] (a bool is not); ``None`` (causal) is the caller's case."""
    if not isinstance(lag_s, int | float) or isinstance(lag_s, bool):
        return False
    return 0 <= lag_s <= MAX_LAG_S


MIN_REENTRY_INTERVAL_S = 1e-3
"""Shortest :attr:`FilterConfig.reentry_interval_s`, seconds (a re-entry per
millisecond is already one per packet at any real rate)."""

REFIT_PASSES = ("forward", "reversed", "both")
"""The values of :attr:`FilterConfig.offset_refit_passes` (issue 15, round 7)."""
PROFILE_TRACKS = ("winner", "always")
"""The values of :attr:`FilterConfig.offset_profile_track` (issue 15, round 8)."""


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the particle filter (units in the names; defaults measured in
    ``docs/filter.md``).

    Attributes
    ----------
    n_particles
        Particles per device.
    accel_noise_mps2
        White-acceleration density of the motion model, m/s² per √Hz.
    angular_accel_noise_dps2
        White angular-acceleration density of the filter's motion model, °/s²
        per √Hz (270 since 2026-11-27, 90 before: the hypotheses then follow a
        hand's sway; the arbiter keeps 90 through
        ``refine_angular_accel_noise_dps2``; docs/filter.md, "Angular noise";
        the 3-D filter keeps 90 through ``Pose3dConfig``).
    tilt_noise_dps
        Random-walk density of pitch and roll, °/√s (only where the site's
        candidate orientations have several pitch or roll values).
    max_speed_mps, max_rate_dps
        Support of the motion prior: speed and turn rate are clipped there.
    initial_speed_mps, initial_rate_dps
        Standard deviation of each velocity component and of the turn rate of
        a new particle.
    reentry_interval_s
        How often hypotheses from the full-grid likelihood re-enter.
    reentry_fraction
        Fraction of the particles replaced at each re-entry.
    proposal_window_s
        Packets pooled (mean RSS per receiver) for the re-entry proposal, and
        over which a proposal's evidence is compared with the filter's.
    jump_probability
        Prior probability that the filter's mode is wrong at one re-entry.
    k
        Candidates taken from the kernel per proposal offset.
    sigma_prior_db, sigma_floor_db
        Starting value and lower bound of the online σ estimate, dB.
    sigma_memory_packets
        Packets over which the σ estimate averages once settled.
    huber_c
        Clip of the residuals that update the σ estimate, in units of 2σ.
    outlier_probability, outlier_range_db
        Prior probability that one receiver's reading is an outlier, spread
        uniformly over ``outlier_range_db``: a receiver far off costs a bounded
        amount and does not move the power offset (the likelihood is a
        Gaussian-plus-uniform mixture per receiver).
    offset_prior_sd_db
        Prior standard deviation of the transmit-power offset around
        ``devices.csv``'s ``tx_power_dbm``, dB.
    initial_offsets_db
        Offsets at which the first packet's candidates are searched, dB.
    offset_scan_db, offset_scans_per_reentry
        Besides the offset belief (and the prior's centre), each re-entry
        searches the grid at this many further offsets from the prior's
        centre, taken in turn from ``offset_scan_db`` (dB): the offset is a
        constant of the device, and a wrong (pose, offset) lock is left only
        if the true offset is searched (docs/filter.md, "Unknown transmit power").
    rest_fraction
        Fraction of the re-entered hypotheses that start at rest (velocity and
        turn rate 0) instead of with the motion of a particle of the filter
        (which belongs to the filter's mode, perhaps the wrong one); only when
        the evidence window holds several packets.
    difference_memory, difference_max_dt_s
        σ is also estimated from the packets alone: the median of the last
        ``difference_memory`` squared differences of one receiver's readings at
        most ``difference_max_dt_s`` apart; σ is the smaller of that and the
        fit's estimate (``0`` switches this off).
    reacquire_gap_s
        Past this silence a device is acquired afresh (its offset and σ
        estimates are kept).
    min_acquisition_receivers
        Receivers a packet needs to start (or restart) a track.
    likelihood
        Per-receiver likelihood: ``"mixture"`` (default: Gaussian plus the
        uniform outlier term above) or ``"huber"`` (the previous design's
        Huber-weighted Gaussian, threshold ``huber_c`` σ; chosen by the real
        BLE site's cross-validation, docs/real-data.md).
    jump_own_past
        ``True`` (default): a re-entered hypothesis more than 1 m or 30° from the
        particle whose motion it copied gets its own pose moved back as its past
        for the smoother; ``False``: every re-entered hypothesis inherits that
        particle's past (the previous design).
    offline_offset_selection
        Offline only (batch ``locate``; the live server and the causal
        ``Tracker`` ignore it): after the filter's pass over the whole file,
        run it again around a few candidate device-level power offsets with a
        tight offset prior and keep the pass whose marginal likelihood of the
        whole file is largest (:mod:`radiopose.filtering.offset`;
        docs/filter.md, "Accuracy round 4"). Costs up to three more passes,
        only for a device whose offset is found away from its enrolled power.
    offset_selection_sd_db
        Standard deviation of the offset prior of those passes around their
        candidate, dB.
    offset_selection_merge_db
        Candidate offsets closer than this to an earlier one are not run, dB.
    offset_selection_trigger_db
        The further passes run only if a candidate lies this far or further
        from the prior's centre (``devices.csv``'s power), dB (``0``: always).
    smoother
        The smoother of a run with a lag (offline ``locate``): ``"lineage"``
        (the particles' genealogy, :mod:`radiopose.filtering.lineage`) or
        ``"backward"`` (the filter's particle sets smoothed backward, a
        re-entered hypothesis's past found among the particles before it,
        :mod:`radiopose.filtering.smoother`; docs/filter.md, "Smoother").
    smoother_position_bandwidth_m, smoother_azimuth_bandwidth_deg
        The backward smoother's kernel widths (a re-entered hypothesis's
        ancestors are the particles before it within ``smoother_reach`` of them).
    smoother_reach
        In bandwidths (see above).
    smoother_ghost_s
        How far back a re-entered hypothesis with no particle within reach
        travels on its own motion before its past is the filter's, seconds.
    offline_reverse_pass
        Offline only (batch ``locate``; the live server and the causal
        ``Tracker`` ignore it): after the forward pass (and the offset
        selection), run the filter again over the time-reversed packets and,
        where the two smoothed tracks disagree (more than
        ``reverse_disagree_m`` or ``reverse_disagree_deg``), keep per segment
        the track whose poses make the segment's packets more likely
        (:mod:`radiopose.filtering.reverse`; docs/filter.md, "Accuracy round
        5"). Costs one more pass. On by default (2026-11-27, with
        ``offline_refine``); ``false`` gives the forward pass alone.
    reverse_disagree_m, reverse_disagree_deg
        Where the forward and reversed tracks count as disagreeing, metres and
        degrees of azimuth.
    offline_refine
        Offline only, 2-D: refine the forward track, every other pass of the
        offset selection and, with ``offline_reverse_pass``, the reversed
        pass's track and the combined one, by batch MAP over the whole file
        (data, the motion prior, one device offset) and emit the refined
        candidate of the lowest objective
        (:mod:`radiopose.filtering.refine2d`; docs/filter.md, "Accuracy round
        6"). On by default (2026-11-27); without ``offline_reverse_pass`` the
        candidates are the forward track and the offset selection's passes.
    refine_max_nfev
        Residual evaluations of each candidate's refinement.
    refine_angular_accel_noise_dps2
        The arbiter's motion prior on the azimuth, °/s²/√Hz (white angular
        acceleration, as ``angular_accel_noise_dps2`` in the filter); default
        90 (the filter's value before 2026-11-27); 0 takes the filter's own
        ``angular_accel_noise_dps2``.
    refine_banded
        Offline only, with ``offline_refine`` (default on since 2026-11-27;
        ``false`` gives the sparse LU of round 6): solve each
        refinement step's normal equations in band form (a banded Cholesky and
        the offset's Schur complement) instead of a sparse LU: the arbiter's
        linear algebra ≈ 4× cheaper (≈ 0.4 CPU s less on the benchmark's
        2,000-packet trace), the same optimum to ~1e-9 relative, but a
        borderline stop of the solver can end one iteration apart: on tuning
        seeds 7200–7219 one run of 80 moved by 0.002 m (docs/performance.md,
        "Ninth pass"; docs/filter.md, "The arbiter's banded solve").
    offline_workers
        Offline only (batch ``locate``, 2-D): processes the passes after the
        forward one may use, this one included (at most the cores available):
        with 2 the time-reversed pass runs in a forked child beside the
        forward pass, and the offset selection's passes and the arbiter's
        refinements are spread over both (:mod:`radiopose.filtering.forked`;
        docs/performance.md, "Eighth pass"). The estimates are the same as
        with 1 (every pass in this process), bit for bit. The live server and
        the streaming ``Tracker`` never fork.
    arbiter_offset_evidence
        Offline only, with ``offline_refine`` (round 7, docs/filter.md
        "Accuracy round 7"; default off): each candidate's refined objective
        gets a penalty from its refined device offset, the offset selection's
        tight passes' whole-file evidence near that offset against the best
        pass's, nats (:func:`radiopose.filtering.offset_refit.evidence_penalty`).
    offline_offset_refit
        Offline only, with ``offline_refine`` (round 7; default off): when the
        arbiter's chosen candidate refines to an offset
        ``offset_selection_trigger_db`` or more from the enrolled power and no
        tight pass ran within ``offset_refit_tolerance_db`` of it, one more
        tight pass runs there and its track competes
        (:func:`radiopose.filtering.offset_refit.arbitrate_offline`).
    offset_refit_tolerance_db
        See ``offline_offset_refit``, dB (default 1.5, as measured).
    offset_refit_passes
        Which passes the refit runs at that offset (default ``"reversed"``,
        as measured): ``"forward"``,
        ``"reversed"`` (over the time-reversed packets, as
        ``offline_reverse_pass``) or ``"both"``.
    offline_offset_profile
        Offline only, 2-D (round 8, docs/filter.md "Accuracy round 8"; default
        off): when the offset selection runs (a candidate of pass 1 lies
        ``offset_selection_trigger_db`` or more from the enrolled power), one
        more tight pass runs at the device's offset by the data alone: the
        argmax of the whole file's offset profile over a coarse pose grid
        (:mod:`radiopose.filtering.offset_profile`), unless a candidate lies
        within ``offset_profile_tolerance_db`` of it. Its track is one more
        candidate of the evidence test and the arbiter.
    offset_profile_tolerance_db
        See ``offline_offset_profile``, dB.
    offset_selection_grid_db
        Offline only, 2-D (2026-11-27, session 11; default empty: off): when
        the offset selection runs, tight passes also run at these offsets (dB
        from the enrolled power) unless a candidate lies within
        ``offset_selection_merge_db`` of one, so that a device's true offset
        is searched even when pass 1's beliefs never came near it (the
        "search failures" of docs/filter.md, "Accuracy round 7"). Each is one
        more candidate of the evidence test and the arbiter.
    offset_selection_reversed_passes
        Offline only, 2-D, with the reversed pass and the arbiter (session 11;
        default 1): when the offset selection ran further passes, this many of
        its passes, largest whole-file evidence first, get a pass over the
        time-reversed packets with their offset prior; the chosen pass's is
        the reversed pass of round 5, the others' tracks are more candidates of
        the arbiter (docs/filter.md, "Offset grid").
    arbiter_laplace
        Offline only, 2-D, with ``offline_refine`` (session 12; default off):
        the arbiter keeps the candidate of the lowest refined objective plus
        its Laplace width term, ½ log det of the objective's Gauss–Newton
        Hessian at the optimum (−log of the mode's posterior mass instead of
        its peak; :attr:`radiopose.filtering.refine2d.Refined2d.log_volume`;
        docs/filter.md, "Laplace arbiter"). A track where some candidate's
        Hessian is not numerically positive definite (no finite term) is
        arbitrated without the term.
    offline_coarse_track
        Offline only, 2-D, with ``offline_refine`` (session 13; default on):
        one more candidate of the arbiter, the most likely path of a coarse
        grid HMM over the whole file's 0.1 s windows at the offset of its
        largest evidence (:mod:`radiopose.filtering.coarse_track`): a search
        that no particle filter's lock can mislead (docs/filter.md,
        "Coarse-grid HMM").
    coarse_track_margin
        With ``offline_coarse_track``: the coarse path's refined track wins the
        arbiter only if its objective is lower than every other candidate's by
        more than this (σ² units ≈ nats; default 2, chosen on the tuning
        seeds' margins: docs/filter.md, "Coarse-grid HMM").
    coarse_track_paths
        With ``offline_coarse_track``: how many coarse paths enter the
        arbiter, each with the margin: the path at the evidence's largest
        peak over the offsets, then at its next local maxima, largest first
        (:func:`radiopose.filtering.coarse_track.coarse_tracks`; session 14,
        docs/filter.md, "Coarse-grid HMM: more than one path"); an integer in
        [1, 8].
    coarse_track_path_step_m
        With ``offline_coarse_track``: the grid step of the coarse paths,
        metres (default 0.5 since session 14; 1 is session 13's path); the
        evidence over the offsets stays on the 1 m grid
        (``CoarseSettings.path_position_step_m``; docs/filter.md, "Coarse-grid
        HMM: a finer path"); positive, at most 5.
    live_resolve_times_s
        Live only (the streaming ``Tracker`` with a lag, as the live server
        runs it; 2-D sites): at each of these times after a track's first
        packet, seconds, the track so far is re-solved by the offline passes
        (forward, reversed, coarse HMM, arbiter; serial), the estimates the
        smoother still holds are replaced by the re-solve's and, where its
        last pose is more than 1 m or 30° from the filter's, the particles
        are re-seeded there (:mod:`radiopose.tracker.resolve`). Default
        ``LIVE_RESOLVE_TIMES_S`` (every 0.05 s from 0.25 to 0.5 s, then every
        0.25 s to 1.5 s); empty: off. Batch ``locate`` with its offline passes
        and the causal filter never re-solve. At most ``MAX_LIVE_RESOLVES``
        increasing times in (0, ``MAX_LAG_S``]; a re-solve of n packets costs
        about 40 ms + (2.5–5 ms) × n of CPU.
    live_resolve_max_sigma_db
        A re-solve runs only while the filter's σ estimate is at most this,
        dB; positive, default ``None`` (no gate; in ``tracker.toml`` a number or
        the key left out). Session 25's 1.5 dB gate
        (re-solves of the first half second only were as often wrong as the
        filter at σ = 2–3 dB) was dropped in session 26 when the re-solves
        went on to 1.5 s (docs/filter.md, "The live re-solve").
    live_resolve_every_s
        Live only, an option (default 0: off): after the last of
        ``live_resolve_times_s``, re-solve the track's last
        ``live_resolve_window_s`` of packets every this many seconds, as
        above, for the whole track. On 10 s walks at σ = 3 dB (tuning seeds)
        every 1 s over 3 s took the live error after the first 2 s from
        5.26° to 4.27°, at about 1.5 s of CPU per second of a 200-packet/s
        track (10–20 % of a core at a few packets per second); seconds in
        [0, ``MAX_LAG_S``].
    live_resolve_window_s
        The periodic re-solve's window, seconds in (0, ``MAX_LAG_S``]
        (default 1.5).
    offset_profile_track
        Whether the profile's pass is an arbiter candidate: ``"winner"``
        (default) only when it wins the evidence test (then it is the chosen
        pass, as any winner); ``"always"`` as the selection's other passes (the
        first version, docs/filter.md "Accuracy round 8").
    """

    n_particles: int = 2000
    accel_noise_mps2: float = 1.0
    angular_accel_noise_dps2: float = 270.0
    tilt_noise_dps: float = 10.0
    max_speed_mps: float = 10.0
    max_rate_dps: float = 720.0
    initial_speed_mps: float = 1.0
    initial_rate_dps: float = 90.0
    reentry_interval_s: float = 0.1
    reentry_fraction: float = 0.05
    proposal_window_s: float = 0.1
    jump_probability: float = 0.001
    k: int = 100
    sigma_prior_db: float = 2.0
    sigma_floor_db: float = 0.25
    sigma_memory_packets: int = 200
    huber_c: float = 2.5
    outlier_probability: float = 0.05
    outlier_range_db: float = 60.0
    offset_prior_sd_db: float = 6.0
    initial_offsets_db: tuple[float, ...] = (-9.0, -4.5, 0.0, 4.5, 9.0)
    offset_scan_db: tuple[float, ...] = (
        3.0, -3.0, 6.0, -6.0, 9.0, -9.0, 1.5, -1.5, 4.5, -4.5, 7.5, -7.5, 12.0, -12.0,
    )  # fmt: skip
    offset_scans_per_reentry: int = 2
    rest_fraction: float = 0.5
    difference_memory: int = 400
    difference_max_dt_s: float = 0.05
    reacquire_gap_s: float = 1.0
    min_acquisition_receivers: int = 3
    # issue 16 (real data): switches back to parts of the previous design; the
    # defaults are the current behaviour
    likelihood: str = "mixture"
    jump_own_past: bool = True
    # issue 15 (unknown transmit power): the offline device-level offset
    offline_offset_selection: bool = True
    offset_selection_sd_db: float = 1.0
    offset_selection_merge_db: float = 0.75
    offset_selection_trigger_db: float = 1.5
    # issue 15 (smoother): the offline smoother's choice and its settings
    smoother: str = "lineage"
    smoother_position_bandwidth_m: float = 0.25
    smoother_azimuth_bandwidth_deg: float = 8.0
    smoother_reach: float = 3.0
    smoother_ghost_s: float = 0.5
    # issue 15 (wrong locks, round 5): the offline time-reversed pass (on by
    # default since round 6, as a candidate of the arbiter)
    offline_reverse_pass: bool = True
    reverse_disagree_m: float = 1.0
    reverse_disagree_deg: float = 30.0
    # issue 15 (wrong locks, round 6): the offline 2-D batch MAP arbiter (on by
    # default: docs/filter.md, "Round 6 as the default")
    offline_refine: bool = True
    refine_max_nfev: int = 30
    refine_angular_accel_noise_dps2: float = 90.0
    refine_banded: bool = True
    # issue 15 (whole-process speed): the offline passes on forked children
    offline_workers: int = 2
    # issue 15 (+6 dB tails, round 7): the arbiter's offset judged by the passes'
    # evidence, and a tight pass at the arbiter's offset (both off by default)
    arbiter_offset_evidence: bool = False
    offline_offset_refit: bool = False
    offset_refit_tolerance_db: float = 1.5
    offset_refit_passes: str = "reversed"
    # issue 15 (+6 dB tails, round 8): a tight pass at the offset profile's argmax (off)
    offline_offset_profile: bool = False
    offset_profile_tolerance_db: float = 1.5
    offset_profile_track: str = "winner"
    # issue 15 (+6 dB tails, session 11): a fixed grid of tight passes (off)
    offset_selection_grid_db: tuple[float, ...] = ()
    offset_selection_reversed_passes: int = 1
    # issue 15 (σ = 3 dB ties, session 12): the arbiter compares the candidates'
    # posterior mass (Laplace) instead of their peak (off)
    arbiter_laplace: bool = False
    # issue 15 (search failures, session 13): the whole file's coarse-grid HMM
    # path as one more arbiter candidate, winning only by a margin (on by
    # default: docs/filter.md, "Coarse-grid HMM"); session 14: the path on a
    # 0.5 m grid (default), more paths (an option)
    offline_coarse_track: bool = True
    coarse_track_margin: float = 2.0
    coarse_track_paths: int = 1
    coarse_track_path_step_m: float = 0.5
    # issue 15 (live acquisition, session 25): times after a track's start, s,
    # at which the live (lagged, streaming) filter re-solves the track so far
    # with the offline passes (radiopose.tracker.resolve; () turns it off)
    live_resolve_times_s: tuple[float, ...] = LIVE_RESOLVE_TIMES_S
    live_resolve_max_sigma_db: float | None = None
    live_resolve_every_s: float = 0.0
    live_resolve_window_s: float = 1.5

    def __post_init__(self) -> None:
        check_setting_types(self, "filter")
        positive = (
            "accel_noise_mps2", "angular_accel_noise_dps2", "max_speed_mps", "max_rate_dps",
            "reentry_interval_s", "proposal_window_s", "sigma_prior_db", "sigma_floor_db",
            "huber_c", "offset_prior_sd_db", "reacquire_gap_s", "difference_max_dt_s",
            "offset_selection_sd_db",
            "smoother_position_bandwidth_m", "smoother_azimuth_bandwidth_deg", "smoother_reach",
            "reverse_disagree_m", "reverse_disagree_deg", "offset_refit_tolerance_db",
            "offset_profile_tolerance_db",
        )  # fmt: skip
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise InputError(f"filter setting {name} = {v!r} must be a positive number")
        for name in (
            "tilt_noise_dps", "initial_speed_mps", "initial_rate_dps",
            "refine_angular_accel_noise_dps2",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"filter setting {name} = {v!r} must be >= 0")
        if self.reentry_interval_s < MIN_REENTRY_INTERVAL_S:
            raise InputError(
                f"filter setting reentry_interval_s = {self.reentry_interval_s!r} must be at "
                f"least {MIN_REENTRY_INTERVAL_S:g} s"
            )
        if not 10 <= self.n_particles <= 1_000_000:
            raise InputError(f"filter setting n_particles = {self.n_particles!r} is out of range")
        if not 0 < self.outlier_probability < 1 or not 0 < self.outlier_range_db < math.inf:
            raise InputError(
                "filter settings outlier_probability lies in (0, 1), outlier_range_db > 0"
            )
        if not 0 < self.reentry_fraction < 1 or not 0 < self.jump_probability < 1:
            raise InputError("filter settings reentry_fraction and jump_probability lie in (0, 1)")
        if not 0 <= self.rest_fraction <= 1:
            raise InputError(f"filter setting rest_fraction = {self.rest_fraction!r} not in [0, 1]")
        if self.offset_scans_per_reentry < 0 or self.difference_memory < 0:
            raise InputError(
                "filter settings offset_scans_per_reentry and difference_memory must be >= 0"
            )
        n_paths = self.coarse_track_paths
        if isinstance(n_paths, bool) or not (isinstance(n_paths, int) and 1 <= n_paths <= 8):
            raise InputError(
                f"filter setting coarse_track_paths = {n_paths!r} must be an integer in [1, 8]"
            )
        step = self.coarse_track_path_step_m
        if not (isinstance(step, int | float) and not isinstance(step, bool)
                and math.isfinite(step) and 0 < step <= 5.0):  # fmt: skip
            raise InputError(
                f"filter setting coarse_track_path_step_m = {step!r} must be in (0, 5] m"
            )
        n_rev = self.offset_selection_reversed_passes
        if isinstance(n_rev, bool) or not (isinstance(n_rev, int) and 1 <= n_rev <= 16):
            raise InputError(
                f"filter setting offset_selection_reversed_passes = {n_rev!r} must be an "
                "integer in [1, 16]"
            )
        if not all(math.isfinite(v) and abs(v) <= 60.0 for v in self.offset_selection_grid_db):
            raise InputError(
                f"filter setting offset_selection_grid_db = {self.offset_selection_grid_db!r}: "
                "each offset must be a finite number of dB within ±60"
            )
        if not all(math.isfinite(v) for v in self.offset_scan_db):
            raise InputError(f"filter setting offset_scan_db = {self.offset_scan_db!r} not finite")
        if not self.initial_offsets_db or self.min_acquisition_receivers < 1:
            raise InputError(
                "filter settings: initial_offsets_db must list an offset and "
                "min_acquisition_receivers must be >= 1"
            )
        gate = self.live_resolve_max_sigma_db
        if gate is not None and not gate > 0:
            raise InputError(
                f"filter setting live_resolve_max_sigma_db = {gate!r} must be a positive "
                "number of dB (left out: no gate)"
            )
        for name, v, lo_open in (
            ("live_resolve_every_s", self.live_resolve_every_s, False),
            ("live_resolve_window_s", self.live_resolve_window_s, True),
        ):
            ok = isinstance(v, int | float) and not isinstance(v, bool) and v <= MAX_LAG_S
            if not ok or not (v > 0 if lo_open else v >= 0):
                bracket = "(" if lo_open else "["
                raise InputError(
                    f"filter setting {name} = {v!r} must be in {bracket}0, {MAX_LAG_S:g}] s"
                )
        times = self.live_resolve_times_s
        if (
            len(times) > MAX_LIVE_RESOLVES
            or not all(0 < v <= MAX_LAG_S for v in times)
            or any(b <= a for a, b in itertools.pairwise(times))
        ):
            raise InputError(
                f"filter setting live_resolve_times_s = {times!r} must be at most "
                f"{MAX_LIVE_RESOLVES} increasing times in (0, {MAX_LAG_S:g}] s"
            )
        if not 1 <= self.k <= 100_000:
            raise InputError(f"filter setting k = {self.k!r} must be in [1, 100000]")
        for name in (
            "offset_selection_merge_db", "offset_selection_trigger_db", "coarse_track_margin",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise InputError(f"filter setting {name} = {v!r} must be >= 0")
        if isinstance(self.refine_max_nfev, bool) or not (
            isinstance(self.refine_max_nfev, int) and 1 <= self.refine_max_nfev <= 10_000
        ):
            raise InputError(
                f"filter setting refine_max_nfev = {self.refine_max_nfev!r} must be an integer "
                "in [1, 10000]"
            )
        check_workers(self.offline_workers)
        if self.likelihood not in LIKELIHOODS:
            raise InputError(
                f"filter setting likelihood = {self.likelihood!r} is not one of {LIKELIHOODS}"
            )
        if self.offset_refit_passes not in REFIT_PASSES:
            raise InputError(
                f"filter setting offset_refit_passes = {self.offset_refit_passes!r} is not one "
                f"of {REFIT_PASSES}"
            )
        if self.offset_profile_track not in PROFILE_TRACKS:
            raise InputError(
                f"filter setting offset_profile_track = {self.offset_profile_track!r} is not "
                f"one of {PROFILE_TRACKS}"
            )
        if self.smoother not in SMOOTHERS:
            raise InputError(
                f"filter setting smoother = {self.smoother!r} is not one of {SMOOTHERS}"
            )
        if not (math.isfinite(self.smoother_ghost_s) and self.smoother_ghost_s >= 0):
            raise InputError(
                f"filter setting smoother_ghost_s = {self.smoother_ghost_s!r} must be >= 0"
            )


@dataclass(frozen=True)
class FilterEstimate:
    """One packet's estimate.

    Attributes
    ----------
    position_m
        ``(x, y, z)`` metres.
    orientation_deg
        ``(azimuth, pitch, roll)`` degrees, azimuth and roll in ``[0, 360)``.
    position_std_m
        Root of the trace of the horizontal position covariance, metres.
    azimuth_std_deg
        Circular standard deviation of azimuth, degrees.
    offset_db
        Posterior mean of the transmit-power offset, dB (``nan`` if smoothed).
    sigma_db
        The current σ estimate, dB.
    """

    position_m: tuple[float, float, float]
    orientation_deg: tuple[float, float, float]
    position_std_m: float
    azimuth_std_deg: float
    offset_db: float = math.nan
    sigma_db: float = math.nan


def config_overrides(items: Sequence[str], config: type = FilterConfig) -> dict[str, object]:
    """``FIELD=VALUE`` items (the scripts' ``--set``; VALUE a Python literal)
    as overrides of the dataclass ``config`` (:class:`FilterConfig`, or e.g.
    :class:`radiopose.filtering.particle3d.Pose3dConfig`), checked by
    building it.

    Raises
    ------
    InputError
        An unknown field, a VALUE that is not a literal, or a value the
        config refuses; the message names the item.
    """
    fields = {f.name for f in dataclasses.fields(config)}
    out: dict[str, object] = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in fields:
            raise InputError(f"{item}: {key!r} is not a {config.__name__} field")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            raise InputError(f"{item}: {value!r} is not a Python literal") from None
    try:
        dataclasses.replace(config(), **out)
    except TypeError as exc:
        raise InputError(str(exc)) from None
    return out


def overrides_or_exit(
    parser: argparse.ArgumentParser, items: Sequence[str], option: str = "--set",
    config: type = FilterConfig,
) -> dict[str, object]:  # fmt: skip
    """:func:`config_overrides` for a script's ``option`` (``--set``,
    ``--pose3d-set``): a bad item is the parser's usage error naming the
    option and the item (exit status 2), not a traceback."""
    try:
        return config_overrides(items, config)
    except InputError as exc:
        parser.error(f"{option} {exc}")
