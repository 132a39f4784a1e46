"""The fixed-lag smoother's genealogy: preallocated ring buffers, compiled updates.

For each packet still within the lag the smoother keeps the particles' pose
rows at that packet (x, y, z, cos and sin of azimuth, pitch, cos and sin of
roll: :data:`~radiopose.filtering.kernels.POSE_ROW`) and, for every current
particle, the index of its ancestor's row there. A resampling replaces each
particle's ancestors by those of the particle it copies; a re-entered
hypothesis gets a past of its own (:meth:`Lineage.inject`). When a packet
leaves the lag, its smoothed pose is the current weights' mean over the rows
of the current particles' ancestors (:func:`~radiopose.filtering.kernels.lineage_moments`).

Storage is one ``(capacity, rows, POSE_ROW)`` float array and one
``(capacity, n)`` int32 array (double-buffered for resampling) used as a ring
(oldest packet at ``head``), grown by doubling when more packets are pending
than it holds; nothing is allocated per packet.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.units import FloatArray


@numba.njit(cache=True)
def _remap(anc, out, live, idx):  # pragma: no cover - compiled
    """``out[k] = anc[k][idx]`` for every live slot ``k``."""
    n = idx.shape[0]
    for k in live:
        for i in range(n):
            out[k, i] = anc[k, idx[i]]


@numba.njit(cache=True)
def _inject(  # pragma: no cover - compiled
    rows, n_rows, anc, live, lags_s, window_s, new, slots, donors, inherit, box, clip
):
    """Re-entered particles ``slots``: within the window, and before it where
    ``inherit`` is false, pose rows of ``new`` moved back along their velocity
    and turn rate by each packet's lag (positions clipped to ``box`` if
    ``clip``); before the window where ``inherit`` is true, the ancestors of
    ``donors`` (all read before any is written)."""
    m = slots.shape[0]
    tmp = np.empty(m, anc.dtype)
    for j in range(live.shape[0]):
        k = live[j]
        lag = lags_s[j]
        old = lag > window_s
        if old:
            for q in range(m):
                tmp[q] = anc[k, donors[q]]
        r = n_rows[k]
        for q in range(m):
            if old and inherit[q]:
                anc[k, slots[q]] = tmp[q]
                continue
            x = new[q, K.X_M] - new[q, K.VX_MPS] * lag
            y = new[q, K.Y_M] - new[q, K.VY_MPS] * lag
            if clip:
                x = min(max(x, box[0]), box[1])
                y = min(max(y, box[2]), box[3])
            az = new[q, K.AZIMUTH_RAD] - new[q, K.RATE_RAD_S] * lag
            roll = new[q, K.ROLL_RAD]
            rows[k, r, 0] = x
            rows[k, r, 1] = y
            rows[k, r, 2] = new[q, K.Z_M]
            rows[k, r, 3] = math.cos(az)
            rows[k, r, 4] = math.sin(az)
            rows[k, r, 5] = new[q, K.PITCH_RAD]
            rows[k, r, 6] = 1.0 if roll == 0.0 else math.cos(roll)
            rows[k, r, 7] = 0.0 if roll == 0.0 else math.sin(roll)
            anc[k, slots[q]] = r
            r += 1
        n_rows[k] = r


INITIAL_CAPACITY = 8
"""Packets a new :class:`Lineage` holds before its first doubling. The ring
grows to what the lag needs and no further: every slot of a ring is written
in turn, so a ring sized for batch ``locate``'s 1 s at 200 packets/s (256, the
default before session 29) cost a live device 37 MB of resident memory at any
packet rate, where a phone at 10 packets/s within a 0.25 s lag needs 4 slots
(docs/performance.md, "Many devices in the live pipeline")."""


class Lineage:
    """Pose rows and ancestor indices of the packets within the smoother's lag.

    Parameters
    ----------
    n_particles
        Particles of the filter.
    capacity
        Initial number of packets held (doubled when exceeded; the ring's order
        and contents do not depend on it).
    extra_rows
        Rows per packet beyond the particles' own, for re-entered hypotheses
        (:meth:`inject`; default ``n_particles // 8``). The ring widens when
        more are needed, at the cost of a copy of the whole ring, so a caller
        that knows how many hypotheses re-enter within the lag passes that.
    """

    def __init__(
        self, n_particles: int, capacity: int = INITIAL_CAPACITY, extra_rows: int | None = None
    ) -> None:
        self.n = n_particles
        extra = n_particles // 8 if extra_rows is None else max(int(extra_rows), 0)
        self.rows = np.empty((capacity, n_particles + extra, K.POSE_ROW))
        self.n_rows = np.zeros(capacity, np.int64)
        self.anc = np.empty((capacity, n_particles), np.int32)
        self._spare = np.empty_like(self.anc)  # the other half of the double buffer
        self.times_s = np.empty(capacity)
        self.head = 0
        self.size = 0
        self._identity = np.arange(n_particles, dtype=np.int32)

    @property
    def capacity(self) -> int:
        return int(self.times_s.size)

    def _live(self) -> np.ndarray:
        return (self.head + np.arange(self.size)) % self.capacity

    def _grow(self, capacity: int, n_rows: int) -> None:
        """Reallocate for ``capacity`` packets and ``n_rows`` rows each, oldest first."""
        live = self._live()
        rows = np.empty((capacity, n_rows, K.POSE_ROW))
        width = min(n_rows, self.rows.shape[1])
        rows[: self.size, :width] = self.rows[live, :width]
        n_r = np.zeros(capacity, np.int64)
        n_r[: self.size] = self.n_rows[live]
        anc = np.empty((capacity, self.n), np.int32)
        anc[: self.size] = self.anc[live]
        times = np.empty(capacity)
        times[: self.size] = self.times_s[live]
        self.rows, self.n_rows, self.anc, self.times_s = rows, n_r, anc, times
        self._spare = np.empty_like(anc)
        self.head = 0

    def push(self, t_s: float, pose_rows: FloatArray) -> None:
        """Record the particles' pose rows ``(n, POSE_ROW)``
        (:func:`~radiopose.filtering.kernels.posterior_moments`) at packet time
        ``t_s``, each particle its own ancestor."""
        if self.size == self.capacity:
            self._grow(2 * self.capacity, self.rows.shape[1])
        k = (self.head + self.size) % self.capacity
        self.rows[k, : self.n] = pose_rows
        self.n_rows[k] = self.n
        self.anc[k] = self._identity
        self.times_s[k] = t_s
        self.size += 1

    def remap(self, idx: np.ndarray) -> None:
        """After resampling with ancestor indices ``idx``: each particle takes the
        genealogy of the particle it copies."""
        if self.size:
            _remap(self.anc, self._spare, self._live(), idx)
            self.anc, self._spare = self._spare, self.anc

    def inject(
        self,
        t_s: float,
        window_s: float,
        new: FloatArray,
        slots: np.ndarray,
        donors: np.ndarray,
        inherit: np.ndarray | None = None,
        box_m: FloatArray | None = None,
    ) -> None:
        """Give re-entered particles (rows ``new`` now in ``slots``) a past: within
        ``window_s`` their pose moved back along their velocity and turn rate;
        before it, the past of the particle ``donors`` whose motion they copied
        — or, where ``inherit`` (bool per particle; default all) is false, their
        own pose moved back as within the window. ``box_m`` = ``[x_lo, x_hi,
        y_lo, y_hi]`` clips the moved-back positions (default: no clipping)."""
        if not self.size:
            return
        m = new.shape[0]
        live = self._live()
        lags = t_s - self.times_s[live]
        need = int(self.n_rows[live].max()) + m
        if need > self.rows.shape[1]:
            self._grow(self.capacity, max(need, self.rows.shape[1] + self.n // 4))
            live = self._live()
        _inject(
            self.rows, self.n_rows, self.anc, live, lags, window_s,
            np.ascontiguousarray(new), np.asarray(slots, np.int64), np.asarray(donors, np.int64),
            np.ones(m, np.bool_) if inherit is None else np.asarray(inherit, np.bool_),
            np.zeros(4) if box_m is None else np.asarray(box_m, np.float64), box_m is not None,
        )  # fmt: skip

    def oldest_time_s(self) -> float:
        return float(self.times_s[self.head])

    def pop_moments(self, w: FloatArray, m: FloatArray) -> None:
        """Drop the oldest packet; :func:`~radiopose.filtering.kernels.lineage_moments`
        of its ancestors' rows under the current weights ``w`` into ``m``."""
        k = self.head
        K.lineage_moments(self.rows[k], self.anc[k], w, m)
        self.head = (self.head + 1) % self.capacity
        self.size -= 1

    def __getstate__(self) -> dict:
        """Only the live packets, oldest first (a checkpoint need not carry the ring)."""
        live = self._live()
        width = int(self.n_rows[live].max()) if self.size else 0
        return {
            "n": self.n,  # the spare half of the double buffer is not kept
            "rows": self.rows[live, :width].copy(),
            "n_rows": self.n_rows[live].copy(),
            "anc": self.anc[live].copy(),
            "times_s": self.times_s[live].copy(),
        }

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["n"], max(INITIAL_CAPACITY, state["times_s"].size))  # type: ignore[misc]
        size = state["times_s"].size
        if state["rows"].shape[1] > self.rows.shape[1]:
            self._grow(self.capacity, state["rows"].shape[1])
        self.rows[:size, : state["rows"].shape[1]] = state["rows"]
        self.n_rows[:size] = state["n_rows"]
        self.anc[:size] = state["anc"]
        self.times_s[:size] = state["times_s"]
        self.size = size
