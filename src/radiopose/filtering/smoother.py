"""The offline backward smoother: the filter's particle sets, smoothed backward.

An alternative to the fixed-lag genealogy (:mod:`radiopose.filtering.lineage`)
for the estimates that ``locate`` reads offline (``FilterConfig.smoother =
"backward"``; docs/filter.md, "Smoother").

Forward, every packet keeps the filter's whole particle set after its update
and re-entry: the pose and motion columns, the filtering weights, and each
particle's ancestor in the previous packet's set (its own index, the index
it copied at a resampling, or ``-1`` for a hypothesis that re-entered from
the full-grid likelihood at this packet).

Backward (:func:`backward_moments`), from the newest packet, the smoothed
weights are handed back packet by packet. This is marginal backward
smoothing (FFBSm)::

    w(t−1|T)_k = Σ_i w(t|T)_i · w(t−1)_k f(x_i(t) | x_k(t−1)) / Σ_l w(t−1)_l f(x_i(t) | x_l(t−1))

with the filter's own transition: a particle that moved from its ancestor
has a transition density to that ancestor alone, so its smoothed weight goes
to it whole (as in the genealogy). A re-entered hypothesis has no ancestor;
the kernel ``f`` (:func:`log_kernel`: the motion model's mean over ``dt``
with a Gaussian of width ``position_bandwidth_m`` and
``azimuth_bandwidth_deg``) finds it one among the previous set's particles —
of any weight, so a low-weight mode that the filter had not yet dropped
counts — when one lies within ``reach`` bandwidths. Where none does (a jump
to a mode the filter did not hold), the hypothesis travels back as a
*ghost* along its own velocity and turn rate (its pose within the evidence
window that made it win is supported by data) for at most ``ghost_s``,
looking at every earlier packet for particles within reach (e.g. hypotheses
of an earlier re-entry in the same mode, which lost to the filter's mode
then); a ghost still unmatched after ``ghost_s`` hands its weight to the
filter's particles by their filtering weights (the filter's own estimate
then), never a pose moved back by a guessed turn rate over the whole lag.

A packet's smoothed pose moments are its particles' under the smoothed
weights plus the ghosts' moved-back poses under theirs.

Block-wise fixed lag: a packet's estimate is emitted once ``lag_s`` of later
packets have been seen, by a backward pass from the newest packet over every
kept packet, run when the kept packets span ``2 · lag_s`` (each packet takes
part in at most two passes; the store holds at most ``2 · lag_s`` of
packets) and at the end of a track.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.units import FloatArray

N_STATE = 9
"""Kept columns per particle: the filter's first nine (x, y, z, vx, vy,
azimuth, turn rate, pitch, roll; :mod:`radiopose.filtering.kernels`)."""

N_MOMENTS = 9
"""The first nine :func:`~radiopose.filtering.kernels.posterior_moments`."""

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class BackwardSettings:
    """Parameters of the backward smoother (from :class:`~radiopose.filtering.FilterConfig`).

    Attributes
    ----------
    position_bandwidth_m, azimuth_bandwidth_deg
        Widths of the kernel that finds a re-entered hypothesis an ancestor
        (pitch and roll use the azimuth's).
    reach
        A particle is within reach of a hypothesis when its kernel distance
        is at most this many bandwidths.
    ghost_s
        How far back an unmatched hypothesis travels on its own motion, seconds.
    """

    position_bandwidth_m: float = 0.25
    azimuth_bandwidth_deg: float = 8.0
    reach: float = 3.0
    ghost_s: float = 0.5

    def kernel(self) -> FloatArray:
        """``[h_pos (m), h_az (rad), reach² (squared bandwidths)]`` for the kernels."""
        return np.array(
            [self.position_bandwidth_m, math.radians(self.azimuth_bandwidth_deg), self.reach**2]
        )


@numba.njit(cache=True)
def log_kernel(a, b, dt_s, h_pos, h_ang):  # pragma: no cover - compiled
    """``−d² / 2``: log kernel (peak 0) of the state row ``b`` at ``t + dt_s``
    given the row ``a`` at ``t`` (:data:`N_STATE` columns each), where::

        d² = |p_b − p_a − v_a dt|² / h_pos² + wrap(az_b − az_a − ω_a dt)² / h_ang²
             + ((pitch_b − pitch_a)² + wrap(roll_b − roll_a)²) / h_ang²

    (the motion model's mean over ``dt``: constant velocity and turn rate;
    positions metres, angles radians)."""
    dx = b[K.X_M] - a[K.X_M] - a[K.VX_MPS] * dt_s
    dy = b[K.Y_M] - a[K.Y_M] - a[K.VY_MPS] * dt_s
    dz = b[K.Z_M] - a[K.Z_M]
    da = K.wrap_pi(b[K.AZIMUTH_RAD] - a[K.AZIMUTH_RAD] - a[K.RATE_RAD_S] * dt_s)
    dp = b[K.PITCH_RAD] - a[K.PITCH_RAD]
    dr = K.wrap_pi(b[K.ROLL_RAD] - a[K.ROLL_RAD])
    d2 = (dx * dx + dy * dy + dz * dz) / (h_pos * h_pos)
    d2 += (da * da + dp * dp + dr * dr) / (h_ang * h_ang)
    return -0.5 * d2


@numba.njit(cache=True)
def _hand_back(g, Xp, logwp, dt, kern, lk, into, mass):  # pragma: no cover - compiled
    """Hand ``mass`` of the state row ``g`` back to the particles ``Xp`` (log
    filtering weights ``logwp``) within reach, in proportion to weight × kernel,
    adding to ``into``; returns False (nothing added) if none is within reach."""
    n = Xp.shape[0]
    lim = -0.5 * kern[2]
    lim_m2 = kern[2] * kern[0] * kern[0]  # position alone out of reach: skip the rest
    top = -np.inf
    found = False
    for k in range(n):
        dx = g[K.X_M] - Xp[k, K.X_M] - Xp[k, K.VX_MPS] * dt
        dy = g[K.Y_M] - Xp[k, K.Y_M] - Xp[k, K.VY_MPS] * dt
        if dx * dx + dy * dy > lim_m2 or logwp[k] == -np.inf:
            lk[k] = -np.inf
            continue
        v = log_kernel(Xp[k], g, dt, kern[0], kern[1])
        if v >= lim:
            found = True
            v += logwp[k]
            lk[k] = v
            top = max(top, v)
        else:
            lk[k] = -np.inf
    if not found:
        return False
    s = 0.0
    for k in range(n):
        if lk[k] > -np.inf:
            lk[k] = math.exp(lk[k] - top)
            s += lk[k]
    for k in range(n):
        if lk[k] > -np.inf:
            into[k] += mass * lk[k] / s
    return True


@numba.njit(cache=True, inline="always")
def _add_pose(m, x, wi):  # pragma: no cover - compiled
    """Add the pose of state row ``x`` with weight ``wi`` to the moments' sums ``m[:8]``."""
    m[0] += wi * x[K.X_M]
    m[1] += wi * x[K.Y_M]
    m[2] += wi * x[K.Z_M]
    m[3] += wi * math.cos(x[K.AZIMUTH_RAD])
    m[4] += wi * math.sin(x[K.AZIMUTH_RAD])
    m[5] += wi * x[K.PITCH_RAD]
    roll = x[K.ROLL_RAD]
    m[6] += wi * (1.0 if roll == 0.0 else math.cos(roll))
    m[7] += wi * (0.0 if roll == 0.0 else math.sin(roll))


@numba.njit(cache=True)
def _moments(X, w, G, gw, n_ghosts, m):  # pragma: no cover - compiled
    """Pose moments (:data:`N_MOMENTS`) of the particles ``X`` with weights ``w``
    and the first ``n_ghosts`` ghosts ``G`` with weights ``gw`` into ``m``."""
    m[:] = 0.0
    for i in range(X.shape[0]):
        if w[i] > 0.0:
            _add_pose(m, X[i], w[i])
    for g in range(n_ghosts):
        _add_pose(m, G[g], gw[g])
    for i in range(X.shape[0]):
        if w[i] > 0.0:
            dx = X[i, K.X_M] - m[0]
            dy = X[i, K.Y_M] - m[1]
            m[8] += w[i] * (dx * dx + dy * dy)
    for g in range(n_ghosts):
        dx = G[g, K.X_M] - m[0]
        dy = G[g, K.Y_M] - m[1]
        m[8] += gw[g] * (dx * dx + dy * dy)


@numba.njit(cache=True)
def backward_moments(X, logw, anc, times_s, kern, ghost_s, out):  # pragma: no cover - compiled
    """The smoothed pose moments of ``T`` kept packets (see the module docstring).

    ``X`` ``(T, n, N_STATE)`` the particle sets, oldest first; ``logw``
    ``(T, n)`` their normalised log filtering weights; ``anc`` ``(T, n)`` each
    particle's ancestor in the previous packet's set (``-1``: re-entered; the
    oldest packet's are not read); ``times_s`` ``(T,)``; ``kern`` =
    :meth:`BackwardSettings.kernel`; ``ghost_s`` seconds. Moments (as
    :func:`~radiopose.filtering.kernels.posterior_moments`' first nine) into
    ``out`` ``(T, N_MOMENTS)``; the newest packet's are the filter's own.
    """
    T, n = X.shape[0], X.shape[1]
    w = np.empty(n)
    wprev = np.empty(n)
    nxt = np.empty(n)
    lk = np.empty(n)
    cap = 4 * n
    G = np.empty((cap, N_STATE))
    gw = np.empty(cap)
    gage = np.empty(cap)
    G2 = np.empty((cap, N_STATE))
    gw2 = np.empty(cap)
    gage2 = np.empty(cap)
    n_g = 0
    for i in range(n):
        w[i] = math.exp(logw[T - 1, i])
    _moments(X[T - 1], w, G, gw, 0, out[T - 1])
    for t in range(T - 1, 0, -1):
        dt = times_s[t] - times_s[t - 1]
        nxt[:] = 0.0
        top = 0.0
        for i in range(n):
            top = max(top, w[i])
        for g in range(n_g):
            top = max(top, gw[g])
        tiny = 1e-7 * top
        for k in range(n):
            wprev[k] = math.exp(logw[t - 1, k])
        fallback = 0.0  # mass handed back by the filtering weights
        # the ghosts of earlier steps and the hypotheses re-entered at t, moved to t − 1
        n_new = 0
        for i in range(n):
            wi = w[i]
            if wi <= tiny:
                continue
            a = anc[t, i]
            if a >= 0:
                nxt[a] += wi
            elif n_g + n_new < cap:
                for c in range(N_STATE):
                    G[n_g + n_new, c] = X[t, i, c]
                gw[n_g + n_new] = wi
                gage[n_g + n_new] = 0.0
                n_new += 1
            else:  # no room: the filter's weights
                fallback += wi
        n_all = n_g + n_new
        n_keep = 0
        for g in range(n_all):
            mass = gw[g]
            if mass <= tiny:
                continue
            if _hand_back(G[g], X[t - 1], logw[t - 1], dt, kern, lk, nxt, mass):
                continue
            age = gage[g] + dt
            if age > ghost_s + 1e-12:  # unmatched for ghost_s: the filter's own weights
                fallback += mass
                continue
            # travel back one packet on its own motion
            for c in range(N_STATE):
                G2[n_keep, c] = G[g, c]
            G2[n_keep, K.X_M] -= G[g, K.VX_MPS] * dt
            G2[n_keep, K.Y_M] -= G[g, K.VY_MPS] * dt
            G2[n_keep, K.AZIMUTH_RAD] = (G[g, K.AZIMUTH_RAD] - G[g, K.RATE_RAD_S] * dt) % _TWO_PI
            gw2[n_keep] = mass
            gage2[n_keep] = age
            n_keep += 1
        total = 0.0
        for k in range(n):
            nxt[k] += fallback * wprev[k]
            total += nxt[k]
        for g in range(n_keep):
            total += gw2[g]
        for k in range(n):
            w[k] = nxt[k] / total
        for g in range(n_keep):
            for c in range(N_STATE):
                G[g, c] = G2[g, c]
            gw[g] = gw2[g] / total
            gage[g] = gage2[g]
        n_g = n_keep
        _moments(X[t - 1], w, G, gw, n_g, out[t - 1])


class BackwardStore:
    """The particle sets of the packets not yet emitted (oldest first).

    Preallocated arrays grown by doubling; :meth:`push` per packet,
    :meth:`reentered` and :meth:`remap` as the filter replaces and resamples
    particles, :meth:`smooth` for the backward pass, :meth:`drop` for the
    emitted packets.
    """

    def __init__(self, settings: BackwardSettings, n_particles: int, capacity: int = 256) -> None:
        self.settings = settings
        self.n = n_particles
        self.x = np.empty((capacity, n_particles, N_STATE))
        self.logw = np.empty((capacity, n_particles))
        self.anc = np.empty((capacity, n_particles), np.int32)
        self.times_s = np.empty(capacity)
        self.size = 0
        self._next_anc = np.full(n_particles, -1, np.int32)  # the next packet's ancestors

    def push(self, t_s: float, S: FloatArray, w: FloatArray) -> None:
        """Keep the particles ``S`` ``(n, ≥ N_STATE)`` with normalised weights ``w`` at ``t_s``."""
        if self.size == self.times_s.size:
            cap = 2 * self.size
            for name in ("x", "logw", "anc", "times_s"):
                old = getattr(self, name)
                new = np.empty((cap, *old.shape[1:]), old.dtype)
                new[: self.size] = old[: self.size]
                setattr(self, name, new)
        k = self.size
        self.x[k] = S[:, :N_STATE]
        with np.errstate(divide="ignore"):
            self.logw[k] = np.log(w)
        self.anc[k] = self._next_anc
        self._next_anc = np.arange(self.n, dtype=np.int32)
        self.times_s[k] = t_s
        self.size += 1

    def reentered(self, slots: np.ndarray) -> None:
        """The particles in ``slots`` were replaced by re-entered hypotheses."""
        self._next_anc[slots] = -1

    def remap(self, idx: np.ndarray) -> None:
        """The filter resampled: particle ``i`` now copies particle ``idx[i]``."""
        self._next_anc = self._next_anc[idx]

    def smooth(self) -> FloatArray:
        """Smoothed pose moments ``(size, N_MOMENTS)`` of every kept packet
        (:func:`backward_moments`)."""
        n = self.size
        out = np.empty((n, N_MOMENTS))
        s = self.settings
        backward_moments(
            self.x[:n], self.logw[:n], self.anc[:n], self.times_s[:n], s.kernel(), s.ghost_s, out
        )
        return out

    def due(self, pending: deque, lag_s: float, final: bool) -> list[tuple[Any, Any, FloatArray]]:
        """The packets whose smoothed estimate is due, as ``(key, causal estimate,
        moments)``, popped from ``pending`` (one ``(t_s, key, causal estimate)`` per
        kept packet, oldest first) and dropped from the store: once the kept
        packets span ``2 · lag_s``, those at least ``lag_s`` older than the
        newest; if ``final``, all of them (end of the track)."""
        if self.size == 0:
            return []
        assert len(pending) == self.size
        newest = float(self.times_s[self.size - 1])
        if not final and newest - self.oldest_time_s() < 2.0 * lag_s:
            return []
        moments = self.smooth()
        out: list[tuple[Any, Any, FloatArray]] = []
        while pending and (final or pending[0][0] <= newest - lag_s):
            _, key, causal = pending.popleft()
            out.append((key, causal, moments[len(out)]))
        self.drop(len(out))
        return out

    def drop(self, k: int) -> None:
        """Forget the oldest ``k`` packets."""
        rest = self.size - k
        for name in ("x", "logw", "anc", "times_s"):
            a = getattr(self, name)
            a[:rest] = a[k : self.size]
        self.size = rest

    def oldest_time_s(self) -> float:
        return float(self.times_s[0])
