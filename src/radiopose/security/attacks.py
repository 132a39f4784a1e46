"""Spoofing attacks on a tracked device, as packet streams (issue 19).

Each attack run simulates one site (:func:`radiopose.simulate.simulate`, the
paper's standard scenario), lets the genuine device walk for ``prefix_s``
(a packet every ``interval_ms``, the simulator's channel and Gaussian noise σ),
and then hands the transmitter address to an attacker at ``t_attack_s``:

``fixed``
    The paper's attacker: one position at least ``min_distance_m`` from every
    point of the spoofed path (the genuine device's continuation), chosen with
    the system's own model (survey map, enrolled pattern: the attacker knows the
    site, :mod:`radiopose.security.attacker`'s assumptions 1–2); per packet the
    azimuth within the rotation bound of the previous one (a Viterbi pass over
    1° steps) and the free power ``δ = clip(mean residual, ±Δ)`` that best match
    the spoofed pose's expected RSS. The genuine device is silent.
``moving``
    The same attacker also moving: per packet it picks, among the poses it can
    reach within the movement and rotation bounds, the one whose best-power
    RSS is closest to the spoofed pose's (greedy, the system's off-grid model).
``clone``
    The ``fixed`` attacker, spoofing a walk of its own (it shows the victim
    elsewhere), sending while the genuine device keeps sending: two devices
    with one address, packets interleaved.
``silent``
    The ``fixed`` attacker that transmits only the packets it can match: where
    its planned pose and best power give an expected RSS within
    ``match_rms_db`` (RMS over receivers, the system's model) of the spoofed
    pose's, silent otherwise — the strongest attacker of the paper analysis
    (experiment 3: it sends only when it matches, ``docs/security.md``). Its
    evidence is its silences.
``replay``
    A recorder ``min_distance_m`` or more from the victim captures the victim's
    packets during the prefix; from its own fixed pose the attacker replays them
    with the recorded power envelope (the power each packet was received with
    at the recorder, relative to its mean) — one transmitter, so every receiver
    sees the attacker's position.

Every attacker but ``silent`` sends with the genuine device's cadence (no
silent gaps: the hardest case for a gap test). Packets are generated with the simulator's
channel (log-distance path loss, both antennas' patterns), not with the survey
map the attacker planned with.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from radiopose.filtering import FilterModel
from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.likelihood import candidate_space, make_scorer
from radiopose.simulate import ScenarioConfig, Simulation, link_rss_dbm, simulate
from radiopose.simulate.trajectories import MotionConfig, rotation_path, straight_path
from radiopose.units import FloatArray, wrap_deg

ATTACKS: tuple[str, ...] = ("fixed", "moving", "clone", "replay", "silent")
"""Attack names, in the issue's order (``silent``: the paper analysis's strongest)."""


@dataclass(frozen=True)
class AttackConfig:
    """Settings of one attack run.

    Attributes
    ----------
    scenario
        The simulated site (standard scenario; ``noise_db`` is replaced by σ).
    prefix_s
        Genuine traffic before the attack starts, seconds.
    attack_s
        Length of the attack, seconds.
    min_distance_m
        The attacker stands at least this far from every spoofed position, metres.
    power_range_db
        The attacker's power lies within the enrolled power ± this, dB.
    max_speed_mps, max_rate_dps
        The attacker's physical bounds (the tracker's: 10 m/s, 360°/s).
    position_step_m
        Grid of positions the ``fixed`` attacker chooses from, metres.
    match_rms_db
        The ``silent`` attacker sends a packet only if its expected RSS lies within
        this RMS of the spoofed pose's, dB.
    """

    scenario: ScenarioConfig = field(default_factory=lambda: ScenarioConfig(duration_s=0.005))
    prefix_s: float = 2.0
    attack_s: float = 1.0
    min_distance_m: float = 5.0
    power_range_db: float = 10.0
    max_speed_mps: float = 10.0
    max_rate_dps: float = 360.0
    position_step_m: float = 0.5
    match_rms_db: float = 1.0


@dataclass(frozen=True, eq=False)
class PacketStream:
    """Packets of one transmitter address: times ``(n,)`` s, RSS ``(n, n_rx)`` dBm,
    which source sent each (``0`` genuine, ``1`` attacker), the true sender pose and
    its transmit power offset from the enrolled power (dB; ``None``: 0 throughout)."""

    t_s: FloatArray
    rss_dbm: FloatArray
    source: np.ndarray
    sender_position_m: FloatArray
    sender_orientation_deg: FloatArray
    t_attack_s: float
    sender_power_offset_db: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class SiteModel:
    """A simulated site with the system's model of its device (built once per run)."""

    sim: Simulation
    model: FilterModel
    rx_xyz_m: FloatArray
    rx_orientation_deg: FloatArray
    rx_patterns: tuple

    @classmethod
    def build(cls, scenario: ScenarioConfig, seed: int) -> SiteModel:
        sim = simulate(scenario, seed=seed)
        site = sim.site
        space = candidate_space(site, site.devices[0].transmitter)
        model = FilterModel.build(site, space, make_scorer("numba", space))
        rx = site.receivers
        return cls(
            sim,
            model,
            np.array([[r.x_m, r.y_m, r.z_m] for r in rx]),
            np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in rx]),
            tuple(site.patterns[r.pattern] for r in rx),
        )

    def rss_dbm(
        self,
        position_m: FloatArray,
        orientation_deg: FloatArray,
        power_offset_db: FloatArray | float,
        noise_db: float,
        rng: np.random.Generator,
    ) -> FloatArray:
        """Noisy RSS ``(n, n_rx)`` of the device's pattern at poses ``(n, 3)`` through the
        simulator's channel, transmit power enrolled + ``power_offset_db``."""
        sc = self.sim.config
        space = self.model.space
        rss = link_rss_dbm(
            sc.channel,
            position_m,
            orientation_deg,
            space.pattern,
            space.tx_power_dbm + np.asarray(power_offset_db, float),
            self.rx_xyz_m,
            self.rx_orientation_deg,
            self.rx_patterns,
        )
        return rss + rng.normal(0.0, noise_db, rss.shape)

    def expected_dbm(self, position_m: FloatArray, azimuth_deg: FloatArray) -> FloatArray:
        """The system's expected RSS ``(n, n_rx)`` (survey map, enrolled pattern, off the grid)."""
        n = position_m.shape[0]
        S = np.zeros((n, K.N_COLUMNS))
        S[:, K.X_M : K.Z_M + 1] = position_m
        S[:, K.AZIMUTH_RAD] = np.deg2rad(azimuth_deg)
        rx = np.arange(self.rx_xyz_m.shape[0], dtype=np.int64)
        return self.model.expected(S, rx)


