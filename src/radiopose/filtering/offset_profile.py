"""Offline: the device's power offset from the data alone, over a coarse pose grid.

Beyond the paper (issue 15, unknown transmit power; docs/filter.md, "Accuracy
round 8"). The offline offset selection (:mod:`radiopose.filtering.offset`)
runs its tight passes at offsets that pass 1 happened to believe; when pass
1's beliefs stay near the enrolled power although the device sends 6 dB
louder, no tight pass runs near the device's offset and every candidate of
the arbiter is metres off (docs/filter.md, "Accuracy round 7", kind 1). This
module gives an offset that does not depend on what the filter searched:

1. the file's packets are cut into windows of ``window_s`` and each window's
   median RSS per receiver is taken (a reading per heard receiver standing for
   that receiver's ``n`` packets of the window);
2. every pose of a **coarse grid** (``position_step_m`` × ``azimuth_step_deg``
   over the map, the site's height and tilt) is scored against each window at
   each offset ``b`` of a fixed set (``offsets_db``):
   ``c(pose, b) = Σ_r w_r (y_r − E_r(pose) − b)² / 2``, ``w_r = n_r / v``,
   ``v = (π/2) σ² + σ_g²`` (the median's variance and the grid's
   coarseness ``σ_g``), nats;
3. per window and offset the poses are summed out
   (``log Σ_pose exp(−c) − log n_pose``, the pose marginal under a flat
   prior) or maximised over (``−min c``, the profile), and the windows are
   summed: ``ℓ(b)``, nats. Its argmax is the device's offset by the data
   alone (:class:`OffsetProfile`).

One window of four receivers fits a wrong (pose, offset) pair nearly as well
as the truth (three constraints for three pose unknowns and the offset), and
the windows are scored independently (no motion between them): measured on
tuning seeds 7300–7349 the argmax lies within 1.5 dB of the device's offset
in 4 runs of 5 at σ = 0.5 and 3 dB, and misses by a bias of the run (up to
7 dB) in the others. So it is used as one more *candidate* of the offset
selection (``FilterConfig.offline_offset_profile``), never as the decider:
the tight passes' evidence, which has the motion's continuity, decides.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.model import FilterModel
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray

Record = tuple[float, HeardRss, object]
"""One packet as the offline passes replay it: ``(t_s, heard, key)``."""


@dataclass(frozen=True, eq=False)
class CoarseTable:
    """The coarse pose grid of one device and its expected RSS (built once).

    Attributes
    ----------
    poses
        ``(n, 3)`` x (m), y (m), azimuth (deg) of each coarse pose.
    table_dbm
        ``(n, n_rx)`` expected RSS of each pose at every receiver, without the
        device's offset, dBm (NaN where the map has none).
    """

    poses: FloatArray
    table_dbm: FloatArray

    @classmethod
    def build(
        cls, model: FilterModel, position_step_m: float, azimuth_step_deg: float
    ) -> CoarseTable:
        """The grid over the model's box (both ends included, at most
        ``position_step_m`` apart) × azimuths every ``azimuth_step_deg`` from 0°,
        at the candidate space's height and first tilt.

        Raises
        ------
        ValueError
            A step not positive.
        """
        if not (position_step_m > 0 and azimuth_step_deg > 0):
            raise ValueError(
                f"CoarseTable: steps {position_step_m!r} m, {azimuth_step_deg!r}° must be positive"
            )
        x_lo, x_hi, y_lo, y_hi = (float(v) for v in model.box_m)
        nx = max(math.ceil((x_hi - x_lo) / position_step_m - 1e-9) + 1, 1)
        ny = max(math.ceil((y_hi - y_lo) / position_step_m - 1e-9) + 1, 1)
        xs = np.linspace(x_lo, x_hi, nx)
        ys = np.linspace(y_lo, y_hi, ny)
        n_az = max(round(360.0 / azimuth_step_deg), 1)
        az = np.arange(n_az) * (360.0 / n_az)
        gx, gy, ga = np.meshgrid(xs, ys, az, indexing="ij")
        poses = np.column_stack([gx.ravel(), gy.ravel(), ga.ravel()])
        space = model.space
        S = np.zeros((poses.shape[0], K.N_COLUMNS))
        S[:, K.X_M] = poses[:, 0]
        S[:, K.Y_M] = poses[:, 1]
        S[:, K.Z_M] = float(space.positions_m[0, 2])
        S[:, K.AZIMUTH_RAD] = np.deg2rad(poses[:, 2])
        S[:, K.PITCH_RAD] = float(model.tilt_box_rad[0])
        S[:, K.ROLL_RAD] = float(model.tilt_box_rad[2])
        all_rx = np.arange(model.receivers_m.shape[0])
        return cls(poses, np.ascontiguousarray(model.expected(S, all_rx)))


@dataclass(frozen=True)
class OffsetProfile:
    """The whole file's offset profile (module docstring).

    Attributes
    ----------
    offsets_db
        ``(m,)`` the offsets scored, dB.
    marginal
        ``(m,)`` ``ℓ(b)`` with the poses summed out per window, nats.
    profile
        ``(m,)`` ``ℓ(b)`` with the best pose per window, nats.
    n_windows
        Windows scored.
    """

    offsets_db: FloatArray
    marginal: FloatArray
    profile: FloatArray
    n_windows: int

    def best_db(self, kind: str = "marginal") -> float:
        """The offset of the largest ``ℓ`` (``kind`` ``"marginal"`` or
        ``"profile"``), dB; ``nan`` with no window."""
        ll = self.marginal if kind == "marginal" else self.profile
        if self.n_windows == 0 or not np.isfinite(ll).any():
            return math.nan
        return float(self.offsets_db[int(np.nanargmax(ll))])


_NEGLIGIBLE_NATS = 40.0
"""Poses whose cost exceeds the window's best by this much are left out of its
sum (each adds less than ``e^-40`` of the best pose's term): most poses, and
most of the kernel's time."""


@numba.njit(cache=True)
def window_offset_costs(table, heard, rss, weight, offsets, marg, prof):  # pragma: no cover
    """One window: for every offset ``b_j`` add ``log Σ_i exp(−c_ij)`` to
    ``marg[j]`` and ``−min_i c_ij`` to ``prof[j]``, ``c_ij = Σ_q w_q (rss_q −
    table[i, heard_q] − b_j)² / 2`` over the poses ``i`` (rows of ``table``)
    with no NaN at the heard receivers.

    Per pose ``c_ij = (A_i − 2 b_j B_i + b_j² W) / 2`` with ``A = Σ w e²``,
    ``B = Σ w e``, ``W = Σ w`` (``e`` the residuals without offset): the
    per-offset loops over the poses are branch-free (they vectorise)."""
    n = table.shape[0]
    m = offsets.shape[0]
    h = heard.shape[0]
    sw = 0.0
    for q in range(h):
        sw += weight[q]
    a = np.empty(n)
    b = np.empty(n)
    k = 0
    for i in range(n):
        s1 = 0.0
        s2 = 0.0
        good = True
        for q in range(h):
            e = rss[q] - table[i, heard[q]]
            if not math.isfinite(e):
                good = False
                break
            s1 += weight[q] * e
            s2 += weight[q] * e * e
        if good:
            a[k] = 0.5 * s2
            b[k] = s1
            k += 1
    if k == 0:
        return
    for j in range(m):
        bj = offsets[j]
        base = 0.5 * bj * bj * sw
        lo = np.inf
        for i in range(k):
            lo = min(lo, a[i] - bj * b[i])
        lo += base
        acc = 0.0
        for i in range(k):
            d = a[i] - bj * b[i] + base - lo
            # a pose further above the best than e^40 adds less than e^-40 of it
            acc += math.exp(-d) if d < _NEGLIGIBLE_NATS else 0.0
        marg[j] += math.log(acc) - lo
        prof[j] -= lo


def window_medians(records: Sequence[Record], window_s: float) -> list[tuple[HeardRss, FloatArray]]:
    """The packets cut into windows of ``window_s`` from the first packet's time:
    per window the median RSS of each receiver that heard any of its packets and
    that receiver's packet count."""
    return [(heard, n) for heard, n, _ in timed_windows(records, window_s)]


def timed_windows(
    records: Sequence[Record], window_s: float
) -> list[tuple[HeardRss, FloatArray, float]]:
    """:func:`window_medians`' windows, each with the mean time of the packets
    that gave it a reading (seconds)."""
    if not (window_s > 0):
        raise ValueError(f"window_medians: window_s {window_s!r} must be positive")
    out: list[tuple[HeardRss, FloatArray, float]] = []
    if not records:
        return out
    t0 = records[0][0]
    per: dict[int, list[float]] = {}
    times: list[float] = []
    current = 0

    def close() -> None:
        if per:
            rx = np.array(sorted(per), dtype=np.int64)
            med = np.array([float(np.median(per[r])) for r in rx])
            n = np.array([float(len(per[r])) for r in rx])
            out.append((HeardRss(rx, med), n, float(np.mean(times))))

    for t_s, heard, _ in records:
        w = math.floor((t_s - t0) / window_s)
        if w != current:
            close()
            per = {}
            times = []
            current = w
        if heard.n_heard:
            times.append(t_s)
        for r, v in zip(heard.receiver_index.tolist(), heard.rss_dbm.tolist(), strict=True):
            per.setdefault(r, []).append(v)
    close()
    return out


def offset_profile(
    table: CoarseTable,
    records: Sequence[Record],
    sigma_db: float,
    offsets_db: FloatArray,
    window_s: float = 0.1,
    grid_sigma_db: float = 1.0,
    min_receivers: int = 3,
    stride: int = 1,
) -> OffsetProfile:
    """The offset profile of the file's packets (module docstring).

    Parameters
    ----------
    table
        The coarse grid (:meth:`CoarseTable.build`).
    records
        Every packet ``(t_s, heard, key)`` in time order.
    sigma_db
        The readings' noise σ (the forward filter's estimate), dB.
    offsets_db
        The offsets to score, dB.
    window_s
        Window length, seconds.
    grid_sigma_db
        The grid's coarseness as noise added to each window reading, dB.
    min_receivers
        Windows heard by fewer receivers are skipped.
    stride
        Score every ``stride``-th window only (cost).
    """
    if not (math.isfinite(sigma_db) and sigma_db > 0):
        raise ValueError(f"offset_profile: sigma_db {sigma_db!r} must be positive")
    offs = np.ascontiguousarray(offsets_db, dtype=np.float64)
    marg = np.zeros(offs.size)
    prof = np.zeros(offs.size)
    n_windows = 0
    for heard, n in window_medians(records, window_s)[:: max(int(stride), 1)]:
        if heard.n_heard < min_receivers:
            continue
        v = (math.pi / 2) * sigma_db**2 / n + grid_sigma_db**2
        window_offset_costs(
            table.table_dbm,
            np.ascontiguousarray(heard.receiver_index, dtype=np.int64),
            np.ascontiguousarray(heard.rss_dbm, dtype=np.float64),
            1.0 / v,
            offs,
            marg,
            prof,
        )
        n_windows += 1
    return OffsetProfile(offs, marg, prof, n_windows)


PROFILE_POSITION_STEP_M = 1.0
"""The coarse grid's position step of :func:`data_offset_db`, metres."""
PROFILE_AZIMUTH_STEP_DEG = 15.0
"""The coarse grid's azimuth step of :func:`data_offset_db`, degrees."""
PROFILE_WINDOW_S = 0.1
"""The windows of :func:`data_offset_db`, seconds."""
PROFILE_GRID_SIGMA_DB = 0.5
"""The grid's coarseness σ_g of :func:`data_offset_db`, dB (measured: 0.5 dB
identified the offset most often on tuning seeds 7300–7349; docs/filter.md,
"Accuracy round 8")."""
PROFILE_OFFSETS_DB = np.arange(-12.0, 12.0 + 1e-9, 0.5)
"""The offsets :func:`data_offset_db` scores, dB (twice the wide prior's sd)."""


def data_offset_db(model: FilterModel, records: Sequence[Record], sigma_db: float) -> float:
    """The device's offset by the data alone: the argmax of the pose-marginal
    :func:`offset_profile` over the coarse grid and windows of the module's
    ``PROFILE_*`` settings, dB (``nan`` with no window of three receivers)."""
    table = CoarseTable.build(model, PROFILE_POSITION_STEP_M, PROFILE_AZIMUTH_STEP_DEG)
    prof = offset_profile(
        table, records, sigma_db, PROFILE_OFFSETS_DB, PROFILE_WINDOW_S, PROFILE_GRID_SIGMA_DB
    )
    return prof.best_db("marginal")


__all__ = [
    "PROFILE_OFFSETS_DB",
    "CoarseTable",
    "OffsetProfile",
    "data_offset_db",
    "offset_profile",
    "timed_windows",
    "window_medians",
]
