"""How much evidence attacks 1–2 leave in the RSS: an oracle bound and a fit test.

Two questions about the ``fixed`` and ``moving`` attackers (issue 19,
``docs/security.md``, "Attacks 1–2"):

**The oracle bound.** Over a window of the attack, the log-likelihood ratio
between the data under the attacker's *true* generating model (its pose and
per-packet power, known from the simulation; the simulator's channel; the true
noise σ) and under the best *genuine* explanation found: one real device,
constant transmit power (one offset fitted), moving along a smooth path::

    Λ = (SSE₀ − SSE₁) / (2σ²)

``SSE₁`` is the residual energy at the attacker's true mean, ``SSE₀`` the
smallest found of (a) the spoofed path itself (the genuine device's true
continuation) with one constant offset and (b) a smooth path
(:func:`smooth_path`) fitted by least squares from several starts (the spoofed
path, the attacker's own pose, the best static poses of a grid). Since a
better genuine explanation can only lower ``SSE₀``, ``Λ`` is an *upper* bound
on the evidence any detector can collect in that window.

**The fit test** (the detector that uses this evidence, :func:`fit_statistic`):
over a window, the best smooth-path fit with one offset (the system's model:
survey map, enrolled pattern — what the server knows), the noise variance from
the packets alone (half the mean squared change from one packet to the next,
as the CUSUM), and the excess of the normalised residual energy over its
degrees of freedom, in nats::

    G = ½ (SSE₀ / σ̂² − (N − p))

``N`` the residuals in the window, ``p`` the fitted parameters. A real device
the fit can follow gives ``G`` ≈ 0 ± √(N/2); an attacker whose RSS no smooth
path at constant power reproduces gives ``G`` of the order of its ``Λ``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.polynomial import legendre
from scipy.optimize import least_squares

from radiopose.units import FloatArray

if TYPE_CHECKING:
    from radiopose.security.attacks import SiteModel

MeanFn = Callable[[FloatArray, FloatArray], FloatArray]
"""Noise-free RSS ``(n, n_rx)`` dBm of poses: positions ``(n, 3)`` m, azimuths ``(n,)`` deg
(enrolled transmit power, no offset)."""


def azimuth_degree(window_s: float) -> int:
    """Degree of the azimuth polynomial of a smooth path over ``window_s``: 3 up to
    0.5 s, then 2 more per further 0.5 s (a periodic sway of 0.2–0.6 Hz bends more
    over longer windows)."""
    return 3 + 2 * max(0, int(np.ceil(window_s / 0.5 - 1e-9)) - 1)


def smooth_path(params: FloatArray, u: FloatArray, z_m: float) -> tuple[FloatArray, FloatArray]:
    """Poses of a smooth path at normalised times ``u`` ∈ [−1, 1].

    ``params = (x, y, vx, vy, a₀, …, a_d)``: position ``(x, y) + (vx, vy)·u`` metres
    (constant velocity, ``v`` in metres per half window), azimuth
    ``Σ a_k P_k(u)`` degrees (Legendre polynomials ``P_k``). Returns positions
    ``(n, 3)`` (height ``z_m``) and azimuths ``(n,)``.
    """
    p = np.asarray(params, float)
    pos = np.column_stack([p[0] + p[2] * u, p[1] + p[3] * u, np.full(u.size, z_m)])
    return pos, legendre.legval(u, p[4:])


@dataclass(frozen=True)
class PathFit:
    """A smooth-path fit: residual energy ``sse_db2`` (dB²), its parameters, offset (dB)."""

    sse_db2: float
    params: FloatArray
    offset_db: float


def _residuals(mean_fn: MeanFn, rss: FloatArray, u: FloatArray, z_m: float):
    ok = np.isfinite(rss)

    def fun(p: FloatArray) -> FloatArray:
        pos, az = smooth_path(p, u, z_m)
        r = (rss - mean_fn(pos, az))[ok]
        r = np.nan_to_num(r, nan=30.0)
        return r - r.mean()  # the constant offset, profiled out

    n = u.size
    k_az = None

    def jac(p: FloatArray) -> FloatArray:
        # the poses are linear in the parameters: differentiate the model in x, y and
        # the azimuth (one call, forward differences) and chain through the bases
        nonlocal k_az
        if k_az is None or k_az.shape[1] != p.size - 4:
            k_az = legendre.legvander(u, p.size - 5)  # (n, d + 1)
        pos0, az0 = smooth_path(p, u, z_m)
        hx, ha = 1e-4, 1e-3
        pos = np.tile(pos0, (4, 1))
        pos[n : 2 * n, 0] += hx
        pos[2 * n : 3 * n, 1] += hx
        az = np.tile(az0, 4)
        az[3 * n :] += ha
        mu = mean_fn(pos, az).reshape(4, n, -1)
        d = np.stack([(mu[1] - mu[0]) / hx, (mu[2] - mu[0]) / hx, (mu[3] - mu[0]) / ha])
        # d: (3, n, n_rx) model derivatives; residual derivative = −(model derivative)
        cols = [d[0], d[1], d[0] * u[:, None], d[1] * u[:, None]]
        cols += [d[2] * k_az[:, j][:, None] for j in range(k_az.shape[1])]
        jm = -np.stack([c[ok] for c in cols], axis=1)  # (m, k)
        return jm - jm.mean(axis=0, keepdims=True)

    return fun, jac, ok


def fit_smooth_path(
    mean_fn: MeanFn,
    t_s: FloatArray,
    rss_dbm: FloatArray,
    starts: Sequence[FloatArray],
    z_m: float,
    keep: int = 4,
    max_nfev: int = 60,
) -> PathFit:
    """Least-squares smooth path with one constant offset, from the ``keep`` best starts.

    Parameters
    ----------
    mean_fn
        The model (:data:`MeanFn`).
    t_s, rss_dbm
        ``(n,)`` packet times (s) and ``(n, n_rx)`` RSS (dBm, ``nan``: not heard).
    starts
        Parameter vectors (:func:`smooth_path`, normalised time over ``t_s``).
    z_m
        Height of the path, metres.
    keep
        How many of the starts (the best by their initial energy) are refined.
    """
    u = _normalised_time(t_s)
    fun, jac, _ = _residuals(mean_fn, rss_dbm, u, z_m)
    costs = [float(np.sum(fun(s) ** 2)) for s in starts]
    best: PathFit | None = None
    for i in np.argsort(costs)[:keep]:
        sol = least_squares(
            fun,
            np.asarray(starts[i], float),
            jac=jac,
            method="lm",
            max_nfev=max_nfev,
            x_scale="jac",
        )
        sse = float(np.sum(sol.fun**2))
        if best is None or sse < best.sse_db2:
            pos, az = smooth_path(sol.x, u, z_m)
            off = float(np.nanmean(rss_dbm - mean_fn(pos, az)))
            best = PathFit(sse, sol.x, off)
    assert best is not None
    return best


def _normalised_time(t_s: FloatArray) -> FloatArray:
    t = np.asarray(t_s, float)
    half = max(0.5 * (t[-1] - t[0]), 1e-9)
    return (t - 0.5 * (t[-1] + t[0])) / half


def path_params(
    position_m: FloatArray, azimuth_deg: FloatArray, t_s: FloatArray, degree: int
) -> FloatArray:
    """The smooth path (:func:`smooth_path`) closest to poses ``(n, 3)``, ``(n,)`` at ``t_s``
    (least squares; the azimuth unwrapped first)."""
    u = _normalised_time(t_s)
    cx = np.polyfit(u, position_m[:, 0], 1)
    cy = np.polyfit(u, position_m[:, 1], 1)
    az = np.degrees(np.unwrap(np.radians(azimuth_deg)))
    ca = legendre.legfit(u, az, degree)
    return np.concatenate([[cx[1], cy[1], cx[0], cy[0]], ca])


@dataclass(frozen=True, eq=False)
class PoseGrid:
    """Static poses of a site and their expected RSS centred across receivers."""

    position_m: FloatArray  # (m, 3)
    azimuth_deg: FloatArray  # (a,)
    centred_dbm: FloatArray  # (m, a, n_rx)

    @classmethod
    def build(
        cls, mean_fn: MeanFn, size_m: float, z_m: float, step_m: float = 0.5, step_deg: float = 5.0
    ) -> PoseGrid:
        axis = np.arange(0.0, size_m + 1e-9, step_m)
        gx, gy = np.meshgrid(axis, axis, indexing="ij")
        pts = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z_m)])
        az = np.arange(0.0, 360.0, step_deg)
        ex = mean_fn(np.repeat(pts, az.size, axis=0), np.tile(az, pts.shape[0]))
        ex = ex.reshape(pts.shape[0], az.size, -1)
        return cls(pts, az, ex - ex.mean(axis=2, keepdims=True))

    def cost(self, rss_dbm: FloatArray) -> FloatArray:
        """``(m, a)``: squared distance of every pose's centred RSS from the packets'
        mean centred RSS (receivers heard in every packet of ``rss_dbm``)."""
        y = np.nanmean(rss_dbm, axis=0)
        ok = np.isfinite(y)
        g = self.centred_dbm[:, :, ok]
        g = g - g.mean(axis=2, keepdims=True)
        yc = y[ok] - y[ok].mean()
        return np.sum((g - yc) ** 2, axis=2)

    def starts(self, t_s: FloatArray, rss_dbm: FloatArray, degree: int, n: int = 6) -> list:
        """Start paths: the ``n`` best positions for the middle third of the window, each
        static, with the azimuth through the best azimuths there in the three thirds."""
        thirds = np.array_split(np.arange(t_s.size), 3)
        costs = [self.cost(rss_dbm[idx]) for idx in thirds]
        mid = costs[1].min(axis=1)
        order = np.argsort(mid)
        chosen: list[int] = []
        for j in order:  # distinct positions (at least 1 m apart)
            if all(
                np.hypot(*(self.position_m[j, :2] - self.position_m[k, :2])) >= 1.0 for k in chosen
            ):
                chosen.append(int(j))
            if len(chosen) == n:
                break
        u_mid = np.array([_normalised_time(t_s)[idx].mean() for idx in thirds])
        out = []
        for j in chosen:
            az = np.array([self.azimuth_deg[int(np.argmin(c[j]))] for c in costs])
            az = np.degrees(np.unwrap(np.radians(az)))
            ca = np.zeros(degree + 1)
            ca[:3] = legendre.legfit(u_mid, az, 2)
            out.append(np.concatenate([self.position_m[j, :2], [0.0, 0.0], ca]))
        return out


def window_noise_var_db2(rss_dbm: FloatArray) -> float:
    """Noise variance from the packets alone: half the mean squared change of each
    receiver's RSS from one packet to the next (dB²)."""
    d = np.diff(rss_dbm, axis=0)
    d = d[np.isfinite(d)]
    return float(np.mean(d * d) / 2.0) if d.size else float("nan")