def genuine_path(
    scenario: ScenarioConfig, t_s: FloatArray, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """Positions ``(n, 3)`` and orientations ``(n, 3)`` of the simulator's walk."""
    sc = scenario
    pos = straight_path(rng, t_s, (0.0, sc.size_m, 0.0, sc.size_m), sc.z_m, sc.motion)
    return pos, rotation_path(rng, t_s, sc.motion)


def genuine_stream(
    site: SiteModel, duration_s: float, noise_db: float, rng: np.random.Generator
) -> PacketStream:
    """The genuine device alone for ``duration_s`` (its motion: the scenario's)."""
    sc = site.sim.config
    n = round(duration_s / (sc.interval_ms / 1000.0))
    t = np.arange(n, dtype=np.float64) * (sc.interval_ms / 1000.0)
    pos, ori = genuine_path(sc, t, rng)
    rss = site.rss_dbm(pos, ori, 0.0, noise_db, rng)
    return PacketStream(t, rss, np.zeros(t.size, np.int8), pos, ori, np.inf)


def _mismatch_db2(
    expected_dbm: FloatArray, target_dbm: FloatArray, power_range_db: float
) -> tuple[FloatArray, FloatArray]:
    """Best-power MSE and power of attacker RSS ``(..., n_rx)`` against targets."""
    e = target_dbm - expected_dbm
    off = np.clip(e.mean(axis=-1), -power_range_db, power_range_db)
    d = e - off[..., None]
    return np.mean(d * d, axis=-1), off


def _far_positions(site: SiteModel, spoofed_m: FloatArray, cfg: AttackConfig) -> FloatArray:
    """Grid positions ``(m, 3)`` at least ``min_distance_m`` from every spoofed position."""
    sc = site.sim.config
    axis = np.arange(0.0, sc.size_m + 1e-9, cfg.position_step_m)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, sc.z_m)])
    d = np.min(np.linalg.norm(pts[:, None, :2] - spoofed_m[None, ::10, :2], axis=2), axis=1)
    return pts[d >= cfg.min_distance_m]


