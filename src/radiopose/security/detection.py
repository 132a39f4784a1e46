"""Spoofing detection beside the Bayesian tracker (issue 19, ``docs/security.md``).

The detector tests the *change from one packet to the next* of what each
receiver ``r`` measures of one transmitter address, ``Δy_r(t) = y_r(t) −
y_r(t−1)``. By default (``signal = "rss"``) ``y`` is the packet's RSS itself: a
single real device moves and turns little between two packets (5 ms), so for
it ``Δy`` is the noise of two packets (variance ``2σ²``) plus a small, slowly
varying term of its motion — whatever the tracker makes of it. Two senders
with one address (a clone beside the genuine device), or one transmitter whose
power follows someone else's recording (replay), make ``Δy`` jump from packet
to packet. With ``signal = "residual"`` ``y`` is the residual at the tracker's
own pose, ``e_r(t) = RSS_r(t) − E_r(x̂_t)`` (``E_r``: the system's expected
RSS, survey map and enrolled pattern, :meth:`radiopose.filtering.FilterModel.expected`):
the first design, kept selectable; its genuine tracks score higher because
the filter's own pose jitter from packet to packet enters ``Δe`` (measured in
``docs/security.md``: up to 42 nats on genuine traffic where the RSS changes
stay under 13).

Per packet, against a reference variance ``v`` of ``Δy`` learned while the
detector is quiet, it adds the log-likelihood ratio of "variance inflated
``k``-fold" against "as before" (a Gaussian variance CUSUM, Page 1954)::

    z_r² = min(Δy_r² / v, c²)                            (clipped at c)
    ℓ_t  = Σ_r [ ½ z_r² (1 − 1/k) − ½ ln k ]
    C_t  = min(max(0, C_{t−1} + ℓ_t + g_t), 2 h)

with ``g_t`` optional gap evidence (``gap_nats > 0``): a silence longer than
``gap_factor`` times the device's typical gap adds
``gap_nats · log2(gap / (gap_factor · typical))`` — a real device's traffic
does not pause where an attacker must. The alarm is on while ``C_t ≥ h``
(``threshold_nats``). ``C_t`` is the per-packet ``spoof_score_nats`` column;
during the first ``warmup_s`` of a track the score is 0 (the reference is being
learned).

:func:`score_track` is the batch form (compiled); :class:`ConsistencyDetector`
the streaming one (live server); both give the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike

from radiopose.errors import InputError
from radiopose.estimates import Estimates
from radiopose.filtering import FilterModel
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.packets import PacketObservation
from radiopose.site import Site
from radiopose.units import FloatArray

SCORE_COLUMN = "spoof_score_nats"
"""Trailing ``estimates.csv`` column: the detector's CUSUM, nats."""
ALARM_COLUMN = "spoof_alarm_flag"
"""Trailing ``estimates.csv`` column: 1 while the alarm is on, else 0."""
SIGNALS = ("rss", "residual")
"""What the detector may test the changes of (:attr:`DetectorConfig.signal`)."""


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of the consistency detector (defaults measured in ``docs/security.md``).

    Attributes
    ----------
    inflation
        ``k``: the variance ratio the CUSUM tests for.
    threshold_nats
        ``h``: alarm level of the CUSUM, nats.
    clip_sigma
        ``c``: a standardised residual change counts at most this much.
    reference_s
        Time constant of the reference variance, seconds.
    warmup_s
        No score during the first seconds of a track (reference learned).
    gap_factor
        A silence longer than this many typical gaps is evidence.
    gap_nats
        Evidence per doubling of such a silence, nats (0, the default, disables
        the gap test: the simulated attackers keep the device's cadence, and
        real traffic's gaps were not measured).
    min_sigma_db
        Lower bound of the per-packet noise σ behind the reference, dB.
    signal
        What the CUSUM tests the packet-to-packet changes of: ``"rss"`` (the
        default: each receiver's RSS itself) or ``"residual"`` (RSS − expected
        RSS at the tracker's pose; the first design, whose genuine tracks score
        higher where the filter's own pose jitters — ``docs/security.md``).
    """

    inflation: float = 1.5
    threshold_nats: float = 16.0
    clip_sigma: float = 2.0
    reference_s: float = 5.0
    warmup_s: float = 1.0
    gap_factor: float = 5.0
    gap_nats: float = 0.0
    min_sigma_db: float = 0.25
    signal: str = "rss"

    def __post_init__(self) -> None:
        if self.signal not in SIGNALS:
            raise InputError(
                f"detector setting signal = {self.signal!r} is not one of {', '.join(SIGNALS)}"
            )
        checks = [
            ("inflation", self.inflation > 1.0),
            ("threshold_nats", self.threshold_nats > 0),
            ("clip_sigma", self.clip_sigma > 0),
            ("reference_s", self.reference_s > 0),
            ("warmup_s", self.warmup_s >= 0),
            ("gap_factor", self.gap_factor > 1.0),
            ("gap_nats", self.gap_nats >= 0),
            ("min_sigma_db", self.min_sigma_db > 0),
        ]
        for name, ok in checks:
            v = getattr(self, name)
            if not ok or not math.isfinite(v):
                raise InputError(f"detector setting {name} = {v!r} is out of range")


@dataclass(frozen=True, eq=False)
class DetectionResult:
    """Per-packet output of :func:`score_track`: ``score_nats`` ``(n,)`` and ``alarm`` ``(n,)``."""

    score_nats: FloatArray
    alarm: np.ndarray

    def alarm_onsets(self) -> np.ndarray:
        """Indices of the packets at which the alarm switches on."""
        a = self.alarm.astype(bool)
        return np.flatnonzero(a & ~np.concatenate([[False], a[:-1]]))


class ConsistencyDetector:
    """The streaming detector of one track: :meth:`update` per packet.

    Parameters
    ----------
    config
        Detector parameters.
    """

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the track (a new one starts at the next packet)."""
        self.start_s: float | None = None
        self.last_s: float | None = None
        self.previous_db: FloatArray | None = None
        self.var_db2 = 0.0
        self.log_gap = 0.0
        self.n = 0
        self.n_gaps = 0
        self.cusum_nats = 0.0
        self.alarm = False

    def update(self, t_s: float, values_db: FloatArray) -> tuple[float, bool]:
        """One packet: ``values_db`` ``(n_rx,)`` by receiver index, ``nan`` where not
        heard — the RSS (``signal = "rss"``) or RSS − expected RSS at the track's
        pose, no power offset (``"residual"``). Returns ``(score_nats, alarm)``."""
        cfg = self.config
        e = np.asarray(values_db, dtype=np.float64)
        gap = 0.0 if self.last_s is None else max(t_s - self.last_s, 0.0)
        if self.start_s is None:
            self.start_s = t_s
        self.last_s = t_s
        prev, self.previous_db = self.previous_db, e.copy()
        if prev is None or prev.shape != e.shape:
            return self.cusum_nats, self.alarm
        # Δe_r: the packet's residual change since the last packet, both heard
        u = (e - prev)[np.isfinite(e) & np.isfinite(prev)]
        if u.size == 0:
            return self.cusum_nats, self.alarm
        warm = t_s - self.start_s < cfg.warmup_s
        v = (
            max(self.var_db2, 2.0 * cfg.min_sigma_db**2)
            if self.n
            else max(float(np.mean(u * u)), 1.0)
        )
        z2 = np.minimum(u * u / v, cfg.clip_sigma**2)
        k = cfg.inflation
        # log-likelihood ratio of N(0, k v) against N(0, v) per receiver
        llr = float(np.sum(0.5 * z2 * (1.0 - 1.0 / k) - 0.5 * math.log(k)))
        if cfg.gap_nats > 0 and self.n_gaps > 1 and gap > 0:
            typical = math.exp(self.log_gap)
            if gap > cfg.gap_factor * typical:
                llr += cfg.gap_nats * math.log2(gap / (cfg.gap_factor * typical))
        h = cfg.threshold_nats
        self.cusum_nats = 0.0 if warm else min(max(0.0, self.cusum_nats + llr), 2.0 * h)
        # the reference: learned while quiet (fast at first, then over reference_s)
        if warm or self.cusum_nats < 0.5 * h:
            self.n += 1
            a = max(1.0 / self.n, min(gap / cfg.reference_s, 1.0))
            self.var_db2 += a * (float(np.mean(z2)) * v - self.var_db2)
            if gap > 0:
                self.n_gaps += 1
                lg = math.log(gap)
                b = max(1.0 / self.n_gaps, min(gap / cfg.reference_s, 1.0))
                self.log_gap += b * (lg - self.log_gap)
        self.alarm = (not warm) and self.cusum_nats >= h
        return self.cusum_nats, self.alarm


@numba.njit(cache=True)
def _score_kernel(
    t: FloatArray,
    r: FloatArray,
    new_track: np.ndarray,
    k: float,
    h: float,
    clip: float,
    reference_s: float,
    warmup_s: float,
    gap_factor: float,
    gap_nats: float,
    min_sigma_db: float,
) -> tuple[FloatArray, np.ndarray]:  # pragma: no cover - compiled
    """:meth:`ConsistencyDetector.update` over a whole track (same arithmetic)."""
    n, n_rx = r.shape
    score = np.zeros(n)
    alarm = np.zeros(n, dtype=np.bool_)
    u = np.empty(n_rx)
    log_k = math.log(k)
    c2 = clip * clip
    have = False
    start = 0.0
    last = 0.0
    var = 0.0
    log_gap = 0.0
    m = 0
    m_gaps = 0
    cusum = 0.0
    on = False
    for i in range(n):
        if new_track[i]:
            have = False
            var = 0.0
            log_gap = 0.0
            m = 0
            m_gaps = 0
            cusum = 0.0
            on = False
        ti = t[i]
        if not have:
            have = True
            start = ti
            last = ti
            score[i] = cusum
            alarm[i] = on
            continue
        gap = max(ti - last, 0.0)
        last = ti
        nu = 0
        for j in range(n_rx):
            a = r[i, j]
            b = r[i - 1, j]
            if math.isfinite(a) and math.isfinite(b):
                u[nu] = a - b
                nu += 1
        if nu == 0:
            score[i] = cusum
            alarm[i] = on
            continue
        warm = ti - start < warmup_s
        if m:
            v = max(var, 2.0 * min_sigma_db * min_sigma_db)
        else:
            s2 = 0.0
            for j in range(nu):
                s2 += u[j] * u[j]
            v = max(s2 / nu, 1.0)
        llr = 0.0
        zsum = 0.0
        for j in range(nu):
            z2 = min(u[j] * u[j] / v, c2)
            zsum += z2
            llr += 0.5 * z2 * (1.0 - 1.0 / k) - 0.5 * log_k
        if gap_nats > 0 and m_gaps > 1 and gap > 0:
            typical = math.exp(log_gap)
            if gap > gap_factor * typical:
                llr += gap_nats * math.log2(gap / (gap_factor * typical))
        cusum = 0.0 if warm else min(max(0.0, cusum + llr), 2.0 * h)
        if warm or cusum < 0.5 * h:
            m += 1
            a = max(1.0 / m, min(gap / reference_s, 1.0))
            var += a * (zsum / nu * v - var)
            if gap > 0:
                m_gaps += 1
                b = max(1.0 / m_gaps, min(gap / reference_s, 1.0))
                log_gap += b * (math.log(gap) - log_gap)
        on = (not warm) and cusum >= h
        score[i] = cusum
        alarm[i] = on
    return score, alarm


def score_track(
    t_s: FloatArray,
    values_db: FloatArray,
    config: DetectorConfig | None = None,
    new_track: np.ndarray | None = None,
) -> DetectionResult:
    """Score one track (batch form of :class:`ConsistencyDetector`, compiled).

    Parameters
    ----------
    t_s
        ``(n,)`` packet times, seconds, non-decreasing.
    values_db
        ``(n, n_rx)`` per packet and receiver index the RSS (``signal = "rss"``) or
        RSS − expected RSS at the track's estimated pose (``"residual"``), dB
        (``nan`` where a receiver did not hear the packet).
    config
        Detector parameters.
    new_track
        ``(n,)`` bool: a new track starts at this packet (the tracker re-acquired).

    Returns
    -------
    DetectionResult
        Per packet the CUSUM score (nats) and the alarm.
    """
    t = np.ascontiguousarray(t_s, dtype=np.float64)
    r = np.ascontiguousarray(np.atleast_2d(np.asarray(values_db, dtype=np.float64)))
    if r.shape[0] != t.shape[0]:
        raise InputError(f"score_track: {t.shape[0]} times but {r.shape[0]} value rows")
    if t.ndim != 1 or not np.isfinite(t).all() or (np.diff(t) < 0).any():
        raise InputError("score_track: the times must be finite and non-decreasing")
    cfg = config or DetectorConfig()
    new = np.zeros(t.size, np.bool_) if new_track is None else np.asarray(new_track, np.bool_)
    score, alarm = _score_kernel(
        t,
        r,
        new,
        cfg.inflation,
        cfg.threshold_nats,
        cfg.clip_sigma,
        cfg.reference_s,
        cfg.warmup_s,
        cfg.gap_factor,
        cfg.gap_nats,
        cfg.min_sigma_db,
    )
    return DetectionResult(score, alarm)


def _score_track_streaming(
    t_s: FloatArray,
    values_db: FloatArray,
    config: DetectorConfig | None = None,
    new_track: np.ndarray | None = None,
) -> DetectionResult:
    """:func:`score_track` through :class:`ConsistencyDetector` (the reference; tests)."""
    t = np.asarray(t_s, dtype=np.float64)
    r = np.atleast_2d(np.asarray(values_db, dtype=np.float64))
    det = ConsistencyDetector(config)
    score = np.zeros(t.size)
    alarm = np.zeros(t.size, dtype=bool)
    for i in range(t.size):
        if new_track is not None and new_track[i]:
            det.reset()
        score[i], alarm[i] = det.update(float(t[i]), r[i])
    return DetectionResult(score, alarm)


def pose_residuals_db(
    model: FilterModel,
    position_m: ArrayLike,
    orientation_deg: ArrayLike,
    rss_dbm: ArrayLike,
) -> FloatArray:
    """Residuals ``(n, n_rx)`` of packets at poses: RSS − the system's expected RSS.

    Parameters
    ----------
    model
        The device's model (:meth:`radiopose.filtering.FilterModel.build`).
    position_m, orientation_deg
        ``(n, 3)`` estimated poses (metres; azimuth, pitch, roll in degrees).
    rss_dbm
        ``(n, n_rx)`` RSS by receiver index, ``nan`` where not heard.
    """
    pos = np.atleast_2d(np.asarray(position_m, dtype=np.float64))
    ori = np.atleast_2d(np.asarray(orientation_deg, dtype=np.float64))
    rss = np.atleast_2d(np.asarray(rss_dbm, dtype=np.float64))
    n, n_rx = rss.shape
    S = np.zeros((n, K.N_COLUMNS))
    S[:, K.X_M : K.Z_M + 1] = pos
    S[:, K.AZIMUTH_RAD] = np.deg2rad(ori[:, 0])
    S[:, K.PITCH_RAD] = np.deg2rad(ori[:, 1])
    S[:, K.ROLL_RAD] = np.deg2rad(ori[:, 2])
    expected = model.expected(S, np.arange(n_rx, dtype=np.int64))
    return rss - expected


def score_estimates(
    site: Site,
    observations: Sequence[PacketObservation],
    estimates: Estimates,
    config: DetectorConfig | None = None,
    reacquire_gap_s: float = 1.0,
) -> DetectionResult:
    """The detector over a track file: one score and alarm per estimate row.

    Each transmitter's estimates are taken in time order; a row's values are its
    packet's RSS (from ``observations``, matched by transmitter and packet id),
    minus the expected RSS at the row's pose for ``signal = "residual"``. A silence longer than
    ``reacquire_gap_s`` starts a new track (the filter re-acquires there).
    Rows of transmitters not enrolled at ``site`` score 0.

    Parameters
    ----------
    site
        The site (receivers, survey map, devices).
    observations
        The packets (:func:`radiopose.packets.group_packets`).
    estimates
        The filter's estimates (``estimates.csv`` rows).
    """
    from radiopose.likelihood import candidate_space, make_scorer

    cfg = config or DetectorConfig()
    n = len(estimates)
    score = np.zeros(n)
    alarm = np.zeros(n, dtype=bool)
    rx_index = {r: i for i, r in enumerate(site.receiver_ids)}
    n_rx = len(rx_index)
    by_key = {(o.transmitter.lower(), str(o.packet_id)): o for o in observations}
    enrolled = {d.transmitter.lower(): d.transmitter for d in site.devices}
    tx_rows: dict[str, list[int]] = {}
    for i, tx in enumerate(estimates.transmitter):
        tx_rows.setdefault(str(tx).lower(), []).append(i)
    for tx, rows_list in tx_rows.items():
        if tx not in enrolled:
            continue
        if cfg.signal == "residual":
            space = candidate_space(site, enrolled[tx])
            # only FilterModel.expected is used: the scorer that costs nothing to build
            model = FilterModel.build(site, space, make_scorer("reference", space))
        rows = np.asarray(rows_list)
        rows = rows[np.argsort(estimates.timestamp_s[rows], kind="stable")]
        rss = np.full((rows.size, n_rx), np.nan)
        for j, i in enumerate(rows):
            o = by_key.get((tx, str(estimates.packet_id[i])))
            if o is None:
                continue
            for r, v in zip(o.receiver_ids, o.rss_dbm, strict=True):
                if r in rx_index:
                    rss[j, rx_index[r]] = v
        if cfg.signal == "rss":
            values = rss
        else:
            values = pose_residuals_db(
                model, estimates.position_m[rows], estimates.orientation_deg[rows], rss
            )
        t = estimates.timestamp_s[rows]
        new = np.concatenate([[True], np.diff(t) > reacquire_gap_s])
        out = score_track(t, values, cfg, new)
        score[rows] = out.score_nats
        alarm[rows] = out.alarm
    return DetectionResult(score, alarm)
