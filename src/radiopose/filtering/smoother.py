"""The offline backward smoother: forward filtering, marginal backward smoothing.

An alternative to the particles' genealogy (:mod:`radiopose.filtering.lineage`)
for the estimates that ``locate`` reads offline (``FilterConfig.smoother =
"backward"``; docs/filter.md, "Smoother").

Forward, every packet ``t`` keeps a subsample of ``M`` of the filter's
particles (:func:`subsample`: drawn from a half-and-half mixture of the
filtering weights and the uniform, so low-weight modes, re-entered hypotheses
among them, stay represented; each kept particle weighted by ``w / q``).
Backward, the smoothed weights of the particles at ``t`` are (FFBSm)::

    w(t|T)_i = Σ_j w(t+1|T)_j · w(t)_i k(x_j(t+1) | x_i(t)) / Σ_l w(t)_l k(x_j(t+1) | x_l(t))

(:func:`backward_weights`): each particle at ``t + 1`` hands its smoothed
mass back to the particles at ``t`` in proportion to their filtering weight
times the transition kernel ``k``. The kernel (:func:`log_transition`) is
the motion model's mean (constant velocity and turn rate over ``dt``) with a
diagonal Gaussian of width ``h`` per pose axis (position, azimuth, pitch and
roll): the motion model's own process noise over one packet (millimetres) is
far narrower than the spacing of ``M`` sampled particles, so ``h`` is a
kernel bandwidth set from each packet's particle spread (:func:`bandwidths`).
A floor ``exp(-floor_nats)`` under the Gaussian is the jump: a particle at
``t + 1`` far from every particle at ``t`` (a hypothesis that re-entered in
another mode) hands its mass back by the filtering weights alone. The past
of a jump is thereby the filter's own estimate then, or — where the jump's
mode was alive at ``t`` with a low weight — that mode's particles, never a
pose moved back along a guessed turn rate.

Block-wise fixed lag: a packet's estimate is emitted once ``lag_s`` of later
packets have been seen, by a backward pass from the newest packet over every
stored packet, run when the stored packets span ``2 · lag_s`` (so each packet
takes part in at most two passes and the store holds at most ``2 · lag_s`` of
packets) and at the end of a track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.units import FloatArray

N_STATE = 9
"""Stored columns per particle: the filter's first nine (x, y, z, vx, vy,
azimuth, turn rate, pitch, roll; :mod:`radiopose.filtering.kernels`)."""

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class BackwardSettings:
    """Parameters of the backward smoother (from :class:`~radiopose.filtering.FilterConfig`).

    Attributes
    ----------
    n_particles
        ``M``, particles kept per packet.
    bandwidth_scale
        Kernel bandwidth as a fraction of the packet's particle spread per axis.
    min_position_m, max_position_m
        Bounds of the position bandwidth, metres.
    min_angle_deg, max_angle_deg
        Bounds of the azimuth (and pitch, roll) bandwidth, degrees.
    floor_nats
        The jump floor of the kernel, ``exp(-floor_nats)`` under its peak.
    """

    n_particles: int = 200
    bandwidth_scale: float = 0.5
    min_position_m: float = 0.02
    max_position_m: float = 0.3
    min_angle_deg: float = 1.0
    max_angle_deg: float = 10.0
    floor_nats: float = 12.5


@numba.njit(cache=True)
def subsample(S, w, m, u0, out_x, out_logw):  # pragma: no cover - compiled
    """Keep ``m`` of the particles ``S`` ``(n, ≥ N_STATE)`` with normalised
    weights ``w``: systematic draws (offset ``u0`` in [0, 1)) from ``q = (w + 1/n) / 2``,
    each kept row's first :data:`N_STATE` columns into ``out_x`` ``(m, N_STATE)``
    and its normalised log weight ``log(w / q)`` into ``out_logw`` ``(m,)``.
    With ``n <= m`` every particle is kept (``out`` rows past ``n`` unused: the
    caller keeps ``min(n, m)``). Returns the number kept."""
    n = S.shape[0]
    if n <= m:
        for i in range(n):
            for c in range(N_STATE):
                out_x[i, c] = S[i, c]
            out_logw[i] = math.log(w[i]) if w[i] > 0.0 else -np.inf
        return n
    total = 0.0
    c_sum = np.empty(n)
    for i in range(n):
        total += 0.5 * w[i] + 0.5 / n
        c_sum[i] = total
    i = 0
    top = -np.inf
    for k in range(m):
        u = (u0 + k) / m * total
        while i < n - 1 and c_sum[i] < u:
            i += 1
        for c in range(N_STATE):
            out_x[k, c] = S[i, c]
        q = 0.5 * w[i] + 0.5 / n
        out_logw[k] = math.log(w[i] / q) if w[i] > 0.0 else -np.inf
        top = max(top, out_logw[k])
    s = 0.0
    for k in range(m):
        s += math.exp(out_logw[k] - top)
    lse = top + math.log(s)
    for k in range(m):
        out_logw[k] -= lse
    return m


@numba.njit(cache=True, inline="always")
def _wrap(a):  # pragma: no cover - compiled
    """``a`` wrapped to ``[-π, π)``."""
    return (a + math.pi) % _TWO_PI - math.pi


@numba.njit(cache=True)
def log_transition(a, b, dt_s, h):  # pragma: no cover - compiled
    """Log kernel (up to a constant) of the state row ``b`` at ``t + dt_s`` given
    the row ``a`` at ``t`` (:data:`N_STATE` columns each)::

        d² = |p_b − p_a − v_a dt|² / h_pos² + wrap(az_b − az_a − ω_a dt)² / h_az²
             + ((pitch_b − pitch_a)² + wrap(roll_b − roll_a)²) / h_tilt²
        log k = log(exp(−d² / 2) + exp(−floor))

    ``h = [h_pos (m), h_az (rad), h_tilt (rad), floor (nats)]``."""
    dx = b[K.X_M] - a[K.X_M] - a[K.VX_MPS] * dt_s
    dy = b[K.Y_M] - a[K.Y_M] - a[K.VY_MPS] * dt_s
    dz = b[K.Z_M] - a[K.Z_M]
    da = _wrap(b[K.AZIMUTH_RAD] - a[K.AZIMUTH_RAD] - a[K.RATE_RAD_S] * dt_s)
    dp = b[K.PITCH_RAD] - a[K.PITCH_RAD]
    dr = _wrap(b[K.ROLL_RAD] - a[K.ROLL_RAD])
    d2 = (dx * dx + dy * dy + dz * dz) / (h[0] * h[0]) + da * da / (h[1] * h[1])
    d2 += (dp * dp + dr * dr) / (h[2] * h[2])
    g = -0.5 * d2
    f = -h[3]
    top = max(g, f)
    return top + math.log(math.exp(g - top) + math.exp(f - top))


@numba.njit(cache=True)
def backward_weights(X, logw, counts, times_s, H, out):  # pragma: no cover - compiled
    """Marginal backward smoothing (FFBSm, see the module docstring).

    ``X`` ``(T, M, N_STATE)`` the kept particles of ``T`` packets (oldest
    first; packet ``t`` uses its first ``counts[t]`` rows), ``logw`` ``(T, M)``
    their normalised log filtering weights, ``times_s`` ``(T,)``, ``H``
    ``(T, 4)`` the kernel parameters from packet ``t`` to ``t + 1``
    (:func:`log_transition`). The smoothed weights go to ``out`` ``(T, M)``
    (each packet's sum to one; the newest packet's are its filtering weights).
    """
    T = X.shape[0]
    out[:] = 0.0
    last = T - 1
    for i in range(counts[last]):
        out[last, i] = math.exp(logw[last, i])
    lk = np.empty(X.shape[1])
    for t in range(T - 2, -1, -1):
        dt = times_s[t + 1] - times_s[t]
        n0 = counts[t]
        n1 = counts[t + 1]
        top_w = 0.0
        for j in range(n1):
            top_w = max(top_w, out[t + 1, j])
        for j in range(n1):
            wj = out[t + 1, j]
            if wj <= 1e-9 * top_w:
                continue
            top = -np.inf
            for i in range(n0):
                v = logw[t, i] + log_transition(X[t, i], X[t + 1, j], dt, H[t])
                lk[i] = v
                top = max(top, v)
            s = 0.0
            for i in range(n0):
                lk[i] = math.exp(lk[i] - top)
                s += lk[i]
            for i in range(n0):
                out[t, i] += wj * lk[i] / s
        total = 0.0
        for i in range(n0):
            total += out[t, i]
        for i in range(n0):
            out[t, i] /= total


@numba.njit(cache=True)
def pose_moments(X, w, n, m):  # pragma: no cover - compiled
    """The first nine :func:`~radiopose.filtering.kernels.posterior_moments` of the
    first ``n`` rows of ``X`` ``(·, N_STATE)`` under weights ``w`` into ``m``."""
    m[:] = 0.0
    for i in range(n):
        wi = w[i]
        m[0] += wi * X[i, K.X_M]
        m[1] += wi * X[i, K.Y_M]
        m[2] += wi * X[i, K.Z_M]
        m[3] += wi * math.cos(X[i, K.AZIMUTH_RAD])
        m[4] += wi * math.sin(X[i, K.AZIMUTH_RAD])
        m[5] += wi * X[i, K.PITCH_RAD]
        roll = X[i, K.ROLL_RAD]
        m[6] += wi * (1.0 if roll == 0.0 else math.cos(roll))
        m[7] += wi * (0.0 if roll == 0.0 else math.sin(roll))
    for i in range(n):
        dx = X[i, K.X_M] - m[0]
        dy = X[i, K.Y_M] - m[1]
        m[8] += w[i] * (dx * dx + dy * dy)


def bandwidths(x: FloatArray, logw: FloatArray, settings: BackwardSettings) -> FloatArray:
    """The kernel parameters ``[h_pos (m), h_az (rad), h_tilt (rad), floor]`` at one
    packet: ``bandwidth_scale`` times the kept particles' weighted spread (root
    mean square distance from the mean position per axis; circular standard
    deviation of azimuth), within the settings' bounds."""
    w = np.exp(logw)
    w = w / w.sum()
    s = settings
    pos = x[:, K.X_M : K.Z_M + 1]
    mean = w @ pos
    spread_m = math.sqrt(float(w @ np.sum((pos - mean) ** 2, axis=1)) / 2.0)
    r = float(abs(w @ np.exp(1j * x[:, K.AZIMUTH_RAD])))
    spread_rad = math.sqrt(-2.0 * math.log(r)) if r > 1e-12 else math.pi
    lo_a, hi_a = math.radians(s.min_angle_deg), math.radians(s.max_angle_deg)
    h_pos = min(max(s.bandwidth_scale * spread_m, s.min_position_m), s.max_position_m)
    h_az = min(max(s.bandwidth_scale * spread_rad, lo_a), hi_a)
    return np.array([h_pos, h_az, h_az, s.floor_nats])