def fixed_attacker(
    site: SiteModel, target_dbm: FloatArray, spoofed_m: FloatArray, dt_s: float, cfg: AttackConfig
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Plan the ``fixed`` attack: position, per-packet azimuth and power offset.

    Parameters
    ----------
    target_dbm
        ``(n, n_rx)`` the system's expected RSS of the spoofed poses (enrolled power).
    spoofed_m
        ``(n, 3)`` the spoofed positions.

    Returns
    -------
    position_m ``(3,)``, azimuth_deg ``(n,)``, offset_db ``(n,)``.
    """
    pts = _far_positions(site, spoofed_m, cfg)
    az = np.arange(360.0)
    # choose the position on every 10th target with the azimuth free per packet
    sub = target_dbm[::10]
    best_cost = np.inf
    best_p = pts[0]
    for chunk in np.array_split(np.arange(pts.shape[0]), max(1, pts.shape[0] // 64)):
        P = np.repeat(pts[chunk], az.size, axis=0)
        A = np.tile(az, chunk.size)
        ex = site.expected_dbm(P, A).reshape(chunk.size, az.size, 1, -1)
        mse, _ = _mismatch_db2(ex, sub[None, None, :, :], cfg.power_range_db)
        cost = np.nanmin(mse, axis=1).sum(axis=1)  # (chunk,)
        j = int(np.nanargmin(cost))
        if cost[j] < best_cost:
            best_cost, best_p = float(cost[j]), pts[chunk[j]]
    # Viterbi over 1° azimuths at that position, rotation within the bound
    ex = site.expected_dbm(np.repeat(best_p[None, :], az.size, axis=0), az)  # (360, n_rx)
    mse, off = _mismatch_db2(ex[None, :, :], target_dbm[:, None, :], cfg.power_range_db)
    mse = np.nan_to_num(mse, nan=1e6)
    reach = max(1, int(np.floor(cfg.max_rate_dps * dt_s)))
    n = target_dbm.shape[0]
    back = np.zeros((n, az.size), np.int64)
    cost = mse[0].copy()
    for i in range(1, n):
        prev = np.full(az.size, np.inf)
        arg = np.zeros(az.size, np.int64)
        for s in range(-reach, reach + 1):
            c = np.roll(cost, s)
            better = c < prev
            prev = np.where(better, c, prev)
            arg = np.where(better, (np.arange(az.size) - s) % az.size, arg)
        back[i] = arg
        cost = prev + mse[i]
    path = np.empty(n, np.int64)
    path[-1] = int(np.argmin(cost))
    for i in range(n - 1, 0, -1):
        path[i - 1] = back[i, path[i]]
    return best_p, az[path], off[np.arange(n), path]


def moving_attacker(
    site: SiteModel,
    target_dbm: FloatArray,
    start_m: FloatArray,
    start_azimuth_deg: float,
    spoofed_m: FloatArray,
    dt_s: float,
    cfg: AttackConfig,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Plan the ``moving`` attack greedily from ``start``: per packet the reachable
    pose (a 5 × 5 × 5 lattice of moves within the bounds) with the best-power
    RSS closest to the target's, kept ``min_distance_m`` from the spoofed position.

    Returns positions ``(n, 3)``, azimuths ``(n,)``, offsets ``(n,)``.
    """
    step_m = cfg.max_speed_mps * dt_s
    step_deg = cfg.max_rate_dps * dt_s
    u = np.linspace(-1.0, 1.0, 5)
    mx, my, ma = (g.ravel() for g in np.meshgrid(u, u, u, indexing="ij"))
    keep = mx**2 + my**2 <= 1.0 + 1e-9
    mx, my, ma = mx[keep] * step_m, my[keep] * step_m, ma[keep] * step_deg
    size = site.sim.config.size_m
    n = target_dbm.shape[0]
    pos = np.empty((n, 3))
    azs = np.empty(n)
    offs = np.empty(n)
    p = np.asarray(start_m, float).copy()
    a = float(start_azimuth_deg)
    for i in range(n):
        P = np.column_stack(
            [np.clip(p[0] + mx, 0, size), np.clip(p[1] + my, 0, size), np.full(mx.size, p[2])]
        )
        A = wrap_deg(a + ma)
        mse, off = _mismatch_db2(
            site.expected_dbm(P, A), target_dbm[i][None, :], cfg.power_range_db
        )
        far = np.hypot(P[:, 0] - spoofed_m[i, 0], P[:, 1] - spoofed_m[i, 1]) >= cfg.min_distance_m
        mse = np.where(far & np.isfinite(mse), mse, np.inf)
        j = int(np.argmin(mse))
        if not np.isfinite(mse[j]):
            j = int(np.argmin(np.abs(mx) + np.abs(my) + np.abs(ma)))  # stay put
            off[j] = offs[i - 1] if i else 0.0
        p, a = P[j], float(A[j])
        pos[i], azs[i], offs[i] = p, a, off[j]
    return pos, azs, offs


def attack_stream(
    site: SiteModel, attack: str, noise_db: float, cfg: AttackConfig, rng: np.random.Generator
) -> PacketStream:
    """One attack run: genuine prefix, then ``attack`` (module docstring)."""
    if attack not in ATTACKS:
        raise ValueError(f"unknown attack {attack!r} (known: {', '.join(ATTACKS)})")
    sc = site.sim.config
    dt = sc.interval_ms / 1000.0
    n_pre = round(cfg.prefix_s / dt)
    n_att = round(cfg.attack_s / dt)
    t = np.arange(n_pre + n_att, dtype=np.float64) * dt
    pos, ori = genuine_path(sc, t, rng)
    t_attack = float(t[n_pre])
    genuine_rss = site.rss_dbm(pos, ori, 0.0, noise_db, rng)
    spoofed, spoofed_ori = pos[n_pre:], ori[n_pre:]
    if attack == "clone":  # the attacker shows the victim elsewhere: a walk of its own
        other_p, other_o = genuine_path(sc, t, rng)
        spoofed, spoofed_ori = other_p[n_pre:], other_o[n_pre:]
    target = site.expected_dbm(spoofed, spoofed_ori[:, 0])
    zeros = np.zeros(n_att)
    if attack == "replay":
        recorder = _far_positions(site, pos, cfg)
        rec = recorder[rng.integers(recorder.shape[0])] if recorder.size else pos[0] + 5.0
        a_pos = np.repeat(rec[None, :], n_att, axis=0)
        a_az = np.full(n_att, rng.uniform(0.0, 360.0))
        # what the recorder (a phone-like antenna, receiver 1's) heard of the victim
        heard = link_rss_dbm(
            sc.channel,
            pos[:n_pre],
            ori[:n_pre],
            site.model.space.pattern,
            site.model.space.tx_power_dbm,
            rec[None, :],
            np.zeros((1, 3)),
            site.rx_patterns[:1],
        )[:, 0]
        heard = heard + rng.normal(0.0, noise_db, heard.shape)
        env = np.resize(heard - heard.mean(), n_att)
        a_off = np.clip(env, -cfg.power_range_db, cfg.power_range_db)
    elif attack == "moving":
        p0, az0, _ = fixed_attacker(site, target[:20], spoofed[:20], dt, cfg)
        a_pos, a_az, a_off = moving_attacker(site, target, p0, float(az0[0]), spoofed, dt, cfg)
    else:
        p0, a_az, a_off = fixed_attacker(site, target, spoofed, dt, cfg)
        a_pos = np.repeat(p0[None, :], n_att, axis=0)
    a_ori = np.column_stack([a_az, zeros, zeros])
    a_rss = site.rss_dbm(a_pos, a_ori, a_off, noise_db, rng)
    a_off = np.broadcast_to(np.asarray(a_off, float), (n_att,))
    if attack == "silent":  # only the packets it matches within match_rms_db
        mse, _ = _mismatch_db2(site.expected_dbm(a_pos, a_az), target, cfg.power_range_db)
        send = np.nan_to_num(mse, nan=np.inf) <= cfg.match_rms_db**2
        keep = np.concatenate([np.ones(n_pre, bool), send])
        src = np.concatenate([np.zeros(n_pre, np.int8), np.ones(n_att, np.int8)])
        return PacketStream(
            t[keep],
            np.vstack([genuine_rss[:n_pre], a_rss])[keep],
            src[keep],
            np.vstack([pos[:n_pre], a_pos])[keep],
            np.vstack([ori[:n_pre], a_ori])[keep],
            t_attack,
            np.concatenate([np.zeros(n_pre), a_off])[keep],
        )
    if attack == "clone":  # both send: the attacker between the genuine packets
        t_all = np.concatenate([t, t[n_pre:] + 0.5 * dt])
        rss_all = np.vstack([genuine_rss, a_rss])
        src = np.concatenate([np.zeros(t.size, np.int8), np.ones(n_att, np.int8)])
        p_all = np.vstack([pos, a_pos])
        o_all = np.vstack([ori, a_ori])
        order = np.argsort(t_all, kind="stable")
        off_all = np.concatenate([np.zeros(t.size), a_off])
        return PacketStream(
            t_all[order],
            rss_all[order],
            src[order],
            p_all[order],
            o_all[order],
            t_attack,
            off_all[order],
        )
    src = np.concatenate([np.zeros(n_pre, np.int8), np.ones(n_att, np.int8)])
    return PacketStream(
        t,
        np.vstack([genuine_rss[:n_pre], a_rss]),
        src,
        np.vstack([pos[:n_pre], a_pos]),
        np.vstack([ori[:n_pre], a_ori]),
        t_attack,
        np.concatenate([np.zeros(n_pre), a_off]),
    )


def scenario_for(sigma_db: float, rotation: str = "linear") -> ScenarioConfig:
    """The standard scenario with noise σ and a rotation kind (``linear``,
    ``periodic`` or ``fast``: beyond the rotation bound)."""
    return replace(
        ScenarioConfig(duration_s=0.005),
        noise_db=sigma_db,
        motion=replace(MotionConfig(), rotation=rotation),  # type: ignore[arg-type]
    )
