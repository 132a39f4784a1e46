"""A particle filter over pose, velocity, turn rate and transmit-power offset.

Beyond the paper: instead of hard per-packet decisions (top-k, clustering,
motion gates that veto), the device's state is a probability distribution,
carried by ``n_particles`` weighted samples and updated by every packet.

State of one particle (:mod:`radiopose.filtering.kernels` names the columns):
position ``(x, y, z)`` metres (``z`` fixed at the site's candidate height),
velocity ``(vx, vy)`` m/s, azimuth and turn rate, pitch and roll (a random walk
within the site's candidate range; frozen where the site has one value), and a
Gaussian belief ``N(b̄, P)`` about the device's transmit-power offset ``b`` in
dB from ``devices.csv``'s ``tx_power_dbm`` (integrated out exactly per particle:
Rao-Blackwellised).

One packet (:meth:`ParticleFilter.step`):

1. **Predict**: nearly-constant velocity and turn rate (white acceleration,
   :func:`~radiopose.filtering.kernels.predict`); speed and turn rate are
   limited only by the prior's support (``TrackerConfig``'s 10 m/s; twice its
   360°/s, so rotation beyond the paper's bound is tracked, not vetoed).
2. **Weight** by the packet's likelihood: the expected RSS off the grid
   (survey map and pattern bilinear), per receiver Gaussian in dB with an
   estimated σ mixed with a uniform outlier term (a receiver 15 dB off costs a
   bounded amount and does not move the offset), the power offset marginalised
   (:func:`~radiopose.filtering.kernels.measurement_update`). Any number of
   receivers informs the filter; a packet heard by one still counts.
3. **Re-enter hypotheses** every ``reentry_interval_s``: the compiled kernel
   (:mod:`radiopose.likelihood`) scores the whole candidate grid against the
   median RSS of the last ``proposal_window_s`` (per receiver), at the current
   offset belief, the prior's and ``offset_scans_per_reentry`` offsets scanned
   in turn over the prior's range, each candidate's offset then profiled out
   (:func:`radiopose.likelihood.profile_offset_db`); a few
   particles are replaced by draws from that top-k, each weighted by its
   likelihood over the evidence window against the filter's own evidence over
   the same packets, times a jump prior ``jump_probability``. A wrong lock is
   thereby left as soon as the data over one window favour another mode by
   more than ``log(m / jump_probability)``.
4. **σ** is estimated online, the smaller of the fit's estimate (EWMA of the
   posterior-median squared residual, started from ``sigma_prior_db``) and the
   packets' own (median squared difference of a receiver's consecutive
   readings): a wrong lock inflates the first, not the second. No σ is told.
5. **Resample** (systematic) when the effective sample size falls below half.

Estimates are the weighted mean position and circular mean azimuth, with the
cloud's spread as ``position_std_m`` (root of the trace of the horizontal
covariance) and ``azimuth_std_deg`` (circular standard deviation). Offline,
a **fixed-lag smoother** reads each packet's estimate from the ancestors, at
that packet, of the particles ``lag_s`` later (the particles' genealogy;
hypotheses that re-entered carry their pose back over the past as static);
``FilterConfig.smoother = "backward"`` smooths the kept particle sets backward
instead (:mod:`radiopose.filtering.smoother`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import LIKELIHOODS, FilterConfig, FilterEstimate
from radiopose.filtering.lineage import Lineage
from radiopose.filtering.model import FilterModel
from radiopose.filtering.smoother import BackwardSettings, BackwardStore
from radiopose.likelihood import HeardRss, profile_offset_db
from radiopose.likelihood.compiled import spare_core, thread_pool
from radiopose.units import FloatArray

__all__ = [
    "LIKELIHOODS",
    "FilterConfig",
    "FilterEstimate",
    "FilterModel",
    "FilterState",
    "ParticleFilter",
]

_SEED_LIMIT = 2**63
"""The motion noise's per-packet seed (:func:`kernels.motion_noise_into`) is
drawn from ``[0, 2⁶³)`` by the track's generator."""

_HINT_BIN_DB = 1.5
"""Width of the power-offset bins whose grid searches share a threshold hint, dB
(the scanned offsets are 1.5 dB apart; speed only)."""


