"""Batch MAP refinement of a whole 3-D track (offline; docs/pose3d.md, "Batch refinement").

Beyond the paper. Given a device's packets, an initial track (one pose per
packet: the 3-D filter's smoothed track, or the truth for an oracle bound) and
an initial device-level power offset, :func:`refine_track` minimises

    Σ_packets Σ_heard ρ((rss − E(pose_i) − b) / σ)            (data)
  + Σ motion-prior residuals² + ((b − b₀) / s_b)²             (priors)

by a projected Levenberg–Marquardt on the sparse normal equations
(:func:`_levenberg_marquardt`; ``solver="trf"`` runs
:func:`scipy.optimize.least_squares` with ``trf``/``lsmr`` instead, which
converged far more slowly on these stiff problems: docs/pose3d.md):

* ``E`` is the 3-D filter's own expected RSS (:meth:`FilterModel3d.expected`:
  the height model's channel plus the full-sphere pattern in the body frame of
  ``R = Rz(az)·Rx(pitch)·Ry(roll)``); no second model. ``ρ`` is ``soft_l1``
  with scale ``robust_scale`` (in σ units) for outlier readings; the priors
  are plain squares.
* The motion prior is the filter's process model (:class:`MotionPrior`):
  position nearly constant velocity (a velocity change between consecutive
  intervals over ``q_acc·√((dt₁ + dt₂)/3)``, the white-acceleration model's
  spread for uniform packets), azimuth constant turn rate (likewise with the
  angular acceleration density), height, pitch and roll random walks (first
  differences over ``q·√dt``); angle differences wrapped.
* Variables: six per packet (x, y, z m; azimuth, pitch, roll rad) and the one
  offset ``b`` dB. Each packet's data residuals depend on its own pose and
  ``b``, the prior residuals on neighbours: the Jacobian's data block is
  taken by central differences of all packets at once (12 evaluations of the
  model per Jacobian), the priors' block is constant.
* Supports: x, y within the site's area, height within its height range, pitch
  within the filter's pitch support (kept off ±90° by 0.01°: hand-held pitch
  stays away from the gimbal), roll within the filter's roll arc (unbounded
  when the arc is the whole circle) — as bounds of the solve, so the result is
  inside the site's support without a clamp; azimuth and a full-circle roll
  are wrapped after the solve.

Offline only: the solve needs the whole track (the causal filter never calls
it). :func:`refine_smoothed` applies it to the 3-D filter's smoothed
estimates: per track, from the filter's track, from each offset-bank member's
own track and from a hybrid spliced from those refined tracks, keeping the
refined track of the lowest objective — with a constant-rate prior, the
polish of the lowest random-walk track unless another distinct mode's polish
is lower by more than a switch margin (docs/pose3d.md, "Mode choice,
2026-11-27").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from radiopose.errors import InputError
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.filtering.config import FilterConfig, FilterEstimate
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray

if TYPE_CHECKING:
    from radiopose.filtering.particle3d import FilterModel3d

_POSE = 6
_GIMBAL_MARGIN_RAD = math.radians(0.01)
_FD_STEP = 1e-3
"""Central-difference step of the data Jacobian: metres and radians (the map's
bilinear cells are 0.25–1 m, the pattern's 2°: a step well inside one cell)."""
_MIN_DT_S = 1e-3
"""Smallest interval used to scale a motion-prior residual, s (equal times)."""
SAME_TRACK_M = 0.1
SAME_TRACK_DEG = 2.0
"""Two refined tracks whose mean position difference is below ``SAME_TRACK_M``
metres and mean rotation angle between them below ``SAME_TRACK_DEG`` degrees are
one mode: only the lower of them is polished (:func:`refine_smoothed`)."""


def same_track(a: RefinedTrack, b: RefinedTrack) -> bool:
    """Whether two refined tracks of the same packets are one mode
    (:data:`SAME_TRACK_M`, :data:`SAME_TRACK_DEG`)."""
    d_m = float(np.linalg.norm(a.position_m - b.position_m, axis=1).mean())
    if d_m >= SAME_TRACK_M:
        return False
    d_deg = float(np.mean(orientation_error_deg(a.orientation_deg, b.orientation_deg)))
    return d_deg < SAME_TRACK_DEG


@dataclass(frozen=True)
class MotionPrior:
    """The 3-D filter's process noise as a batch prior.

    Attributes
    ----------
    accel_noise_mps2
        White-acceleration density of x and y, m/s²·√s (nearly constant velocity).
    angular_accel_noise_dps2
        Angular-acceleration density of azimuth, °/s²·√s (constant turn rate).
    height_noise_mps
        Random-walk density of height, m/√s.
    tilt_noise_dps
        Random-walk density of pitch and roll, °/√s.
    height_accel_noise_mps2
        When > 0, height follows a nearly-constant-rate model instead of the
        random walk: white vertical acceleration of this density, m/s²·√s
        (the refinement's own prior; docs/pose3d.md, "Refinement prior").
    tilt_accel_noise_dps2
        When > 0, pitch and roll follow nearly-constant-rate models instead of
        the random walks: white angular acceleration of this density, °/s²·√s.
    """

    accel_noise_mps2: float
    angular_accel_noise_dps2: float
    height_noise_mps: float
    tilt_noise_dps: float
    height_accel_noise_mps2: float = 0.0
    tilt_accel_noise_dps2: float = 0.0

    @classmethod
    def of_filter(
        cls,
        config: FilterConfig,
        height_noise_mps: float,
        tilt_noise_dps: float,
        height_accel_noise_mps2: float = 0.0,
        tilt_accel_noise_dps2: float = 0.0,
    ) -> MotionPrior:
        """The prior of a 3-D filter with ``config`` and its 3-D noise densities
        (with the optional constant-rate densities of height and tilt)."""
        return cls(
            config.accel_noise_mps2,
            config.angular_accel_noise_dps2,
            height_noise_mps,
            tilt_noise_dps,
            height_accel_noise_mps2,
            tilt_accel_noise_dps2,
        )


@dataclass(frozen=True)
class PoseBand:
    """A hand-held pose prior: height and pitch inside bands (the refinement's
    residuals, and the 3-D particle filter's weights with
    ``Pose3dConfig.hand_band_filter``).

    Inside ``height_m`` (m) and ``pitch_deg`` (°) the prior is flat; outside, each
    packet costs ``½ (dt / τ) (d / sd)²`` nats, ``d`` the distance to the band
    (metres or degrees), ``dt`` the packet's share of the track's time and
    ``τ = time_s``, so the prior counts once per ``τ`` of data, not once per
    packet (as :func:`heading_cost`). ``None`` leaves that axis free. A
    modelling assumption about a phone held in the hand (issue 18: 0.8–1.6 m,
    pitched 20–70°), not about radio: wrong for a phone on a table or in a
    pocket (docs/pose3d.md, "A hand-held band, 2026-11-28").
    """

    height_m: tuple[float, float] | None = None
    height_sd_m: float = 0.1
    pitch_deg: tuple[float, float] | None = None
    pitch_sd_deg: float = 10.0
    time_s: float = 1.0

    def __post_init__(self) -> None:
        for name, b in (("height_m", self.height_m), ("pitch_deg", self.pitch_deg)):
            if b is not None and not (
                len(b) == 2 and all(math.isfinite(v) for v in b) and b[0] <= b[1]
            ):
                raise InputError(f"hand-held band {name} = {b!r} must be [low, high], low <= high")
        for name in ("height_sd_m", "pitch_sd_deg", "time_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"hand-held band {name} = {v!r} must be a positive number")

    def axes(self) -> list[tuple[int, float, float, float]]:
        """``(pose column, low, high, sd)`` per banded axis, in the refinement's
        units (metres; radians)."""
        out = []
        if self.height_m is not None:
            out.append((2, float(self.height_m[0]), float(self.height_m[1]), self.height_sd_m))
        if self.pitch_deg is not None:
            lo, hi = (math.radians(v) for v in self.pitch_deg)
            out.append((4, lo, hi, math.radians(self.pitch_sd_deg)))
        return out

    def excess_sq(self, height_m: FloatArray, pitch_rad: FloatArray) -> FloatArray:
        """Per pose, ``Σ (d / sd)²`` over the banded axes (``d`` the distance
        outside the band; 0 inside): heights in metres, pitches in radians."""
        out = np.zeros(np.shape(height_m))
        for c, lo, hi, sd in self.axes():
            x = np.asarray(height_m if c == 2 else pitch_rad, dtype=float)
            out += ((x - np.clip(x, lo, hi)) / sd) ** 2
        return out

    def cost(self, t_s: FloatArray, position_m: FloatArray, orientation_deg: FloatArray) -> float:
        """This prior's cost of a whole track, nats (``t_s`` ascending seconds;
        ``(n, 3)`` positions, m, and orientations, °)."""
        w = _time_share(np.asarray(t_s, dtype=float)) / self.time_s
        pitch = np.deg2rad(np.asarray(orientation_deg, dtype=float)[:, 1])
        return 0.5 * float(np.sum(w * self.excess_sq(np.asarray(position_m)[:, 2], pitch)))


def _time_share(t: FloatArray) -> FloatArray:
    """Each packet's share of the track's time, s: half the intervals either side."""
    if t.size < 2:
        return np.zeros(t.size)
    edges = np.concatenate([[t[0]], 0.5 * (t[1:] + t[:-1]), [t[-1]]])
    return np.diff(edges)


@dataclass(frozen=True)
class RefinedTrack:
    """The result of :func:`refine_track`.

    Attributes
    ----------
    position_m
        ``(n, 3)`` refined positions, metres.
    orientation_deg
        ``(n, 3)`` refined azimuth [0, 360), pitch, roll [−180, 180), degrees.
    offset_db
        Refined device-level power offset, dB.
    sigma_db
        σ the data residuals were scaled by, dB.
    cost
        Final objective (½ Σ ρ), in σ² units.
    initial_cost
        Objective at the initial track.
    nfev
        Residual evaluations of the solve.
    """

    position_m: FloatArray
    orientation_deg: FloatArray
    offset_db: float
    sigma_db: float
    cost: float
    initial_cost: float
    nfev: int


@dataclass(frozen=True, eq=False)
class _Problem:
    """The fixed arrays of one solve."""

    n: int
    pkt: np.ndarray  # (m,) packet of each data residual
    rx: np.ndarray  # (m,) receiver of each data residual
    rss_dbm: FloatArray  # (m,)
    all_rx: np.ndarray  # receivers heard by any packet
    col_of_rx: np.ndarray  # site receiver index -> column of the expected block
    sigma_db: float


def _expected_track(model: FilterModel3d, X: FloatArray, prob: _Problem) -> FloatArray:
    """Expected RSS without offset of each data residual's packet and receiver."""
    S = np.zeros((prob.n, K.N_COLUMNS))
    S[:, K.X_M] = X[:, 0]
    S[:, K.Y_M] = X[:, 1]
    S[:, K.Z_M] = X[:, 2]
    S[:, K.AZIMUTH_RAD] = X[:, 3]
    S[:, K.PITCH_RAD] = X[:, 4]
    S[:, K.ROLL_RAD] = X[:, 5]
    e = model.expected(S, prob.all_rx)
    return e[prob.pkt, prob.col_of_rx[prob.rx]]


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2 * np.pi) - np.pi


class _Prior:
    """Motion-prior residuals: ``A · x`` (rows sparse) with wrapped angle differences."""

    def __init__(self, times_s: FloatArray, prior: MotionPrior, n_vars: int):
        n = times_s.size
        dt = np.maximum(np.diff(times_s), _MIN_DT_S)
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        self.angle_rows: list[tuple[int, str, int, int, float]] = []
        r0 = 0
        if prior.height_accel_noise_mps2 > 0:
            height: tuple[int, str, float] = (2, "acc", prior.height_accel_noise_mps2)
        else:
            height = (2, "rw", prior.height_noise_mps)
        if prior.tilt_accel_noise_dps2 > 0:
            tilt_kind, tilt_q = "acc", math.radians(prior.tilt_accel_noise_dps2)
        else:
            tilt_kind, tilt_q = "rw", math.radians(prior.tilt_noise_dps)
        blocks: list[tuple[int, str, float]] = [
            (0, "acc", prior.accel_noise_mps2),
            (1, "acc", prior.accel_noise_mps2),
            (3, "acc", math.radians(prior.angular_accel_noise_dps2)),
            height,
            (4, tilt_kind, tilt_q),
            (5, tilt_kind, tilt_q),
        ]
        for comp, kind, q in blocks:
            if kind == "acc" and n >= 3:
                d1, d2 = dt[:-1], dt[1:]
                w = 1.0 / (q * np.sqrt((d1 + d2) / 3.0))
                i = np.arange(1, n - 1)
                k = i.size
                rr = r0 + np.arange(k)
                # ((x_{i+1} − x_i)/d2 − (x_i − x_{i−1})/d1) · w
                rows += [rr, rr, rr]
                cols += [_POSE * (i + 1) + comp, _POSE * i + comp, _POSE * (i - 1) + comp]
                vals += [w / d2, -w / d2 - w / d1, w / d1]
            elif kind == "rw" and n >= 2:
                w = 1.0 / (q * np.sqrt(dt))
                i = np.arange(n - 1)
                k = i.size
                rr = r0 + np.arange(k)
                rows += [rr, rr]
                cols += [_POSE * (i + 1) + comp, _POSE * i + comp]
                vals += [w, -w]
            else:
                continue
            if comp >= 3:
                self.angle_rows.append((comp, kind, r0, k, q))
            r0 += k
        self.n_rows = r0
        self.dt = dt
        if r0:
            self.A = sp.csr_matrix(
                (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                shape=(r0, n_vars),
            )
        else:
            self.A = sp.csr_matrix((0, n_vars))

    def residuals(self, x: FloatArray) -> FloatArray:
        """``A · x`` with each angle's first differences wrapped to [−π, π)."""
        if not self.n_rows:
            return np.zeros(0)
        out = np.asarray(self.A @ x)
        n = self.dt.size + 1
        X = x[: n * _POSE].reshape(n, _POSE)
        for comp, kind, r0, k, q in self.angle_rows:
            d = np.diff(X[:, comp])
            dw = _wrap(d)
            if np.array_equal(d, dw):
                continue
            if kind == "rw":
                out[r0 : r0 + k] = dw / (q * np.sqrt(self.dt))
            else:
                d1, d2 = self.dt[:-1], self.dt[1:]
                w = 1.0 / (q * np.sqrt((d1 + d2) / 3.0))
                out[r0 : r0 + k] = (dw[1:] / d2 - dw[:-1] / d1) * w
        return out


def soft_l1_head(m: int, c2: float) -> Callable[[FloatArray], FloatArray]:
    """The refinements' robust loss in :func:`scipy.optimize.least_squares`'s
    form (``ρ, ρ′, ρ″`` of the squared residuals ``z``, shape ``(3, z.size)``):
    soft-L1 at scale² ``c2`` (σ² units) on the first ``m`` (the data), plain
    squares on the rest (the priors)."""

    def loss(z: FloatArray) -> FloatArray:
        out = np.empty((3, z.size))
        out[0], out[1], out[2] = z, 1.0, 0.0
        zd = z[:m] / c2
        s = np.sqrt(1.0 + zd)
        out[0, :m] = 2.0 * c2 * (s - 1.0)
        out[1, :m] = 1.0 / s
        out[2, :m] = -0.5 / (c2 * s**3)
        return out

    return loss


def checked_track(
    where: str,
    times_s: Sequence[float] | FloatArray,
    position_m: FloatArray,
    orientation_deg: FloatArray | None,
    heard: Sequence[HeardRss],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A track to refine as float arrays ``(times s (n,), positions m (n, 3),
    orientations ° (n, 3))``, checked: one row per packet, finite, times not
    going backwards; otherwise a one-line :class:`InputError` naming ``where``.
    ``orientation_deg = None``: a track of positions only (the orientations
    returned are zeros)."""
    t = np.asarray(times_s, dtype=float).reshape(-1)
    n = t.size
    if n == 0:
        raise InputError(f"{where}: the track is empty (no packet to refine)")
    pos = np.asarray(position_m, dtype=float)
    ori = np.zeros((n, 3)) if orientation_deg is None else np.asarray(orientation_deg, dtype=float)
    if pos.shape != (n, 3) or ori.shape != (n, 3) or len(heard) != n:
        raise InputError(
            f"{where}: {n} times, {len(heard)} packets, positions {pos.shape} and "
            f"orientations {ori.shape} (each must have one row per packet)"
        )
    if not (np.isfinite(t).all() and np.isfinite(pos).all() and np.isfinite(ori).all()):
        raise InputError(f"{where}: non-finite time or initial pose")
    if n > 1 and np.any(np.diff(t) < 0):
        raise InputError(f"{where}: packet times go backwards")
    return t, pos, ori


def refine_track(
    model: FilterModel3d,
    times_s: Sequence[float] | FloatArray,
    heard: Sequence[HeardRss],
    position_m: FloatArray,
    orientation_deg: FloatArray,
    offset_db: float,
    sigma_db: float,
    prior: MotionPrior | None,
    *,
    offset_prior_db: float = 0.0,
    offset_prior_sd_db: float = 6.0,
    robust_scale: float = 2.5,
    max_nfev: int = 50,
    solver: str = "lm",
    presmooth_s: float = 0.0,
    band: PoseBand | None = None,
) -> RefinedTrack:
    """Refine one device's track by batch MAP (see the module docstring).

    Parameters
    ----------
    model
        The 3-D filter's device model
        (:class:`~radiopose.filtering.particle3d.FilterModel3d`): its
        ``expected``, ``box_m``, ``z_box_m`` and ``tilt_rad``.
    times_s
        ``(n,)`` packet times, seconds, non-decreasing.
    heard
        ``n`` packets' readings (site receiver indices and RSS, dBm).
    position_m, orientation_deg
        ``(n, 3)`` initial track: x, y, z metres; azimuth, pitch, roll degrees.
    offset_db
        Initial device-level power offset, dB (the filter's).
    sigma_db
        Reading noise σ, dB (the filter's estimate); the data residuals' scale.
    prior
        The motion prior (:class:`MotionPrior`); ``None`` leaves it out (each
        packet then fits alone: for tests).
    offset_prior_db, offset_prior_sd_db
        The offset's prior ``N(b₀, s_b²)``, dB.
    robust_scale
        ``soft_l1`` scale of the data residuals, in σ units.
    max_nfev
        Bound on the solver's residual evaluations.
    solver
        ``"lm"`` (default): projected Levenberg–Marquardt on the sparse normal
        equations; ``"trf"``: :func:`scipy.optimize.least_squares` (``trf``,
        ``lsmr``), which converged far more slowly here (docs/pose3d.md).
    presmooth_s
        Before the solve, a centred moving average of the initial track over
        this many seconds (angles unwrapped): a particle smoother's track
        jitters from packet to packet, which the motion prior at 5 ms spacing
        charges heavily and the solver would spend its iterations removing.
    band
        Optional hand-held band prior (:class:`PoseBand`) on height and
        pitch: plain squared residuals beside the motion prior's, so the
        objective (``cost``) includes its cost.

    Raises
    ------
    InputError
        An empty track, arrays of different lengths, non-finite initial poses,
        offset or σ, or times going backwards.
    """
    t, pos, ori = checked_track("refine_track", times_s, position_m, orientation_deg, heard)
    n = t.size
    if not (math.isfinite(offset_db) and math.isfinite(sigma_db) and sigma_db > 0):
        raise InputError(
            f"refine_track: offset {offset_db!r} dB must be finite and σ {sigma_db!r} dB positive"
        )
    if solver not in ("lm", "trf") or not math.isfinite(presmooth_s) or presmooth_s < 0:
        raise InputError(f"refine_track: solver {solver!r} ('lm' or 'trf'), presmooth_s >= 0")
    if not (robust_scale > 0 and offset_prior_sd_db > 0 and max_nfev >= 1):
        raise InputError("refine_track: robust_scale, offset_prior_sd_db > 0, max_nfev >= 1")

    pkt = np.concatenate([np.full(h.n_heard, i, dtype=np.int64) for i, h in enumerate(heard)])
    rx = np.concatenate([np.asarray(h.receiver_index, dtype=np.int64) for h in heard])
    rss = np.concatenate([np.asarray(h.rss_dbm, dtype=float) for h in heard])
    if rx.size == 0:
        raise InputError("refine_track: no packet was heard by any receiver")
    all_rx = np.unique(rx)
    col = np.zeros(int(all_rx.max()) + 1, dtype=np.int64)
    col[all_rx] = np.arange(all_rx.size)
    prob = _Problem(n, pkt, rx, rss, all_rx, col, float(sigma_db))
    m = rx.size
    n_vars = _POSE * n + 1

    # bounds (the site's support) and the initial point inside them
    box = np.asarray(model.box_m, dtype=float)
    zb = np.asarray(model.z_box_m, dtype=float)
    p_lo, p_hi, r_c, r_w = (float(v) for v in model.tilt_rad)
    p_lo = max(p_lo, -0.5 * math.pi + _GIMBAL_MARGIN_RAD)
    p_hi = min(p_hi, 0.5 * math.pi - _GIMBAL_MARGIN_RAD)
    roll_bounded = 0.0 < r_w < math.pi
    lo = np.array([box[0], box[2], zb[0], -np.inf, p_lo, r_c - r_w if roll_bounded else -np.inf])
    hi = np.array([box[1], box[3], zb[1], np.inf, p_hi, r_c + r_w if roll_bounded else np.inf])
    frozen = hi - lo <= 0  # a fixed height, pitch or roll: the variable stays put
    X0 = np.empty((n, _POSE))
    X0[:, :3] = pos
    X0[:, 3] = np.unwrap(np.deg2rad(ori[:, 0]))
    X0[:, 4] = np.deg2rad(ori[:, 1])
    roll = np.deg2rad(ori[:, 2])
    X0[:, 5] = r_c + _wrap(roll - r_c) if roll_bounded else np.unwrap(roll)
    if presmooth_s > 0 and n > 2:
        w = round(presmooth_s / max(float(np.median(np.diff(t))), 1e-6))
        if w > 1:
            from scipy.ndimage import uniform_filter1d  # ≈ 0.07 s to import: only here

            X0 = uniform_filter1d(X0, size=w, axis=0, mode="nearest")
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    eps = 1e-9 * np.maximum(span, 1.0)
    X0 = np.clip(X0, lo + eps, hi - eps)
    X0[:, frozen] = lo[frozen]
    fd_lo = np.tile(np.where(frozen, -np.inf, lo), n)
    fd_hi = np.tile(np.where(frozen, np.inf, hi), n)
    free = np.tile(~frozen, n)
    x0 = np.concatenate([X0.ravel(), [float(offset_db)]])
    lb = np.concatenate([fd_lo, [-np.inf]])
    ub = np.concatenate([fd_hi, [np.inf]])

    pri = _Prior(t, prior, n_vars) if prior is not None else None
    # the band's rows: per banded (free) axis, √(share/τ)/sd · (x − clip(x, lo, hi))
    bands = [a for a in (band.axes() if band is not None else []) if not frozen[a[0]]]
    band_w = np.sqrt(_time_share(t) / band.time_s) if band is not None else np.zeros(0)
    sig = float(sigma_db)

    def band_residuals(X: FloatArray) -> list[FloatArray]:
        return [band_w / sd * (X[:, c] - np.clip(X[:, c], lo, hi)) for c, lo, hi, sd in bands]

    def band_jac(X: FloatArray) -> sp.csr_matrix:
        if not bands:
            return sp.csr_matrix((0, n_vars))
        rows, cols, vals = [], [], []
        for k, (c, lo, hi, sd) in enumerate(bands):
            out = np.flatnonzero((X[:, c] < lo) | (X[:, c] > hi))
            rows.append(k * n + out)
            cols.append(_POSE * out + c)
            vals.append(band_w[out] / sd)
        return sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(len(bands) * n, n_vars),
        )

    c2 = float(robust_scale) ** 2

    def split(x: FloatArray) -> tuple[FloatArray, float]:
        X = x[: _POSE * n].reshape(n, _POSE).copy()
        X[:, frozen] = lo[frozen]
        return X, float(x[-1])

    def fun(x: FloatArray) -> FloatArray:
        X, b = split(x)
        data = (rss - _expected_track(model, X, prob) - b) / sig
        parts = [data]
        if pri is not None:
            parts.append(pri.residuals(np.concatenate([X.ravel(), [b]])))
        parts += band_residuals(X)
        parts.append(np.array([(b - offset_prior_db) / offset_prior_sd_db]))
        return np.concatenate(parts)

    data_rows = np.repeat(np.arange(m), _POSE)
    data_cols = (_POSE * pkt[:, None] + np.arange(_POSE)[None, :]).ravel()
    prior_block = pri.A if pri is not None else sp.csr_matrix((0, n_vars))
    # frozen variables (a site with one height, pitch or roll) have no column
    prior_block = prior_block @ sp.diags(np.concatenate([free, [True]]).astype(float))
    last = sp.csr_matrix(([1.0 / offset_prior_sd_db], ([0], [n_vars - 1])), shape=(1, n_vars))

    def jac(x: FloatArray) -> sp.csr_matrix:
        X, _ = split(x)
        d = np.zeros((m, _POSE))
        for c in range(_POSE):
            if frozen[c]:
                continue
            Xp, Xm = X.copy(), X.copy()
            Xp[:, c] += _FD_STEP
            Xm[:, c] -= _FD_STEP
            # expected enters with a minus sign: d(residual)/dx = −dE/dx / σ
            d[:, c] = -(_expected_track(model, Xp, prob) - _expected_track(model, Xm, prob)) / (
                2 * _FD_STEP * sig
            )
        data = sp.csr_matrix((d.ravel(), (data_rows, data_cols)), shape=(m, n_vars))
        bcol = sp.csr_matrix(
            (np.full(m, -1.0 / sig), (np.arange(m), np.full(m, n_vars - 1))), shape=(m, n_vars)
        )
        return sp.vstack([data + bcol, prior_block, band_jac(X), last], format="csr")

    loss = soft_l1_head(m, c2)

    f0 = fun(x0)
    initial_cost = 0.5 * float(loss(f0**2)[0].sum())
    if solver == "trf":
        lb_free = np.where(np.concatenate([free, [True]]), lb, -np.inf)
        ub_free = np.where(np.concatenate([free, [True]]), ub, np.inf)
        # imported here: scipy.optimize pulls in scipy.spatial, which a plain
        # offline 2-D locate (the MAP arbiter uses the LM solver only) never needs
        from scipy.optimize import least_squares

        res = least_squares(
            fun, x0, jac=jac, bounds=(lb_free, ub_free), method="trf", loss=loss,
            tr_solver="lsmr", x_scale="jac", max_nfev=max_nfev, xtol=1e-6, ftol=1e-6,
        )  # fmt: skip
        x_opt, cost, nfev = res.x, float(res.cost), int(res.nfev)
    else:
        x_opt, cost, nfev = _levenberg_marquardt(fun, jac, loss, x0, lb, ub, max_nfev)
    X, b = split(x_opt)
    out_ori = np.column_stack(
        [
            np.rad2deg(X[:, 3]) % 360.0,
            np.rad2deg(X[:, 4]),
            (np.rad2deg(X[:, 5]) + 180.0) % 360.0 - 180.0,
        ]
    )
    return RefinedTrack(X[:, :3].copy(), out_ori, b, sig, cost, initial_cost, nfev)


def _levenberg_marquardt(
    fun: Callable[[FloatArray], FloatArray],
    jac: Callable[[FloatArray], sp.csr_matrix],
    loss: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lb: FloatArray,
    ub: FloatArray,
    max_nfev: int,
) -> tuple[FloatArray, float, int]:
    """Projected Levenberg–Marquardt with the robust loss by reweighting (IRLS):
    each step solves the sparse normal equations ``(JᵀWJ + λ diag(JᵀWJ)) δ = −JᵀWf``
    (banded plus the offset's row and column: a sparse LU), clipped into the
    bounds; ``λ`` shrinks after an accepted step and grows after a rejected one
    (:func:`damped_least_squares`). Returns ``(x, cost, residual evaluations)``."""
    import scipy.sparse.linalg as spla

    def linearise(x: FloatArray, f: FloatArray, w: FloatArray) -> Callable[[float], FloatArray]:
        J = jac(x)
        JW = J.T.multiply(w).tocsr()
        A = (JW @ J).tocsc()
        g = JW @ f
        dA = A.diagonal()
        dA = np.where(dA > 0, dA, 1.0)

        def step(lam: float) -> FloatArray:
            M = (A + sp.diags(lam * dA)).tocsc()
            return -np.asarray(spla.spsolve(M, g))

        return step

    return damped_least_squares(fun, linearise, loss, x0, lb, ub, max_nfev)


def damped_least_squares(
    fun: Callable[[FloatArray], FloatArray],
    linearise: Callable[[FloatArray, FloatArray, FloatArray], Callable[[float], FloatArray]],
    loss: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lb: FloatArray,
    ub: FloatArray,
    max_nfev: int,
) -> tuple[FloatArray, float, int]:
    """The Levenberg–Marquardt iteration of the batch refinements (3-D here, 2-D
    in :mod:`radiopose.filtering.refine2d`, sparse or banded): at ``x`` with
    residuals ``f`` and the robust loss's weights ``w``, ``linearise(x, f, w)``
    gives the damped step ``δ(λ)`` of the normal equations; a step clipped into
    ``[lb, ub]`` is accepted if it lowers the cost (``λ`` then ÷ 3, at least
    1e-9), else ``λ`` × 4 and retried (given up above 1e8); the iteration ends
    after ``max_nfev`` residual evaluations, a rejected linearisation or a
    relative cost decrease below 1e-7. Returns ``(x, cost, residual
    evaluations)``."""

    def cost_of(f: FloatArray) -> float:
        return 0.5 * float(loss(f * f)[0].sum())

    x = x0.copy()
    f = fun(x)
    cost = cost_of(f)
    nfev = 1
    lam = 1e-3
    while nfev < max_nfev:
        step_of = linearise(x, f, loss(f * f)[1])
        improved = False
        while nfev < max_nfev:
            xn = np.clip(x + step_of(lam), lb, ub)
            fn = fun(xn)
            nfev += 1
            cn = cost_of(fn)
            if cn < cost:
                rel = (cost - cn) / max(cost, 1e-12)
                x, f, cost = xn, fn, cn
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
            if lam > 1e8:
                break
        if not improved or rel < 1e-7:
            break
    return x, cost, nfev


def packet_costs(
    model: FilterModel3d,
    heard: Sequence[HeardRss],
    position_m: FloatArray,
    orientation_deg: FloatArray,
    offset_db: float,
    sigma_db: float,
    robust_scale: float = 2.5,
) -> FloatArray:
    """``(n,)`` each packet's data term of :func:`refine_track`'s objective
    (½ Σ ρ over its heard receivers, σ² units) at the given track and offset."""
    n = len(heard)
    pkt = np.concatenate([np.full(h.n_heard, i, dtype=np.int64) for i, h in enumerate(heard)])
    rx = np.concatenate([np.asarray(h.receiver_index, dtype=np.int64) for h in heard])
    rss = np.concatenate([np.asarray(h.rss_dbm, dtype=float) for h in heard])
    all_rx = np.unique(rx)
    col = np.zeros(int(all_rx.max()) + 1, dtype=np.int64)
    col[all_rx] = np.arange(all_rx.size)
    prob = _Problem(n, pkt, rx, rss, all_rx, col, float(sigma_db))
    X = np.column_stack([np.asarray(position_m, float), np.deg2rad(orientation_deg)])
    z = ((rss - _expected_track(model, X, prob) - offset_db) / sigma_db) ** 2
    c2 = robust_scale**2
    rho = c2 * (np.sqrt(1.0 + z / c2) - 1.0)  # ½ · 2c²(√(1 + z/c²) − 1)
    return np.bincount(pkt, weights=rho, minlength=n).astype(np.float64)


def heading_cost(
    t_s: FloatArray,
    position_m: FloatArray,
    orientation_deg: FloatArray,
    sd_deg: float,
    time_s: float,
    speed_mps: float,
    span_s: float = 0.5,
) -> float:
    """The hand-held heading prior's cost of a whole track, nats.

    The prior of the 3-D filter (:func:`radiopose.filtering.kernels3d.heading_prior`,
    ``Pose3dConfig.heading_prior_deg``) integrated over the track: per packet
    ``(dt / τ) κ g(v) (1 − cos Δ)``, ``Δ`` the angle between the azimuth and
    the walking direction (``atan2(vy, vx) − 90°``: the phone's top ahead),
    ``κ = 1 / sd²`` (radians), ``g(v) = v² / (v² + v0²)``, ``τ = time_s``,
    ``v0 = speed_mps``, ``dt`` the packet's share of the track's time. The
    velocity is the track's own: the positions ``span_s / 2`` seconds either
    side (interpolated; clipped at the ends) differenced, so a refined
    track's per-packet jitter does not turn the walking direction.
    ``t_s`` ascending seconds; ``position_m`` ``(n, 3)``; ``orientation_deg``
    ``(n, 3)`` (only the azimuth is read)."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 2 or not sd_deg > 0:
        return 0.0
    p = np.asarray(position_m, dtype=float)
    lo = np.maximum(t - 0.5 * span_s, t[0])
    hi = np.minimum(t + 0.5 * span_s, t[-1])
    dt_span = np.maximum(hi - lo, 1e-9)
    vx = (np.interp(hi, t, p[:, 0]) - np.interp(lo, t, p[:, 0])) / dt_span
    vy = (np.interp(hi, t, p[:, 1]) - np.interp(lo, t, p[:, 1])) / dt_span
    v2 = vx * vx + vy * vy
    walk = np.arctan2(vy, vx) - 0.5 * math.pi
    delta = np.deg2rad(np.asarray(orientation_deg, dtype=float)[:, 0]) - walk
    share = _time_share(t)
    kappa = 1.0 / math.radians(sd_deg) ** 2
    g = v2 / (v2 + speed_mps * speed_mps)
    return float(np.sum(share / time_s * kappa * g * (1.0 - np.cos(delta))))


def track_sigma_db(estimates: Sequence[FilterEstimate], config: FilterConfig) -> float:
    """The σ (dB) a track of filter estimates is refined and scored at: the last
    finite online σ estimate (``config.sigma_prior_db`` without one), floored at
    ``config.sigma_floor_db``."""
    sig = [e.sigma_db for e in estimates if math.isfinite(e.sigma_db)]
    return max(sig[-1] if sig else config.sigma_prior_db, config.sigma_floor_db)


def segment_misfit_ratio(
    model: FilterModel3d,
    records: Sequence[tuple[float, HeardRss, object]],
    estimates: Sequence[tuple[object, FilterEstimate]],
    config: FilterConfig,
    segment_s: float = 0.5,
) -> float:
    """A σ-free misfit of refined estimates: the data term per reading
    (:func:`packet_costs` at each estimate's pose and offset, σ
    :func:`track_sigma_db`) in segments of
    ``segment_s`` seconds of the packets' time, the largest segment's over the
    median segment's (≈ 1 for a track that fits everywhere alike; a track in
    a wrong mode over part of its length fits worse there). 0 without a heard,
    estimated packet. ``records`` as :func:`refine_smoothed`'s."""
    got = dict(estimates)
    rows = [r for r in records if r[2] in got and r[1].n_heard > 0]
    if not rows:
        return 0.0
    ests = [got[r[2]] for r in rows]
    sigma = track_sigma_db(ests, config)
    heard = [r[1] for r in rows]
    pos = np.array([e.position_m for e in ests], dtype=float)
    ori = np.array([e.orientation_deg for e in ests], dtype=float)
    off = np.array([e.offset_db for e in ests], dtype=float)
    off = np.where(np.isfinite(off), off, 0.0)
    cost = np.zeros(len(rows))
    for b in np.unique(off):  # one offset per refined track
        idx = np.flatnonzero(off == b)
        cost[idx] = packet_costs(model, [heard[i] for i in idx], pos[idx], ori[idx], b, sigma)
    t = np.array([r[0] for r in rows])
    seg = np.floor((t - t[0]) / segment_s).astype(np.int64)
    reads = np.bincount(seg, weights=[h.n_heard for h in heard])
    per = np.bincount(seg, weights=cost)[reads > 0] / reads[reads > 0]
    return float(per.max() / np.median(per))


CoarseStart = Callable[
    [FloatArray, Sequence[HeardRss], float], Sequence[tuple[FloatArray, FloatArray, float]]
]
"""Starts from a track's packets: ``(times s, heard, σ dB) → [(positions m,
orientations °, offset dB), …]``, poses per packet (:func:`refine_smoothed`)."""


def _same_start(
    a: tuple[FloatArray, FloatArray, float], b: tuple[FloatArray, FloatArray, float]
) -> bool:
    """Whether two initial tracks ``(positions m, orientations °, offset dB)`` are equal."""
    return bool(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2])


def refine_smoothed(
    model: FilterModel3d,
    records: Sequence[tuple[float, HeardRss, object]],
    smoothed: Sequence[tuple[object, FilterEstimate]],
    config: FilterConfig,
    height_noise_mps: float,
    tilt_noise_dps: float,
    max_nfev: int,
    alternatives: Sequence[Sequence[tuple[object, FilterEstimate]]] = (),
    hybrid_segment_s: float = 0.0,
    height_accel_noise_mps2: float = 0.0,
    tilt_accel_noise_dps2: float = 0.0,
    polish_starts: int = 1,
    polish_margin: float = math.inf,
    polish_switch: float = 0.0,
    anneal_sigma: Sequence[float] = (),
    anneal_keep_direct: bool = False,
    coarse_start: CoarseStart | None = None,
    heading: tuple[float, float, float] | None = None,
    memo: dict[tuple[object, ...], object] | None = None,
    orientation_path: bool = False,
    band: PoseBand | None = None,
) -> list[tuple[object, FilterEstimate]]:
    """The 3-D filter's smoothed estimates refined by :func:`refine_track`.

    ``records`` are the filter's packets ``(t_s, heard, key)`` in order,
    ``smoothed`` its estimates by key. Each track (packets separated by more
    than ``config.reacquire_gap_s``, the filter's own track boundary) is
    refined alone, initialised at its smoothed poses and the median of their
    offsets, σ the last σ estimate (the filter's online σ, floored at
    ``config.sigma_floor_db``). Each of ``alternatives`` (other initial
    tracks by key: the offset bank's members' own smoothed tracks) covering
    the whole track is refined too, with the same σ, and the refined track of
    the lowest objective is kept. With ``hybrid_segment_s > 0`` and several
    refined tracks, one more start is spliced from them: per segment of that
    many seconds, the refined track whose data term there is lowest (at its
    own offset); it is refined and competes like the others.
    ``height_accel_noise_mps2`` and ``tilt_accel_noise_dps2`` (> 0) replace
    the height and tilt random walks of the prior by constant-rate models
    (:class:`MotionPrior`): with ``polish_starts`` ≥ 1 as a polish — every
    start is refined with the random walks as before, then the
    ``polish_starts`` refined tracks of the lowest objective are refined
    again with the constant-rate prior and the lowest of those is kept; with
    ``polish_starts = 0`` every start is refined with the constant-rate prior
    directly (stiffer: more starts stay in a local minimum, docs/pose3d.md).
    The polished tracks are distinct modes (:func:`same_track`: a refined
    track within 0.1 m and 2° of a lower one is not polished again) whose
    random-walk objective is within ``polish_margin`` (σ² units) of the
    lowest (docs/pose3d.md, "Mode choice, 2026-11-27"); the polish of the
    lowest random-walk track is kept unless another polished mode's
    objective is lower by more than ``polish_switch`` (σ² units: a
    log-likelihood ratio in nats; 0: the lowest polished objective wins).
    Starts identical to an earlier one (the chosen member's own track) are
    refined once. ``anneal_sigma`` (factors > 1, largest first; empty: off):
    each start is first refined with σ times each factor in turn, each from
    the last one's optimum, before its refinement at σ (a graduated
    continuation: a larger σ weighs the data less against the motion prior,
    docs/pose3d.md "Annealed refinement"); with ``anneal_keep_direct`` each
    start is also refined at σ directly and the lower objective of the two is
    that start's result. ``coarse_start`` (optional): a function of a track's
    packet times (s), heard readings and σ (dB) returning more starts, each
    positions (m) and orientations (°) per packet and an offset (dB) (the
    whole-file coarse HMM's paths:
    :func:`radiopose.filtering.coarse3d.coarse_paths3d`); each is refined and
    competes like the others (polished only within the margin: forcing its
    polish let a coarse path's mirror win over the filter's track on a tuning
    seed, docs/pose3d.md).
    ``heading`` = ``(sd °, τ s, v0 m/s)`` (``None``: off) adds each refined
    track's :func:`heading_cost` to its objective where the modes to polish
    are picked and where the kept one is chosen (the tracks are refined
    without it; docs/pose3d.md, "Heading in the mode choice, 2026-11-28").
    ``memo`` (optional, a dict the caller keeps): each solve and each coarse
    start is stored by its inputs and reused by a later call on the same
    packets (the escalation refines a file again with more starts; the solves
    are deterministic, so the result is the same as solving again).
    ``orientation_path``: after the mode choice, the most likely orientation
    path along the kept track's positions
    (:func:`radiopose.filtering.orientation_path.orientation_path`, a Viterbi
    search over a fine orientation grid) is refined like a start (and
    polished) and replaces the kept track when its objective (with the
    heading cost) is lower by more than ``polish_switch``
    (docs/pose3d.md, "An orientation path, 2026-11-28").
    ``band`` (optional, :class:`PoseBand`): the hand-held band prior in every
    solve (so in every objective the mode choice compares).
    Returns every
    smoothed estimate, those of the refined tracks with their pose and offset
    replaced (spread and σ kept).
    """
    by_key = dict(smoothed)
    alt_keys = [dict(a) for a in alternatives]
    out = dict(smoothed)
    prior = MotionPrior.of_filter(
        config, height_noise_mps, tilt_noise_dps, height_accel_noise_mps2, tilt_accel_noise_dps2
    )
    walks = MotionPrior.of_filter(config, height_noise_mps, tilt_noise_dps)
    polish = polish_starts > 0 and prior != walks  # a constant-rate prior, as a polish
    search = walks if polish else prior
    track: list[tuple[float, HeardRss, object]] = []

    def start(ests: list[FilterEstimate]) -> tuple[FloatArray, FloatArray, float]:
        offs = np.array([e.offset_db for e in ests], dtype=float)
        off = float(np.median(offs[np.isfinite(offs)])) if np.isfinite(offs).any() else 0.0
        return (
            np.array([e.position_m for e in ests], dtype=float),
            np.array([e.orientation_deg for e in ests], dtype=float),
            off,
        )

    def finish() -> None:
        rows = [r for r in track if r[2] in by_key and r[1].n_heard > 0]
        track.clear()
        if not rows:
            return
        ests = [by_key[r[2]] for r in rows]
        inits = [start(ests)]
        for alt in alt_keys:
            if all(r[2] in alt for r in rows):
                init = start([alt[r[2]] for r in rows])
                # the chosen track is often one member's own: refining it twice adds nothing
                if not any(_same_start(init, i) for i in inits):
                    inits.append(init)
        t_rows = np.array([r[0] for r in rows])
        h_rows = [r[1] for r in rows]
        sigma = track_sigma_db(ests, config)
        track_key = (t_rows.tobytes(), float(sigma))

        def remembered(key: tuple[object, ...], make: Callable[[], Any]) -> Any:
            if memo is None:
                return make()
            if key not in memo:
                memo[key] = make()
            return memo[key]

        if coarse_start is not None:
            cs = coarse_start
            inits += remembered(("coarse", *track_key), lambda: cs(t_rows, h_rows, sigma))

        def solve(
            pos: FloatArray,
            ori: FloatArray,
            off: float,
            pri: MotionPrior = search,
            factor: float = 1.0,
        ) -> RefinedTrack:
            key = ("solve", *track_key, np.asarray(pos).tobytes(), np.asarray(ori).tobytes(),
                   float(off), pri, float(factor), band)  # fmt: skip
            return remembered(key, lambda: refine_track(
                model, t_rows, h_rows, pos, ori, off, sigma * factor, pri, offset_prior_db=0.0,
                offset_prior_sd_db=config.offset_prior_sd_db, max_nfev=max_nfev, band=band,
            ))  # fmt: skip

        def searched(pos: FloatArray, ori: FloatArray, off: float) -> RefinedTrack:
            """A start refined at σ, first at σ × each ``anneal_sigma`` factor."""
            at = pos, ori, off
            for factor in anneal_sigma:
                r = solve(*at, factor=factor)
                at = r.position_m, r.orientation_deg, r.offset_db
            r = solve(*at)
            if anneal_sigma and anneal_keep_direct:
                direct = solve(pos, ori, off)
                return r if r.cost < direct.cost else direct
            return r

        def extra(r: RefinedTrack) -> float:
            """The mode choice's extra term: the heading prior's cost, if on."""
            if heading is None:
                return 0.0
            return heading_cost(t_rows, r.position_m, r.orientation_deg, *heading)

        done = [searched(*init) for init in inits]
        if hybrid_segment_s > 0 and len(done) > 1:
            costs = np.array([
                packet_costs(model, h_rows, d.position_m, d.orientation_deg, d.offset_db, sigma)
                for d in done
            ])  # fmt: skip
            seg = np.floor((t_rows - t_rows[0]) / hybrid_segment_s).astype(np.int64)
            seg_cost = np.array([np.bincount(seg, weights=c) for c in costs])
            pick = np.argmin(seg_cost, axis=0)[seg]  # the refined track per packet
            if np.unique(pick).size > 1:
                pos = np.array([done[k].position_m[i] for i, k in enumerate(pick)])
                ori = np.array([done[k].orientation_deg[i] for i, k in enumerate(pick)])
                off = float(np.median([done[k].offset_db for k in pick]))
                done.append(solve(pos, ori, off))
        if polish:
            # the constant-rate prior as a polish of the lowest-objective tracks
            # the random walks found (their objectives are not comparable with
            # the polished ones: only polished tracks compete)
            chosen = [r.cost + extra(r) for r in done]
            done = [done[i] for i in np.argsort(chosen, kind="stable")]
            chosen.sort()
            picked: list[RefinedTrack] = []
            for d, c in zip(done, chosen, strict=True):
                if len(picked) >= polish_starts or c > chosen[0] + polish_margin:
                    break
                if not any(same_track(d, p) for p in picked):
                    picked.append(d)
            done = [solve(d.position_m, d.orientation_deg, d.offset_db, prior)
                    for d in picked]  # fmt: skip
        score = [r.cost + extra(r) for r in done]
        if polish:
            # the search's own choice (done[0]) stays unless another mode is clearly lower
            score[0] -= polish_switch
        best = done[int(np.argmin(score))]
        if orientation_path:
            from radiopose.filtering.orientation_path import orientation_path as o_path

            kept = best
            path = remembered(
                ("orientation-path", *track_key, kept.position_m.tobytes(), kept.offset_db),
                lambda: o_path(model, t_rows, h_rows, kept.position_m, kept.offset_db, sigma),
            )
            found = searched(kept.position_m, path, kept.offset_db)
            if polish:
                found = solve(found.position_m, found.orientation_deg, found.offset_db, prior)
            if found.cost + extra(found) < kept.cost + extra(kept) - polish_switch:
                best = found
        for i, (r, e) in enumerate(zip(rows, ests, strict=True)):
            p, o = best.position_m[i], best.orientation_deg[i]
            out[r[2]] = replace(
                e,
                position_m=(float(p[0]), float(p[1]), float(p[2])),
                orientation_deg=(float(o[0]), float(o[1]), float(o[2])),
                offset_db=best.offset_db,
            )

    last_t: float | None = None
    for rec in records:
        if last_t is not None and rec[0] - last_t > config.reacquire_gap_s:
            finish()
        track.append(rec)
        last_t = rec[0]
    finish()
    return [(k, out[k]) for k, _ in smoothed]