def fit_statistic(fit: PathFit, rss_dbm: FloatArray, degree: int, var_db2: float) -> float:
    """``G = ½ (SSE / σ̂² − (N − p))``, nats (module docstring)."""
    n = int(np.isfinite(rss_dbm).sum())
    p = 4 + degree + 1 + 1  # position, velocity, azimuth coefficients, offset
    return 0.5 * (fit.sse_db2 / var_db2 - (n - p))


# ----------------------------------------------------------------------------- the bound
@dataclass(frozen=True)
class OracleResult:
    """The oracle bounds over one attack window (nats) and what stands behind them.

    ``bound_window_nats``: the best smooth path fitted to the attack window alone (a
    genuine device allowed to appear anywhere at the attack start);
    ``bound_spoofed_nats``: the genuine device's own path (prefix and spoofed
    continuation) over ``prefix_s`` before and the window after the start, one offset;
    ``bound_nats``: the best continuous explanation found over that span (≤ the former).
    """

    attack: str
    run: int
    n_receivers: int
    window_s: float
    sigma_db: float
    packets: int
    bound_window_nats: float
    bound_spoofed_nats: float
    bound_nats: float
    attacker_fit_nats: float  # (SSE at the attacker's true mean − N σ²) / 2σ²: noise check
    power_range_db: float  # max − min of the attacker's power offset in the window
    power_mean_db: float  # the attacker's mean power offset in the window