@dataclass(eq=False)
class FilterState:
    """The mutable belief about one device (picklable, for live checkpoints).

    ``particles`` ``(n, N_COLUMNS)`` and ``log_weights`` ``(n,)``; ``sigma2_db2``
    the σ² estimate; ``window`` the recent packets ``(t_s, heard, log_evidence)``
    of the evidence window; ``lineage`` (the genealogy, :class:`Lineage`) and
    ``pending`` (``(t_s, key, causal estimate)`` per packet within the lag)
    serve the fixed-lag smoother.
    """

    rng: np.random.Generator
    particles: FloatArray | None = None
    log_weights: FloatArray | None = None
    last_time_s: float | None = None
    reentry_time_s: float = -math.inf
    sigma2_db2: float = 4.0
    fit2_db2: float = 4.0
    sigma_count: int = 0
    last_rss_dbm: FloatArray | None = None
    last_rss_time_s: FloatArray | None = None
    diff2_db2: FloatArray | None = None
    diff_count: int = 0
    offset_prior_db: float = 0.0
    scan_index: int = 0
    window: deque = field(default_factory=deque)
    lineage: Lineage | None = None
    pending: deque = field(default_factory=deque)
    # issue 15: Σ_t log p(y_t | y_1:t-1) of the packets so far (nats, up to a
    # constant), for the offline offset selection (radiopose.filtering.offset)
    log_evidence: float = 0.0
    # offline offset selection: every packet ``(t_s, heard, key)`` and the causal
    # offset belief at it (``None`` unless the offline tracker records them)
    records: list | None = None
    beliefs_db: list | None = None
    # 3-D offline batch refinement (radiopose.filtering.refine3d): the smoothed
    # estimates emitted so far, ``(key, FilterEstimate)`` (``None`` otherwise)
    refine_smoothed: list | None = None
    # round 5 (offline reversed pass): the forward pass's smoothed estimates
    # ``(key, estimate)`` as emitted (``None`` unless the offline tracker keeps them)
    forward_kept: list | None = None
    forward_evidence: dict | None = None  # and each packet's log evidence by key
    backward: BackwardStore | None = None  # smoother: FilterConfig.smoother = "backward"
    # live re-solve of a track's start (FilterConfig.live_resolve_times_s;
    # radiopose.tracker.resolve.LiveResolve), None when off or not started
    resolve: Any = None


