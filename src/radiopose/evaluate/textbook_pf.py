"""Issue 15's anchor: a plain textbook particle filter, told σ and the power.

Issue 15 states the bar ``filter`` must clear: "a plain textbook particle
filter on the same likelihood (constant-velocity motion, a few particles
re-drawn from the full-grid likelihood every 0.1 s, told σ)", quoted at
0.17 m / 1.4° (σ = 0.5 dB) and 0.67 m / 6.7° (σ = 3 dB) on scenarios of the
standard kind. This module is that filter, so the bar is measured on the same
seeds as ``filter`` (``scripts/live_lag_accuracy.py --variants textbook``;
docs/filter.md, "The issue's anchor").

It is an *evaluation anchor*, not a method a site would run: it is told the
readings' noise σ (:attr:`TextbookConfig.sigma_db`) and takes ``devices.csv``'s
transmit power as exact, two things ``filter`` must estimate. So it is not in
the built-in registry; a caller registers it for
one σ (:func:`registered_textbook`, a context manager) and runs it through
the registry like any method (``locate``, ``run_methods``, ``Tracker``).

The model, per packet at time ``t`` (``dt`` since the last packet):

* **state** per particle: position ``x, y`` (m), velocity ``vx, vy`` (m/s),
  azimuth (rad inside), turn rate (rad/s); height, pitch and roll stay at the
  drawn candidate's;
* **predict**: nearly-constant velocity and turn rate, white acceleration
  ``accel_noise_mps2`` m/s²/√Hz and angular acceleration
  ``angular_accel_noise_dps2`` °/s²/√Hz; positions clipped to the site's area;
* **weight**: ``Σ_r −(y_r − E_r)² / (2σ²)`` over the heard receivers, ``E``
  the survey map plus the pattern at the enrolled power
  (:meth:`radiopose.filtering.FilterModel.expected`, the filter's lookup);
* **re-draw** every ``reentry_interval_s``: ``reentry_fraction`` of the
  particles (chosen at random) replaced by draws from the compiled kernel's
  top-``k`` of the current packet, each candidate drawn with probability
  ``∝ exp(−h·MSE / (2σ²))`` and jittered within its grid cell, at rest, with
  the cloud's average weight (no evidence test, no jump prior);
* **resample** (systematic) when the effective sample size drops below half;
* **estimate**: the weighted mean position and circular-mean azimuth, with
  their weighted spread as ``position_std_m`` / ``azimuth_std_deg``.

The first packet heard by ``min_receivers`` or more starts the track (all
particles drawn from its top-``k``); a silence longer than ``reacquire_gap_s``
starts a new one.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.filtering import FilterModel
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names
from radiopose.likelihood import HeardRss
from radiopose.tracker.filter import filter_seed
from radiopose.tracker.protocol import Device, Evidence, Outcome, Step
from radiopose.tracker.reasons import SKIP_NO_TRACK, SKIP_OUT_OF_ORDER, SKIP_TOO_FEW_RECEIVERS
from radiopose.tracker.registry import METHODS, RESERVED_NAMES
from radiopose.units import FloatArray

NAME = "textbook"
"""The anchor's name in the registry inside :func:`registered_textbook`."""


@dataclass(frozen=True)
class TextbookConfig:
    """Settings of the textbook particle filter (module docstring).

    Attributes
    ----------
    sigma_db
        The readings' noise σ it is told, dB (the scenario's).
    n_particles
        Particles per device.
    k
        Candidates taken from the compiled kernel per draw.
    reentry_interval_s, reentry_fraction
        How often particles are re-drawn, seconds, and what share of them.
    accel_noise_mps2, angular_accel_noise_dps2
        White acceleration, m/s²/√Hz, and angular acceleration, °/s²/√Hz.
    min_receivers
        Receivers a packet needs to start a track.
    reacquire_gap_s
        A silence longer than this starts a new track, seconds.
    """

    sigma_db: float = 1.0
    n_particles: int = 2000
    k: int = 100
    reentry_interval_s: float = 0.1
    reentry_fraction: float = 0.05
    accel_noise_mps2: float = 1.0
    angular_accel_noise_dps2: float = 90.0
    min_receivers: int = 3
    reacquire_gap_s: float = 1.0

    def __post_init__(self) -> None:
        check_setting_types(self, "textbook filter")
        bounds = {
            "sigma_db": (0.01, 30.0),
            "n_particles": (10, 1_000_000),
            "k": (1, 1000),
            "reentry_interval_s": (0.001, 60.0),
            "reentry_fraction": (0.0, 1.0),
            "accel_noise_mps2": (0.0, 100.0),
            "angular_accel_noise_dps2": (0.0, 10_000.0),
            "min_receivers": (1, 1000),
            "reacquire_gap_s": (0.001, 3600.0),
        }
        for name, (lo, hi) in bounds.items():
            v = getattr(self, name)
            if not lo <= v <= hi:
                raise InputError(f"textbook filter setting {name} = {v!r} must be in [{lo}, {hi}]")