def channel_mean_fn(site: SiteModel) -> MeanFn:
    """The simulator's channel as a :data:`MeanFn` (enrolled power, no noise)."""
    from radiopose.simulate import link_rss_dbm

    sc = site.sim.config
    space = site.model.space

    def fn(pos: FloatArray, az: FloatArray) -> FloatArray:
        ori = np.column_stack([az, np.zeros(az.size), np.zeros(az.size)])
        return link_rss_dbm(
            sc.channel,
            pos,
            ori,
            space.pattern,
            space.tx_power_dbm,
            site.rx_xyz_m,
            site.rx_orientation_deg,
            site.rx_patterns,
        )

    return fn


def oracle_window(
    attack: str,
    run: int,
    seed: int,
    sigma_db: float,
    n_receivers: int,
    window_s: float,
    prefix_s: float = 0.5,
) -> OracleResult:
    """The oracle bounds (module docstring) over the first ``window_s`` of one attack run.

    The run is the detection experiment's (site seed ``seed + run``, the same random
    streams) with ``n_receivers`` receivers and an attacker that plans exactly
    ``window_s`` of attack (the strongest attacker for that window). The continuous
    explanations span ``prefix_s`` of the genuine prefix and the window: one device,
    one smooth path, one transmit power across the attack start.
    """
    from dataclasses import replace

    from radiopose.security.attacks import (
        ATTACKS,
        AttackConfig,
        SiteModel,
        attack_stream,
        genuine_path,
        scenario_for,
    )

    scenario = replace(scenario_for(sigma_db), n_receivers=n_receivers)
    site = SiteModel.build(scenario, seed + run)
    key = [seed + run, round(sigma_db * 1000), 2 + ATTACKS.index(attack)]
    stream = attack_stream(
        site, attack, sigma_db, AttackConfig(attack_s=window_s), np.random.default_rng(key)
    )
    # the genuine walk, prefix and continuation (the first draws of the run's stream)
    g_pos, g_ori = genuine_path(scenario, stream.t_s, np.random.default_rng(key))
    assert stream.sender_power_offset_db is not None
    power_db: FloatArray = stream.sender_power_offset_db
    z = scenario.z_m
    chan = channel_mean_fn(site)
    s2 = sigma_db**2

    def spans(lo_s: float) -> tuple[FloatArray, FloatArray, np.ndarray, float]:
        w = stream.t_s >= lo_s
        t, y = stream.t_s[w], stream.rss_dbm[w]
        mu1 = (
            chan(stream.sender_position_m[w], stream.sender_orientation_deg[w, 0])
            + power_db[w][:, None]
        )
        return t, y, w, float(np.nansum((y - mu1) ** 2))

    # H0 over the attack window alone: the best smooth path (may start anywhere)
    t, y, w, sse1 = spans(stream.t_attack_s)
    deg = azimuth_degree(window_s)
    grid = PoseGrid.build(chan, scenario.size_m, z)
    starts = grid.starts(t, y, deg)
    starts.append(path_params(g_pos[w], g_ori[w, 0], t, deg))
    starts.append(
        path_params(stream.sender_position_m[w], stream.sender_orientation_deg[w, 0], t, deg)
    )
    fit_w = fit_smooth_path(chan, t, y, starts, z, keep=len(starts))
    n_att = int(np.isfinite(y).sum())
    a_off = power_db[w]
    # H0 across the start: prefix_s of genuine traffic and the window, one path, one power
    t, y, w, sse1c = spans(stream.t_attack_s - prefix_s - 1e-9)
    r = y - chan(g_pos[w], g_ori[w, 0])
    sse_sp = float(np.nansum((r - np.nanmean(r)) ** 2))
    deg_c = azimuth_degree(window_s + prefix_s)
    starts = grid.starts(t, y, deg_c)
    starts.append(path_params(g_pos[w], g_ori[w, 0], t, deg_c))
    fit_c = fit_smooth_path(chan, t, y, starts, z, keep=len(starts))
    return OracleResult(
        attack,
        run,
        n_receivers,
        window_s,
        sigma_db,
        int(a_off.size),
        (fit_w.sse_db2 - sse1) / (2 * s2),
        (sse_sp - sse1c) / (2 * s2),
        (min(sse_sp, fit_c.sse_db2) - sse1c) / (2 * s2),
        (sse1 - n_att * s2) / (2 * s2),
        float(np.ptp(a_off)),
        float(np.mean(a_off)),
    )