class ParticleFilter:
    """The filter for one device: :meth:`step` per packet, :meth:`flush` at the end.

    Parameters
    ----------
    model
        The device's arrays (:meth:`FilterModel.build`).
    config
        Filter parameters.
    lag_s
        Smoothing lag: ``None`` for a causal filter (each step returns its
        packet's estimate); a number for the fixed-lag smoother, whose
        estimates come out of :meth:`take_smoothed` once ``lag_s`` of later
        packets have been seen (and all of them after :meth:`flush`).
    """

    def __init__(self, model: FilterModel, config: FilterConfig, lag_s: float | None = None):
        self.model = model
        self.config = config
        self.lag_s = lag_s
        self._smoothed: list[tuple[object, FilterEstimate]] = []
        self._motion = np.array(
            [
                config.accel_noise_mps2,
                math.radians(config.angular_accel_noise_dps2),
                math.radians(config.tilt_noise_dps),
                config.max_speed_mps,
                math.radians(config.max_rate_dps),
            ]
        )
        self._work: _Work | None = None
        # smoother: the backward smoother replaces the genealogy when chosen (and lagged)
        self._backward = (
            BackwardSettings(
                config.smoother_position_bandwidth_m,
                config.smoother_azimuth_bandwidth_deg,
                config.smoother_reach,
                config.smoother_ghost_s,
            )
            if config.smoother == "backward" and lag_s is not None
            else None
        )

    def _log_eps(self, sigma_db: float) -> float:
        """``log ε′`` of the per-receiver outlier mixture (:func:`kernels.measurement_update`)."""
        eps = self.config.outlier_probability
        return math.log(
            eps * math.sqrt(2.0 * math.pi) * sigma_db / ((1.0 - eps) * self.config.outlier_range_db)
        )

    def new_state(self, seed: int = 0) -> FilterState:
        return FilterState(
            rng=np.random.default_rng(seed),
            sigma2_db2=self.config.sigma_prior_db**2,
            fit2_db2=self.config.sigma_prior_db**2,
        )

    # ------------------------------------------------------------------ proposals
    def _draw(
        self, st: FilterState, heard: HeardRss, m: int, offsets_db: list[float], n_packets: int
    ) -> tuple[FloatArray, FloatArray, float] | None:
        """``m`` particles drawn from the kernel's top-k of ``heard`` searched at each
        offset, with each candidate's best offset (shrunk to the prior); returns
        ``(particles, offsets, precision)`` or ``None`` if nothing is scorable."""
        cfg, mod = self.config, self.model
        tops = mod.search(
            [HeardRss(heard.receiver_index, heard.rss_dbm - off) for off in offsets_db],
            cfg.k,
            [round((off - st.offset_prior_db) / _HINT_BIN_DB) for off in offsets_db],
        )
        cand = np.unique(np.concatenate([top.candidate_idx for top in tops]))
        if cand.size == 0:
            return None
        T = mod.candidate_states(cand)
        e = heard.rss_dbm[None, :] - mod.expected(T, heard.receiver_index)
        # each candidate's offset profiled out (n_packets·h readings, with the prior)
        best, cost, prec = profile_offset_db(
            e,
            n_packets * heard.n_heard,
            math.sqrt(st.sigma2_db2),
            st.offset_prior_db,
            cfg.offset_prior_sd_db,
        )
        ok = np.isfinite(cost)
        if not ok.any():
            return None
        p = np.where(ok, np.exp(-(cost - cost[ok].min())), 0.0)
        pick = st.rng.choice(cand.size, size=m, p=p / p.sum())
        S = T[pick]
        mod.jitter_in_cell(S, st.rng)
        return S, best[pick], prec

    def _initialise(self, st: FilterState, heard: HeardRss) -> bool:
        cfg = self.config
        n = cfg.n_particles
        offsets = [st.offset_prior_db + o for o in cfg.initial_offsets_db]
        drawn = self._draw(st, heard, n, offsets, 1)
        if drawn is None:
            return False
        S, off, prec = drawn
        S[:, K.VX_MPS] = st.rng.normal(0.0, cfg.initial_speed_mps, n)
        S[:, K.VY_MPS] = st.rng.normal(0.0, cfg.initial_speed_mps, n)
        S[:, K.RATE_RAD_S] = np.deg2rad(st.rng.normal(0.0, cfg.initial_rate_dps, n))
        S[:, K.OFFSET_DB] = off
        S[:, K.OFFSET_VAR_DB2] = 1.0 / (prec + 1.0 / cfg.offset_prior_sd_db**2)
        st.particles = S
        st.log_weights = np.zeros(n)
        st.window.clear()
        st.lineage = None
        return True

    def _reenter(self, st: FilterState, t_s: float, w: FloatArray) -> None:
        """Replace a few particles by full-grid hypotheses weighted by their evidence."""
        cfg, mod = self.config, self.model
        S = st.particles
        assert S is not None and st.log_weights is not None
        n = S.shape[0]
        n_rx = mod.receivers_m.shape[0]
        per_rx: list[list[float]] = [[] for _ in range(n_rx)]
        for _, hd, _ in st.window:
            for r, v in zip(hd.receiver_index.tolist(), hd.rss_dbm.tolist(), strict=True):
                per_rx[r].append(v)
        heard_rx = np.array([r for r in range(n_rx) if per_rx[r]], dtype=np.int64)
        if heard_rx.size < cfg.min_acquisition_receivers:
            return
        # the window's median RSS per receiver: an outlying packet does not move it
        mean = HeardRss(heard_rx, np.array([float(np.median(per_rx[r])) for r in heard_rx]))
        b = float(np.sum(w * S[:, K.OFFSET_DB]))
        var_b = float(np.sum(w * (S[:, K.OFFSET_VAR_DB2] + (S[:, K.OFFSET_DB] - b) ** 2)))
        sd_b = math.sqrt(var_b)
        offsets = [b] if sd_b < 1.5 else [b - sd_b, b, b + sd_b]
        if abs(b - st.offset_prior_db) > 1.0:
            offsets.append(st.offset_prior_db)
        # the offset is a constant of the device: a wrong (pose, offset) lock is
        # left only if the true offset is searched, so scan the prior's range
        scan = cfg.offset_scan_db
        for _ in range(min(cfg.offset_scans_per_reentry, len(scan))):
            o = st.offset_prior_db + scan[st.scan_index % len(scan)]
            st.scan_index += 1
            if min(abs(o - v) for v in offsets) > 1.0:
                offsets.append(o)
        m = max(1, round(cfg.reentry_fraction * n))
        drawn = self._draw(st, mean, m, offsets, len(st.window))
        if drawn is None:
            return
        new, off, prec = drawn
        donors = st.rng.choice(n, size=m, p=w)
        new[:, K.VX_MPS] = S[donors, K.VX_MPS]
        new[:, K.VY_MPS] = S[donors, K.VY_MPS]
        new[:, K.RATE_RAD_S] = S[donors, K.RATE_RAD_S]
        # a donor's motion belongs to the filter's mode, which may be the wrong
        # one: some hypotheses start at rest (the median pose of a window of
        # several packets is a static one; with one packet it says nothing of rest)
        rest = (st.rng.random(m) < cfg.rest_fraction) & (len(st.window) > 1)
        new[rest, K.VX_MPS : K.VY_MPS + 1] = 0.0
        new[rest, K.RATE_RAD_S] = 0.0
        new[:, K.OFFSET_DB] = off
        new[:, K.OFFSET_VAR_DB2] = 1.0 / (prec + 1.0 / cfg.offset_prior_sd_db**2)
        ll, evidence = self._window_evidence(st, t_s, new, off)
        prior = (
            -0.5
            * ((off - st.offset_prior_db) ** 2 - (b - st.offset_prior_db) ** 2)
            / cfg.offset_prior_sd_db**2
        )
        slots = st.rng.choice(n, size=m, replace=False)
        lse = float(K.log_sum_exp(st.log_weights))
        donor_rows = S[donors]
        S[slots] = new
        st.log_weights[slots] = lse + math.log(cfg.jump_probability / m) + ll - evidence + prior
        if self.lag_s is not None:
            self._inject_lineage(st, t_s, new, slots, donors, donor_rows)
        if st.backward is not None:  # smoother: no ancestors in the previous set
            st.backward.reentered(slots)

    def _inject_lineage(
        self,
        st: FilterState,
        t_s: float,
        new: FloatArray,
        slots: np.ndarray,
        donors: np.ndarray,
        donor_rows: FloatArray,
    ) -> None:
        """Give re-entered particles a past for the smoother: within the evidence
        window their pose moved back along their velocity and turn rate; before
        it, the past of the particle whose motion they copied if they lie in its
        mode (within 1 m and 30°), else (a jump to another mode, which has no
        genealogy in the filter) their own pose moved back as within the window."""
        if st.lineage is None:
            return
        d = donor_rows
        dist = np.hypot(new[:, K.X_M] - d[:, K.X_M], new[:, K.Y_M] - d[:, K.Y_M])
        turn = np.abs((new[:, K.AZIMUTH_RAD] - d[:, K.AZIMUTH_RAD] + np.pi) % (2 * np.pi) - np.pi)
        same = (dist <= 1.0) & (turn <= math.radians(30.0))
        if not self.config.jump_own_past:
            same[:] = True
        st.lineage.inject(
            t_s, self.config.proposal_window_s, new, slots, donors, inherit=same,
            box_m=self.model.box_m,
        )  # fmt: skip

    def starts_track(self, st: FilterState, t_s: float) -> bool:
        """Whether a packet at ``t_s`` starts a new track: none yet, or a silence
        longer than ``reacquire_gap_s`` since the last packet."""
        return st.particles is None or (
            st.last_time_s is not None and t_s - st.last_time_s > self.config.reacquire_gap_s
        )

    def _advance_clock(self, st: FilterState, t_s: float, heard: HeardRss) -> float | None:
        """Start of :meth:`step`: the time since the last packet, seconds (0 for a
        new track), or ``None`` when no track could be started. A gap longer than
        ``reacquire_gap_s`` ends the track (flushed to the smoother, its power
        offset kept as the next prior) and acquires anew from this packet."""
        cfg = self.config
        new_track = self.starts_track(st, t_s)
        dt = 0.0
        if new_track:
            if st.particles is not None:
                w = _normalised(st.log_weights)
                st.offset_prior_db = float(np.sum(w * st.particles[:, K.OFFSET_DB]))
                self._flush_into(st, w)
                st.particles = None
            if heard.n_heard < cfg.min_acquisition_receivers or not self._initialise(st, heard):
                st.last_time_s = t_s
                return None
            st.reentry_time_s = t_s
        else:
            assert st.particles is not None and st.last_time_s is not None
            dt = max(t_s - st.last_time_s, 0.0)
        st.last_time_s = t_s
        return dt

    # ------------------------------------------------------------------ step
    def step(
        self, st: FilterState, t_s: float, heard: HeardRss, key: object = None
    ) -> FilterEstimate | None:
        """Process one packet at ``t_s``; return the causal estimate, or ``None``
        while no track could be started (too few receivers, nothing scorable).

        ``key`` identifies the packet for the smoother (:meth:`take_smoothed`).
        """
        cfg, mod = self.config, self.model
        dt_s = self._advance_clock(st, t_s, heard)
        if dt_s is None:
            return None
        dt = dt_s
        S, logw = st.particles, st.log_weights
        assert S is not None and logw is not None
        n, h = S.shape[0], heard.n_heard
        work = self._buffers(n)
        # the motion noise's seed (kernels.motion_noise_into): one draw per packet
        seed = int(st.rng.integers(_SEED_LIMIT)) if dt > 0 else 0
        pred = work.pred[: n * h].reshape(n, h)
        sigma = math.sqrt(st.sigma2_db2)
        update = K.packet_update_huber if cfg.likelihood == "huber" else K.packet_update
        lse0, lse1 = _packet_update(
            update,
            S, logw, work.noise, seed, dt, self._motion, mod.box_m, mod.tilt_box_rad,
            np.ascontiguousarray(heard.receiver_index, dtype=np.int64), *mod.lookup_arrays(),
            np.ascontiguousarray(heard.rss_dbm, dtype=np.float64), sigma,
            self._likelihood_parameter(sigma), pred, work.w,
        )  # fmt: skip
        return self._finish_step(st, t_s, heard, key, pred, lse0, lse1)

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
        """End of :meth:`step` after the packet's update (``lse0``/``lse1``: the
        log-sum of the weights before and after it): the evidence window, σ,
        re-entry, the estimate, the smoother's genealogy and resampling."""
        cfg = self.config
        S, logw = st.particles, st.log_weights
        assert S is not None and logw is not None
        n = S.shape[0]
        work = self._buffers(n)
        if not math.isfinite(lse1):  # every particle impossible: start again
            self._flush_into(st, np.full(S.shape[0], 1.0 / S.shape[0]))
            st.particles = None
            return self.step(st, t_s, heard, key)
        st.window.append((t_s, heard, lse1 - lse0))
        # the packet's evidence with the Gaussian's −h log σ, which the weights
        # leave out (σ differs between the offline offset passes)
        st.log_evidence += lse1 - lse0 - 0.5 * heard.n_heard * math.log(st.sigma2_db2)
        while st.window and st.window[0][0] <= t_s - cfg.proposal_window_s:
            st.window.popleft()
        w = work.w
        self._update_sigma(st, S, pred, heard, w, t_s)
        if t_s - st.reentry_time_s >= cfg.reentry_interval_s:
            self._reenter(st, t_s, w)
            st.reentry_time_s = t_s
            K.normalise_into(logw, w)
        moments = work.moments
        K.posterior_moments(S, w, work.rows, moments)
        est = _summary(moments, float(moments[9]), math.sqrt(st.sigma2_db2))
        if self._backward is not None:  # smoother: the backward smoother's store
            if st.backward is None:
                st.backward = BackwardStore(self._backward, n)
            st.backward.push(t_s, S, w)
            st.pending.append((t_s, key, est))
            self._emit_backward(st, final=False)
        elif self.lag_s is not None:
            if st.lineage is None:
                st.lineage = Lineage(n, extra_rows=self._lineage_extra_rows(n))
            st.lineage.push(t_s, work.rows)
            st.pending.append((t_s, key, est))
            self._emit(st, w, t_s - self.lag_s)
        if 1.0 / float(moments[10]) < 0.5 * n:
            K.resample_in_place(S, w, float(st.rng.uniform()), work.scratch, work.idx)
            logw[:] = 0.0
            if st.lineage is not None:
                st.lineage.remap(work.idx)
            if st.backward is not None:  # smoother
                st.backward.remap(work.idx)
        return est

    def _lineage_extra_rows(self, n: int) -> int:
        """Rows the smoother's genealogy keeps per packet for re-entered
        hypotheses: one re-entry's worth per re-entry while the packet is within
        the lag and the evidence window, with one to spare (so its ring need
        not widen, a copy of all of it, while tracking), at most ``2 n`` (the
        defaults need 0.65 n; a long lag or frequent re-entries widen the ring
        as they go instead of reserving it for every packet up front)."""
        cfg = self.config
        m = max(1, round(cfg.reentry_fraction * n))
        span_s = (self.lag_s or 0.0) + cfg.proposal_window_s
        return min(m * (math.ceil(span_s / cfg.reentry_interval_s) + 2), 2 * n)

    def _likelihood_parameter(self, sigma_db: float) -> float:
        """The scalar that :func:`kernels.measurement_update` takes after σ:
        ``log ε′`` of the per-receiver outlier mixture (``huber_c`` for
        ``likelihood = "huber"``, :func:`kernels.measurement_update_huber`)."""
        if self.config.likelihood == "huber":
            return self.config.huber_c
        return self._log_eps(sigma_db)

    def _window_evidence(
        self, st: FilterState, t_s: float, new: FloatArray, offset_db: FloatArray
    ) -> tuple[FloatArray, float]:
        """Each row of ``new`` (particles at ``t_s``, power offsets ``offset_db``)
        scored over the evidence window, moved back along its velocity and turn
        rate to each packet's time: ``(log-likelihood per row, the filter's own
        log evidence over the same packets)``, nats."""
        ll = np.zeros(new.shape[0])
        sigma = math.sqrt(st.sigma2_db2)
        back = np.empty_like(new)
        for tau, hd, _ in st.window:
            back[:] = new
            lag = t_s - tau
            back[:, K.X_M] -= new[:, K.VX_MPS] * lag
            back[:, K.Y_M] -= new[:, K.VY_MPS] * lag
            back[:, K.AZIMUTH_RAD] -= new[:, K.RATE_RAD_S] * lag
            pred = self.model.expected(back, hd.receiver_index)
            self._window_loglik(pred, hd.rss_dbm, offset_db, sigma, ll)
        return ll, sum(lz for _, _, lz in st.window)

    def _window_loglik(
        self, pred: FloatArray, rss: FloatArray, offset_db: FloatArray, sigma_db: float,
        out: FloatArray,
    ) -> None:  # fmt: skip
        """Add each row's log-likelihood of one packet at its fixed offset to ``out``
        (the configured likelihood)."""
        if self.config.likelihood == "huber":
            K.fixed_offset_loglik_huber(pred, rss, offset_db, sigma_db, self.config.huber_c, out)
        else:
            K.fixed_offset_loglik(pred, rss, offset_db, sigma_db, self._log_eps(sigma_db), out)

    def _buffers(self, n: int) -> _Work:
        """Work arrays for ``n`` particles (reused from packet to packet)."""
        if self._work is None or self._work.w.size != n:
            self._work = _Work.allocate(n, self.model.receivers_m.shape[0])
        return self._work

    def _update_sigma(
        self,
        st: FilterState,
        S: FloatArray,
        pred: FloatArray,
        heard: HeardRss,
        w: FloatArray,
        t_s: float,
    ) -> None:
        """σ² = the smaller of two estimates (never below the floor):

        * the fit: EWMA of the posterior-median mean squared residual (clipped
          at 2c σ) — includes any misfit of the filter's pose, so a wrong lock
          inflates it and would make itself cheap;
        * the packets alone: ``median(d²) / (2 · 0.4549)`` over the last
          ``difference_memory`` differences ``d`` of one receiver's readings at
          most ``difference_max_dt_s`` apart (``d ~ N(0, 2σ²)`` when the pose
          barely moves between them; 0.4549 is the median of χ²₁) — robust to
          outliers, and only ever lowers σ (where the device's RSS changes fast
          between packets it overestimates, and the fit is the smaller)."""
        cfg = self.config
        lim2 = (2.0 * cfg.huber_c) ** 2 * st.sigma2_db2
        u0 = float(st.rng.uniform())
        median = float(K.median_squared_residual(S, pred, heard.rss_dbm, w, lim2, u0))
        h = heard.n_heard
        st.sigma_count += h
        a = max(h / (st.sigma_count + 20.0), h / (cfg.sigma_memory_packets * 4.0))
        st.fit2_db2 = max((1.0 - a) * st.fit2_db2 + a * median, cfg.sigma_floor_db**2)
        sigma2 = st.fit2_db2
        if cfg.difference_memory > 0:
            if st.last_rss_dbm is None or st.last_rss_time_s is None or st.diff2_db2 is None:
                n_rx = self.model.receivers_m.shape[0]
                st.last_rss_dbm = np.zeros(n_rx)
                st.last_rss_time_s = np.full(n_rx, -math.inf)
                st.diff2_db2 = np.zeros(cfg.difference_memory)
            st.diff_count = int(
                K.push_differences(
                    np.ascontiguousarray(heard.receiver_index, dtype=np.int64),
                    np.ascontiguousarray(heard.rss_dbm, dtype=np.float64),
                    t_s, cfg.difference_max_dt_s, st.last_rss_dbm, st.last_rss_time_s,
                    st.diff2_db2, st.diff_count,
                )
            )  # fmt: skip
            if st.diff_count >= 40:
                used = min(st.diff_count, cfg.difference_memory)
                sigma2 = min(sigma2, float(K.median_of_first(st.diff2_db2, used)) / (2.0 * 0.4549))
        st.sigma2_db2 = max(sigma2, cfg.sigma_floor_db**2)

    # ------------------------------------------------------------------ smoothing
    def _emit(self, st: FilterState, w: FloatArray, upto_s: float | None) -> None:
        lin = st.lineage
        assert lin is not None and len(st.pending) == lin.size
        while st.pending and (upto_s is None or st.pending[0][0] <= upto_s):
            moments = self._buffers(lin.n).lineage_moments
            lin.pop_moments(w, moments)
            _, key, causal = st.pending.popleft()
            smooth = _summary(moments, causal.offset_db, causal.sigma_db)
            # the genealogy collapses (few distinct ancestors), so its spread
            # understates the uncertainty: report the filter's own at that packet
            self._smoothed.append(
                (
                    key,
                    replace(
                        smooth,
                        position_std_m=causal.position_std_m,
                        azimuth_std_deg=causal.azimuth_std_deg,
                    ),
                )
            )

    def _emit_backward(self, st: FilterState, final: bool) -> None:
        """Smoother: the backward smoother's estimates that are due (:meth:`BackwardStore.due`)."""
        if st.backward is not None and self.lag_s is not None:
            for key, causal, m in st.backward.due(st.pending, self.lag_s, final):
                self._smoothed.append((key, _summary(m, causal.offset_db, causal.sigma_db)))

    def _flush_into(self, st: FilterState, w: FloatArray) -> None:
        if self._backward is not None:  # smoother
            self._emit_backward(st, final=True)
            st.backward = None
        if self.lag_s is not None and st.lineage is not None:
            self._emit(st, w, None)
        st.lineage = None

    def flush(self, st: FilterState) -> None:
        """Emit every pending smoothed estimate (end of the data)."""
        if st.particles is not None and st.log_weights is not None:
            self._flush_into(st, _normalised(st.log_weights))

    def reseed(
        self,
        st: FilterState,
        t_s: float,
        pose: FilterEstimate,
        velocity_mps: tuple[float, float],
        rate_dps: float,
        share: float,
        prior: float,
    ) -> None:
        """Replace a ``share`` of the particles by draws around ``pose`` at
        ``t_s`` (a live re-solve's estimate, :mod:`radiopose.tracker.resolve`),
        weighted like re-entered hypotheses: each by its likelihood over the
        evidence window against the filter's own evidence there, times
        ``prior`` (the probability that the re-solve, not the filter, holds the
        device), so the packets decide between the two.

        The draws: position spread ``pose.position_std_m`` clipped to
        [0.05, 0.5] m, azimuth spread ``pose.azimuth_std_deg`` clipped to
        [2, 15]°, velocity ``velocity_mps`` (m/s) ± 0.2 m/s, turn rate
        ``rate_dps`` (°/s) ± 20 °/s, the power offset ``pose.offset_db`` ± 0.5 dB.
        In the smoother's genealogy each has its own pose moved back along its
        motion as its past (a re-entry that inherits nothing)."""
        S, logw = st.particles, st.log_weights
        if S is None or logw is None or not math.isfinite(pose.offset_db):
            return
        n, rng, box = S.shape[0], st.rng, self.model.box_m
        m = max(1, min(n, round(share * n)))
        sd_m = min(max(pose.position_std_m, 0.05), 0.5)
        sd_az = math.radians(min(max(pose.azimuth_std_deg, 2.0), 15.0))
        x, y, z = pose.position_m
        az, pitch, roll = (math.radians(a) for a in pose.orientation_deg)
        new = np.zeros((m, S.shape[1]))
        new[:, K.X_M] = np.clip(x + rng.normal(0.0, sd_m, m), box[0], box[1])
        new[:, K.Y_M] = np.clip(y + rng.normal(0.0, sd_m, m), box[2], box[3])
        new[:, K.Z_M] = z
        new[:, K.VX_MPS] = velocity_mps[0] + rng.normal(0.0, 0.2, m)
        new[:, K.VY_MPS] = velocity_mps[1] + rng.normal(0.0, 0.2, m)
        new[:, K.AZIMUTH_RAD] = (az + rng.normal(0.0, sd_az, m)) % (2.0 * math.pi)
        new[:, K.RATE_RAD_S] = math.radians(rate_dps) + rng.normal(0.0, math.radians(20.0), m)
        new[:, K.PITCH_RAD] = pitch
        new[:, K.ROLL_RAD] = roll
        off = pose.offset_db + rng.normal(0.0, 0.5, m)
        new[:, K.OFFSET_DB] = off
        new[:, K.OFFSET_VAR_DB2] = 0.25
        ll, evidence = self._window_evidence(st, t_s, new, off)
        slots = rng.choice(n, size=m, replace=False)
        lse = float(K.log_sum_exp(logw))
        # the filter's own particles keep 1 − prior of the mass, the new ones prior
        keep = np.ones(n, dtype=bool)
        keep[slots] = False
        if keep.any():
            logw[keep] += math.log(1.0 - prior) + lse - float(K.log_sum_exp(logw[keep]))
        S[slots] = new
        logw[slots] = lse + math.log(prior / m) + ll - evidence
        if st.lineage is not None:
            st.lineage.inject(
                t_s, self.config.proposal_window_s, new, slots, slots,
                inherit=np.zeros(m, dtype=bool), box_m=box,
            )  # fmt: skip
        if st.backward is not None:
            st.backward.reentered(slots)

    def take_smoothed(self) -> list[tuple[object, FilterEstimate]]:
        """The smoothed estimates emitted since the last call, as ``(key, estimate)``."""
        out, self._smoothed = self._smoothed, []
        return out