class BackwardStore:
    """The kept particles of the packets not yet emitted (oldest first).

    Preallocated arrays grown by doubling; :meth:`push` per packet,
    :meth:`smooth` for the backward pass, :meth:`drop` for the emitted packets.
    """

    def __init__(self, settings: BackwardSettings, capacity: int = 512) -> None:
        self.settings = settings
        m = settings.n_particles
        self.x = np.empty((capacity, m, N_STATE))
        self.logw = np.full((capacity, m), -np.inf)
        self.counts = np.zeros(capacity, np.int64)
        self.times_s = np.empty(capacity)
        self.h = np.empty((capacity, 4))
        self.size = 0

    def push(self, t_s: float, S: FloatArray, w: FloatArray, u0: float) -> None:
        """Keep a subsample of the particles ``S`` with normalised weights ``w`` at ``t_s``."""
        if self.size == self.times_s.size:
            cap = 2 * self.size
            for name in ("x", "logw", "counts", "times_s", "h"):
                old = getattr(self, name)
                new = np.empty((cap, *old.shape[1:]), old.dtype)
                new[: self.size] = old[: self.size]
                setattr(self, name, new)
        k = self.size
        n = subsample(S, w, self.settings.n_particles, u0, self.x[k], self.logw[k])
        self.counts[k] = n
        self.times_s[k] = t_s
        self.h[k] = bandwidths(self.x[k, :n], self.logw[k, :n], self.settings)
        self.size += 1

    def smooth(self) -> FloatArray:
        """Smoothed pose moments ``(size, 9)`` of every stored packet
        (:func:`pose_moments` under :func:`backward_weights`)."""
        n = self.size
        ws = np.empty((n, self.x.shape[1]))
        backward_weights(self.x[:n], self.logw[:n], self.counts[:n], self.times_s[:n], self.h[:n], ws)
        out = np.empty((n, 9))
        for t in range(n):
            pose_moments(self.x[t], ws[t], int(self.counts[t]), out[t])
        return out

    def drop(self, k: int) -> None:
        """Forget the oldest ``k`` packets."""
        rest = self.size - k
        for name in ("x", "logw", "counts", "times_s", "h"):
            a = getattr(self, name)
            a[:rest] = a[k : self.size]
        self.size = rest

    def oldest_time_s(self) -> float:
        return float(self.times_s[0])