# ----------------------------------------------------------------------------- the split test
@dataclass(frozen=True)
class SplitConfig:
    """The continuity test (:func:`split_scores`).

    Attributes
    ----------
    before_s, after_s
        Spans fitted before and after each candidate split time, seconds.
    stride_s
        Candidate splits every ``stride_s`` seconds.
    threshold_nats
        Alarm level of ``G_split``, nats.
    """

    before_s: float = 0.5
    after_s: float = 0.25
    stride_s: float = 0.1
    threshold_nats: float = 40.0


def _moved(params: FloatArray, t_old: FloatArray, t_new: FloatArray, z_m: float, degree: int):
    """``params`` of a path over ``t_old`` re-expressed (least squares) over ``t_new``;
    outside ``t_old`` the azimuth continues at its end rate (no polynomial blow-up)."""
    t0, half = 0.5 * (t_old[-1] + t_old[0]), max(0.5 * (t_old[-1] - t_old[0]), 1e-9)
    u = (t_new - t0) / half
    uc = np.clip(u, -1.0, 1.0)
    pos, az = smooth_path(params, u, z_m)
    coef = np.asarray(params, float)[4:]
    rate = legendre.legval(uc, legendre.legder(coef)) if coef.size > 1 else 0.0 * uc
    az = legendre.legval(uc, coef) + rate * (u - uc)
    return path_params(pos, az, t_new, degree)