_SPLIT_MIN_PARTICLES = 1000
"""From this many particles a packet's particles are updated on two threads."""


def _packet_update(
    update: Any, S: FloatArray, logw: FloatArray, noise: FloatArray, seed: int, *args: Any
) -> tuple[float, float]:
    """``update`` (:func:`kernels.packet_update` or its Huber twin
    :func:`kernels.packet_update_huber`: same arguments, same numbers) with the
    motion noise's ``seed``, its particles split in two halves run on two
    threads when there are at least :data:`_SPLIT_MIN_PARTICLES` and a core is
    spare (:func:`~radiopose.likelihood.compiled.spare_core`): the kernel
    releases the GIL and touches only its own rows, whose noise depends only on
    ``seed`` and the row's index in the packet (``row0``,
    :func:`kernels.motion_noise_into`); the weights and ``lse`` are then taken
    over all of them."""
    n = S.shape[0]
    if n < _SPLIT_MIN_PARTICLES or not spare_core():
        return update(S, logw, noise, seed, 0, *args)
    *common, pred, w = args
    lse0 = float(K.log_sum_exp(logw))
    h = n // 2
    submit: Any = thread_pool(2).submit  # mypy miscounts numba's untyped dispatcher
    first = submit(update, S[:h], logw[:h], noise[:h], seed, 0, *common, pred[:h], w[:h])
    update(S[h:], logw[h:], noise[h:], seed, h, *common, pred[h:], w[h:])
    first.result()
    lse1 = float(K.log_sum_exp(logw))
    if math.isfinite(lse1):
        K.normalise_into(logw, w)
    return lse0, lse1