@dataclass
class TextbookState:
    """One device's particles (mutated in place by each step)."""

    rng: np.random.Generator
    particles: FloatArray | None = None
    log_weights: FloatArray | None = None
    last_time_s: float | None = None
    last_draw_s: float = -math.inf


@dataclass(frozen=True)
class TextbookPF:
    """The textbook particle filter as a registry method (module docstring)."""

    config: TextbookConfig = field(default_factory=TextbookConfig)
    name: str = NAME
    label: str = "textbook particle filter, told sigma and power (issue 15's anchor)"
    evidence: frozenset[Evidence] = frozenset({Evidence.DENSE})
    estimates_orientation: bool = True
    acquires: bool = False
    lagged: bool = False
    state_type: type = field(default=TextbookState)

    def prepare(self, device: Device) -> None:
        if device.scorer is None:  # pragma: no cover - the tracker builds one for DENSE
            raise InputError("textbook filter: the device has no scorer")
        device.engine = FilterModel.build(device.site, device.space, device.scorer)

    def new_state(self, device: Device) -> TextbookState:
        return TextbookState(np.random.default_rng(filter_seed(device.config.seed, device.key)))

    def step(
        self, device: Device, state: TextbookState, heard: HeardRss, t_s: float, packet_id: str
    ) -> Step:
        cfg, mod = self.config, device.engine
        if state.last_time_s is not None and t_s < state.last_time_s:
            return Step(state, Outcome(reason=SKIP_OUT_OF_ORDER))
        if heard.n_heard == 0:
            return Step(state, Outcome(reason=SKIP_TOO_FEW_RECEIVERS))
        gap = math.inf if state.last_time_s is None else t_s - state.last_time_s
        if state.particles is None or gap > cfg.reacquire_gap_s:
            state.particles = None
            state.last_time_s = t_s
            drawn = None
            if heard.n_heard >= cfg.min_receivers:
                drawn = _draw(mod, cfg, state.rng, heard, cfg.n_particles)
            if drawn is None:
                return Step(state, Outcome(reason=SKIP_NO_TRACK))
            state.particles = drawn
            state.log_weights = np.zeros(cfg.n_particles)
            state.last_draw_s = t_s
            return Step(state, _estimate(state))
        assert state.log_weights is not None and state.last_time_s is not None
        _predict(mod, cfg, state, t_s - state.last_time_s)
        state.last_time_s = t_s
        if t_s - state.last_draw_s >= cfg.reentry_interval_s:
            state.last_draw_s = t_s
            _redraw(mod, cfg, state, heard)
        S = state.particles
        r = (heard.rss_dbm[None, :] - mod.expected(S, heard.receiver_index)) / cfg.sigma_db
        lw = state.log_weights - 0.5 * np.einsum("ij,ij->i", r, r)
        lw -= lw.max()
        w = np.exp(lw)
        w /= w.sum()
        if 1.0 / float(w @ w) < 0.5 * w.size:
            u = (state.rng.random() + np.arange(w.size)) / w.size
            idx = np.minimum(np.searchsorted(np.cumsum(w), u), w.size - 1)
            state.particles = S[idx]
            lw = np.zeros(w.size)
        state.log_weights = lw
        return Step(state, _estimate(state))

    def flush(self, device: Device, state: TextbookState) -> tuple[()]:
        return ()


def _draw(
    mod: FilterModel, cfg: TextbookConfig, rng: np.random.Generator, heard: HeardRss, m: int
) -> FloatArray | None:
    """``m`` particles at rest drawn from the kernel's top-``k`` of ``heard`` at
    the enrolled power, ``∝ exp(−h·MSE / (2σ²))``, jittered within a cell."""
    top = mod.search([heard], cfg.k, [0])[0]
    if top.candidate_idx.size == 0:
        return None
    mse = np.asarray(top.mse_db2, dtype=float)
    p = np.exp(-(mse - mse.min()) * heard.n_heard / (2.0 * cfg.sigma_db**2))
    S = mod.candidate_states(top.candidate_idx[rng.choice(mse.size, size=m, p=p / p.sum())])
    mod.jitter_in_cell(S, rng)
    return S