@dataclass(frozen=True, eq=False)
class SplitScores:
    """Per candidate split: its time (s), when the test is decided (s), ``G_split`` (nats)."""

    split_s: FloatArray
    decided_s: FloatArray
    score_nats: FloatArray


def split_scores(
    mean_fn: MeanFn,
    grid: PoseGrid,
    t_s: FloatArray,
    rss_dbm: FloatArray,
    z_m: float,
    config: SplitConfig | None = None,
    nfev: int = 30,
) -> SplitScores:
    """The continuity test over a track: at every candidate split ``s``, one device on one
    smooth path at one power over ``[s − before_s, s + after_s)`` against two (one
    before ``s``, another after)::

        G_split = ½ (SSE_joint − SSE_before − SSE_after) / σ̂²

    (nats; σ̂² from the packets' consecutive differences over the span,
    :func:`window_noise_var_db2`). Decided at ``s + after_s``. Each fit is started
    from the previous split's fits (moved in time), the other fits of the split, and
    for the ``after`` span the best static poses of ``grid``.
    """
    cfg = config or SplitConfig()
    t = np.asarray(t_s, float)
    y = np.asarray(rss_dbm, float)
    db = azimuth_degree(cfg.before_s)
    da = azimuth_degree(cfg.after_s)
    dj = azimuth_degree(cfg.before_s + cfg.after_s)
    splits = np.arange(t[0] + cfg.before_s, t[-1] - cfg.after_s + 1e-9, cfg.stride_s)
    scores = np.full(splits.size, np.nan)
    prev: dict[str, tuple[FloatArray, FloatArray]] = {}
    for i, s in enumerate(splits):
        ib = (t >= s - cfg.before_s) & (t < s)
        ia = (t >= s) & (t < s + cfg.after_s)
        ij = ib | ia
        if ib.sum() < 10 or ia.sum() < 10:
            continue
        tb, ta, tj = t[ib], t[ia], t[ij]
        if prev:
            starts_b = [_moved(*prev[k], tb, z_m, db) for k in ("b", "j")]
        else:
            starts_b = grid.starts(tb, y[ib], db)
        fb = fit_smooth_path(mean_fn, tb, y[ib], starts_b, z_m, keep=2, max_nfev=nfev)
        starts_a = [*grid.starts(ta, y[ia], da, n=3), _moved(fb.params, tb, ta, z_m, da)]
        starts_a += [_moved(*prev[k], ta, z_m, da) for k in ("a", "j") if k in prev]
        fa = fit_smooth_path(mean_fn, ta, y[ia], starts_a, z_m, keep=2, max_nfev=nfev)
        starts_j = [_moved(fb.params, tb, tj, z_m, dj), _moved(fa.params, ta, tj, z_m, dj)]
        starts_j += grid.starts(tj, y[ij], dj, n=2)
        if "j" in prev:
            starts_j.append(_moved(*prev["j"], tj, z_m, dj))
        fj = fit_smooth_path(mean_fn, tj, y[ij], starts_j, z_m, keep=2, max_nfev=nfev)
        # the split's own fits may not beat the joint path on their spans: refine from it
        for name, idx, deg in (("b", ib, db), ("a", ia, da)):
            f = fb if name == "b" else fa
            g = fit_smooth_path(
                mean_fn, t[idx], y[idx], [_moved(fj.params, tj, t[idx], z_m, deg)], z_m, 1, nfev
            )
            if g.sse_db2 < f.sse_db2:
                if name == "b":
                    fb = g
                else:
                    fa = g
        prev = {"b": (fb.params, tb), "a": (fa.params, ta), "j": (fj.params, tj)}
        var = window_noise_var_db2(y[ij])
        scores[i] = 0.5 * (fj.sse_db2 - fb.sse_db2 - fa.sse_db2) / var
    return SplitScores(splits, splits + cfg.after_s, scores)


@dataclass(frozen=True, eq=False)
class SplitTrack:
    """The continuity test over one stream of the detection experiment."""

    kind: str  # "fixed", "moving" or "genuine"
    run: int
    sigma_db: float
    t_attack_s: float  # inf for a genuine chunk
    genuine_s: float  # genuine traffic behind the test's decisions, seconds
    scores: SplitScores
    cusum_onsets_s: FloatArray  # the shipped CUSUM's alarm onsets on the same packets