def _normalised(logw: FloatArray | None) -> FloatArray:
    assert logw is not None
    w = np.exp(logw - np.max(logw))
    return w / np.sum(w)


def _summary(moments: FloatArray, offset_db: float, sigma_db: float) -> FilterEstimate:
    """The estimate from weighted pose moments (:func:`kernels.posterior_moments`'
    first nine): mean position, circular mean azimuth and roll, mean pitch, and
    the spread."""
    x, y, z, c, s, pitch, cr, sr, var = moments[:9].tolist()
    r = min(math.hypot(c, s), 1.0)
    az_std = math.degrees(math.sqrt(-2.0 * math.log(r))) if r > 1e-12 else 180.0
    roll = math.degrees(math.atan2(sr, cr)) % 360.0 if (cr or sr) else 0.0
    return FilterEstimate(
        (x, y, z),
        (math.degrees(math.atan2(s, c)) % 360.0, math.degrees(pitch), roll),
        math.sqrt(max(var, 0.0)),
        az_std,
        offset_db,
        sigma_db,
    )


@dataclass(eq=False)
class _Work:
    """Work arrays of one packet's compiled calls, reused from packet to packet
    (their contents never outlive a :meth:`ParticleFilter.step`)."""

    noise: FloatArray  # (n, N_NOISE) the motion model's draws (kernels.motion_noise_into)
    pred: FloatArray  # (n · n_receivers,) expected RSS, viewed as (n, h)
    w: FloatArray  # (n,) normalised weights
    scratch: FloatArray  # (n, N_COLUMNS) resampling copy
    idx: np.ndarray  # (n,) ancestor indices of a resampling
    rows: FloatArray  # (n, POSE_ROW) the particles' pose rows
    moments: FloatArray  # (11,) posterior moments
    lineage_moments: FloatArray  # (9,) a smoothed packet's moments

    @classmethod
    def allocate(cls, n: int, n_receivers: int) -> _Work:
        return cls(
            np.empty((n, K.N_NOISE)),
            np.empty(n * max(n_receivers, 1)),
            np.empty(n),
            np.empty((n, K.N_COLUMNS)),
            np.empty(n, np.int64),
            np.empty((n, K.POSE_ROW)),
            np.empty(11),
            np.empty(9),
        )