def _predict(mod: FilterModel, cfg: TextbookConfig, st: TextbookState, dt_s: float) -> None:
    """Nearly-constant velocity and turn rate over ``dt_s`` seconds, in place."""
    S = st.particles
    assert S is not None
    if dt_s <= 0.0:
        return
    n = S.shape[0]
    dv = st.rng.normal(0.0, cfg.accel_noise_mps2 * math.sqrt(dt_s), (n, 2))
    dw = st.rng.normal(0.0, math.radians(cfg.angular_accel_noise_dps2) * math.sqrt(dt_s), n)
    S[:, K.X_M] += (S[:, K.VX_MPS] + 0.5 * dv[:, 0]) * dt_s
    S[:, K.Y_M] += (S[:, K.VY_MPS] + 0.5 * dv[:, 1]) * dt_s
    S[:, K.VX_MPS] += dv[:, 0]
    S[:, K.VY_MPS] += dv[:, 1]
    S[:, K.AZIMUTH_RAD] = (S[:, K.AZIMUTH_RAD] + (S[:, K.RATE_RAD_S] + 0.5 * dw) * dt_s) % (
        2.0 * math.pi
    )
    S[:, K.RATE_RAD_S] += dw
    x_lo, x_hi, y_lo, y_hi = mod.box_m
    np.clip(S[:, K.X_M], x_lo, x_hi, out=S[:, K.X_M])
    np.clip(S[:, K.Y_M], y_lo, y_hi, out=S[:, K.Y_M])


def _redraw(mod: FilterModel, cfg: TextbookConfig, st: TextbookState, heard: HeardRss) -> None:
    """Replace ``reentry_fraction`` of the particles by draws from ``heard``'s
    top-``k``, at the cloud's average weight."""
    S, lw = st.particles, st.log_weights
    assert S is not None and lw is not None
    n = S.shape[0]
    m = round(cfg.reentry_fraction * n)
    if m == 0 or heard.n_heard < cfg.min_receivers:
        return
    new = _draw(mod, cfg, st.rng, heard, m)
    if new is None:
        return
    slots = st.rng.choice(n, size=m, replace=False)
    top = float(lw.max())
    average = top + math.log(float(np.mean(np.exp(lw - top))))
    S[slots] = new
    lw[slots] = average


def _estimate(st: TextbookState) -> Outcome:
    """The weighted mean pose and its spread."""
    S, lw = st.particles, st.log_weights
    assert S is not None and lw is not None
    w = np.exp(lw - lw.max())
    w /= w.sum()
    x, y, z = (float(w @ S[:, c]) for c in (K.X_M, K.Y_M, K.Z_M))
    sin, cos = float(w @ np.sin(S[:, K.AZIMUTH_RAD])), float(w @ np.cos(S[:, K.AZIMUTH_RAD]))
    az = math.degrees(math.atan2(sin, cos)) % 360.0
    pitch = float(np.degrees(w @ S[:, K.PITCH_RAD]))
    roll = float(np.degrees(w @ S[:, K.ROLL_RAD]))
    var = float(w @ ((S[:, K.X_M] - x) ** 2 + (S[:, K.Y_M] - y) ** 2))
    resultant = min(math.hypot(sin, cos), 1.0)
    az_std = math.degrees(math.sqrt(-2.0 * math.log(resultant))) if resultant > 0 else 180.0
    return Outcome(
        (x, y, z), (az, pitch, roll), position_std_m=math.sqrt(var), azimuth_std_deg=az_std
    )


assert NAME in RESERVED_NAMES  # no other method may take the anchor's name


@contextmanager
def registered_textbook(sigma_db: float, **settings: object) -> Iterator[TextbookPF]:
    """The textbook filter told ``sigma_db`` (dB), registered under :data:`NAME`
    for the ``with`` block only (the registry is the process's: a method left
    registered would join every later listing of :data:`METHODS`, such as the
    demo's table); ``settings`` are other :class:`TextbookConfig` fields.

    Raises
    ------
    InputError
        A setting out of range (:class:`TextbookConfig`).
    """
    method = TextbookPF(TextbookConfig(sigma_db=sigma_db, **settings))  # type: ignore[arg-type]
    previous = METHODS.get(NAME)
    METHODS[NAME] = method  # (register_method refuses the reserved name to others)
    try:
        yield method
    finally:
        if previous is None:
            METHODS.pop(NAME, None)
        else:
            METHODS[NAME] = previous


__all__ = ["NAME", "TextbookConfig", "TextbookPF", "TextbookState", "registered_textbook"]