def split_track(
    kind: str,
    run: int,
    seed: int,
    sigma_db: float,
    chunk_s: float = 30.0,
    warmup_s: float = 1.0,
    window_s: float = 0.5,
    config: SplitConfig | None = None,
) -> SplitTrack:
    """:func:`split_scores` over one attack run (up to ``window_s`` after its start) or
    one genuine chunk of the detection experiment (the same sites and random streams
    as :func:`radiopose.security.detect_experiment.run_task`; chunk ``run`` rotates
    linearly, periodically or beyond the bound in turn). Splits in the first
    ``warmup_s`` of the stream are not scored (the fits start cold there)."""
    from radiopose.security.attacks import (
        ATTACKS,
        AttackConfig,
        SiteModel,
        attack_stream,
        genuine_stream,
        scenario_for,
    )
    from radiopose.security.detection import DetectorConfig, score_track

    cfg = config or SplitConfig()
    rotations = ("linear", "periodic", "fast")
    if kind == "genuine":
        site = SiteModel.build(scenario_for(sigma_db, rotations[run % 3]), seed + run)
        rng = np.random.default_rng([seed + run, round(sigma_db * 1000), 1])
        stream = genuine_stream(site, chunk_s, sigma_db, rng)
        keep = np.ones(stream.t_s.size, bool)
    else:
        site = SiteModel.build(scenario_for(sigma_db), seed + run)
        rng = np.random.default_rng([seed + run, round(sigma_db * 1000), 2 + ATTACKS.index(kind)])
        stream = attack_stream(site, kind, sigma_db, AttackConfig(), rng)
        keep = stream.t_s <= stream.t_attack_s + window_s
    t, y = stream.t_s[keep], stream.rss_dbm[keep]
    z = site.sim.config.z_m
    grid = PoseGrid.build(site.expected_dbm, site.sim.config.size_m, z)
    sc = split_scores(site.expected_dbm, grid, t, y, z, cfg)
    ok = sc.split_s >= t[0] + warmup_s
    sc = SplitScores(sc.split_s[ok], sc.decided_s[ok], sc.score_nats[ok])
    before = sc.decided_s < stream.t_attack_s
    genuine_s = float(before.sum() * cfg.stride_s)
    cus = score_track(stream.t_s, stream.rss_dbm, DetectorConfig())
    onsets = stream.t_s[cus.alarm_onsets()]
    return SplitTrack(kind, run, sigma_db, stream.t_attack_s, genuine_s, sc, onsets)


def split_outcomes(
    tracks: Sequence[SplitTrack], threshold_nats: float, window_s: float = 0.5
) -> dict[str, object]:
    """At one threshold: per attack the fraction detected within ``window_s`` (the split
    test alone and OR the CUSUM) and the false-alarm onsets on genuine traffic."""
    fa = 0
    fa_or = 0
    hours = sum(tr.genuine_s for tr in tracks) / 3600.0
    det: dict[str, list[bool]] = {}
    det_or: dict[str, list[bool]] = {}
    for tr in tracks:
        sc = tr.scores
        above = np.nan_to_num(sc.score_nats, nan=-np.inf) >= threshold_nats
        onset = above & ~np.concatenate([[False], above[:-1]])
        pre = sc.decided_s < tr.t_attack_s
        fa += int(np.sum(onset & pre))
        fa_or += int(np.sum(onset & pre)) + int(np.sum(tr.cusum_onsets_s < tr.t_attack_s))
        if tr.kind != "genuine":
            inside = (sc.decided_s >= tr.t_attack_s) & (sc.decided_s <= tr.t_attack_s + window_s)
            hit = bool(np.any(above & inside))
            c = tr.cusum_onsets_s
            hit_c = bool(np.any((c >= tr.t_attack_s) & (c <= tr.t_attack_s + window_s)))
            det.setdefault(tr.kind, []).append(hit)
            det_or.setdefault(tr.kind, []).append(hit or hit_c)
    out: dict[str, object] = {"threshold_nats": threshold_nats, "genuine_h": hours}
    for k in sorted(det):
        out[f"{k}_detected"] = float(np.mean(det[k]))
        out[f"{k}_detected_or_cusum"] = float(np.mean(det_or[k]))
    out["false_alarms"] = fa
    out["false_alarms_per_hour"] = fa / hours if hours else float("nan")
    out["false_alarms_or_cusum_per_hour"] = fa_or / hours if hours else float("nan")
    return out
