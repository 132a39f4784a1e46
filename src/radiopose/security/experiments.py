"""The paper's four spoofing experiments ("Security Analysis"), one run at a time.

Each run simulates its own site (:func:`radiopose.simulate.simulate` with the
run's seed: 4 receivers at random positions, the paper's 20 m × 20 m area,
0.1 m × 1° candidate grid) and returns tidy rows (:class:`RunOutput`):

1. ``match`` — same-pattern match probability: ``n_targets`` random target
   candidates; does any pose ``≥ d`` away match (:func:`~radiopose.security.attacker.find_matches`)?
2. ``pattern`` — the same with the attacker's real pattern drawn independently
   of the enrolled one (another smartphone-like pattern).
3. ``path`` — a straight target path (the simulator's motion model, a packet
   every ``interval_ms``); the attacker must hop between matching poses within
   the movement and rotation limits (× each of ``limit_scales``), silent at
   most ``t/2``; how many packets until it fails (:class:`~radiopose.security.attacker.PathSearch`).
4. ``e2e`` — the longest feasible spoofed sequence of experiment 3 (limits × 1)
   is turned into packets with the *simulator's* channel (the attacker at its
   grid pose, its best power, Gaussian noise) and fed to the real tracker
   (``full``); the genuine device on the same path is fed alongside for comparison.

:func:`run_experiment` is a pure function of ``(experiment, run, config)``, so
runs can be spread over processes (:mod:`radiopose.security.runner`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.likelihood import CandidateSpace, candidate_space, expected_rss_dbm
from radiopose.packets import PacketObservation
from radiopose.patterns.synthetic import smartphone_like
from radiopose.security.attacker import (
    AttackerModel,
    MatchResult,
    MatchTable,
    MotionLimits,
    PathAttack,
    PathSearch,
    attacker_space,
    build_match_table,
    find_matches,
    system_scorer,
    system_threshold_db2,
)
from radiopose.simulate import ScenarioConfig, Simulation, link_rss_dbm, simulate
from radiopose.simulate.trajectories import rotation_path, straight_path
from radiopose.tracker import Tracker, TrackerConfig
from radiopose.units import FloatArray, angle_diff_deg, wrap_deg

EXPERIMENTS: tuple[str, ...] = ("match", "pattern", "path", "e2e")
"""Experiment names, in the issue's order (also accepted as ``1``–``4``)."""

ALIASES = {"1": "match", "2": "pattern", "3": "path", "4": "e2e"}

Row = dict[str, Any]


@dataclass(frozen=True)
class SpoofConfig:
    """Settings of the spoofing experiments (defaults: the paper's, see ``docs/security.md``).

    Attributes
    ----------
    scenario
        The simulated site of each run (paper's standard scenario).
    attacker
        Distance ``d``, power range ``Δ`` and top-k.
    n_targets
        Random targets per run (experiments 1 and 2).
    target_noise_db
        σ of Gaussian noise on the target's RSS before matching (0: the
        system's expected RSS, the paper's setting).
    path_packets
        Longest target path examined, packets (experiment 3).
    limit_scales
        Fractions of the tracker's movement/rotation bounds the attacker keeps to.
    packet_noise_db
        σ of the RSS noise on the packets fed to the tracker (experiment 4), dB.
    follow_radius_m
        The reported path "follows" the spoofed one while within this distance, metres.
    tracker
        Tracker settings of experiment 4 (paper defaults).
    seed
        Base seed; run ``j`` uses site seed ``seed + j``.
    """

    scenario: ScenarioConfig = field(default_factory=lambda: ScenarioConfig(duration_s=0.005))
    attacker: AttackerModel = field(default_factory=AttackerModel)
    n_targets: int = 100
    target_noise_db: float = 0.0
    path_packets: int = 400
    limit_scales: tuple[float, ...] = (1.0, 0.1)
    packet_noise_db: float = 1.0
    follow_radius_m: float = 1.0
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        check_setting_types(self, "spoof")  # finite numbers, integers (NaN, inf, 2.5)
        checks = [
            ("n_targets", self.n_targets >= 1),
            ("target_noise_db", 0 <= self.target_noise_db <= 60),
            ("path_packets", self.path_packets >= 1),
            ("limit_scales", len(self.limit_scales) >= 1 and min(self.limit_scales) > 0),
            ("packet_noise_db", 0 <= self.packet_noise_db <= 60),
            ("follow_radius_m", self.follow_radius_m > 0),
            ("seed", 0 <= self.seed < 2**63),
        ]
        for name, ok in checks:
            if not ok:
                raise InputError(f"spoof setting {name} = {getattr(self, name)!r} is out of range")

    def quick(self) -> SpoofConfig:
        """The ``--quick`` variant: 25 targets per run, paths of at most 200 packets."""
        return replace(
            self, n_targets=min(self.n_targets, 25), path_packets=min(self.path_packets, 200)
        )


@dataclass(frozen=True, eq=False)
class RunOutput:
    """Tidy rows of one run, by table name (``targets``, ``paths``, …)."""

    experiment: str
    run: int
    tables: dict[str, list[Row]]
    elapsed_s: float = 0.0


def parse_experiments(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Experiment names or numbers → canonical names (all if empty), in order."""
    if not names:
        return EXPERIMENTS
    out = []
    for n in names:
        key = ALIASES.get(n.strip().lower(), n.strip().lower())
        if key not in EXPERIMENTS:
            raise InputError(f"unknown experiment {n!r} (known: 1 match, 2 pattern, 3 path, 4 e2e)")
        if key not in out:
            out.append(key)
    return tuple(sorted(out, key=EXPERIMENTS.index))


# ----------------------------------------------------------------------------- helpers
def run_site(config: SpoofConfig, run: int) -> Simulation:
    """The simulated site of run ``run`` (seed ``config.seed + run``)."""
    return simulate(config.scenario, seed=config.seed + run)


def _rng(config: SpoofConfig, run: int, experiment: str) -> np.random.Generator:
    return np.random.default_rng([config.seed, run, EXPERIMENTS.index(experiment) + 1])


def _space(sim: Simulation) -> CandidateSpace:
    return candidate_space(sim.site, sim.site.devices[0].transmitter)


def _target_rss(
    space: CandidateSpace, cand: int, noise_db: float, rng: np.random.Generator
) -> FloatArray:
    p, o = space.split(np.array([cand]))
    y = expected_rss_dbm(space, p, o)[0]
    if noise_db > 0:
        y = y + rng.normal(0.0, noise_db, y.shape)
    return y


def _match(
    space: CandidateSpace,
    table: MatchTable,
    scorer: object,
    cand: int,
    config: SpoofConfig,
    rng: np.random.Generator,
) -> MatchResult:
    y = _target_rss(space, cand, config.target_noise_db, rng)
    tau = system_threshold_db2(scorer, y, config.attacker.k)
    return find_matches(
        table, y, tau, space.candidate_positions_m(np.array([cand]))[0], config.attacker
    )


def snap_to_grid(
    space: CandidateSpace, positions_m: FloatArray, azimuth_deg: FloatArray
) -> np.ndarray:
    """Nearest grid candidate ``(n,)`` of poses (azimuth-only grids: pitch = roll = 0)."""
    pts = space.positions_m
    x = np.unique(pts[:, 0])
    y = np.unique(pts[:, 1])
    step_x = x[1] - x[0] if x.size > 1 else 1.0
    step_y = y[1] - y[0] if y.size > 1 else 1.0
    ix = np.clip(np.rint((positions_m[:, 0] - x[0]) / step_x), 0, x.size - 1).astype(np.int64)
    iy = np.clip(np.rint((positions_m[:, 1] - y[0]) / step_y), 0, y.size - 1).astype(np.int64)
    n_az = int(np.sum(np.all(space.orientations_deg[:, 1:] == 0.0, axis=1)))
    ia = np.rint(wrap_deg(azimuth_deg) / (360.0 / n_az)).astype(np.int64) % n_az
    return (ix * y.size + iy) * space.n_orientations + ia


# ----------------------------------------------------------------------------- 1 and 2
def _match_run(config: SpoofConfig, run: int, experiment: str) -> dict[str, list[Row]]:
    sim = run_site(config, run)
    rng = _rng(config, run, experiment)
    space = _space(sim)
    pattern = None
    if experiment == "pattern":
        pattern = smartphone_like(
            rng, "attacker", range_db=rng.uniform(*config.scenario.device_range_db)
        )
    table = build_match_table(attacker_space(space, pattern))
    scorer = system_scorer(space)
    targets = rng.integers(0, space.n_candidates, config.n_targets)
    rows, example = [], []
    best_example = -1
    for t_i, cand in enumerate(targets):
        res = _match(space, table, scorer, int(cand), config, rng)
        tp = space.candidate_positions_m(np.array([cand]))[0]
        ta = space.candidate_orientations_deg(np.array([cand]))[0, 0]
        row: Row = {
            "experiment": experiment,
            "run": run,
            "target": t_i,
            "x_m": tp[0],
            "y_m": tp[1],
            "azimuth_deg": ta,
            "threshold_db2": res.threshold_db2,
            "matched": int(res.any),
            "n_match_candidates": len(res),
            "n_match_positions": int(np.unique(space.split(res.candidate_idx)[0]).size),
        }
        if res.any:
            bp = space.candidate_positions_m(res.candidate_idx[:1])[0]
            row |= {
                "best_mse_db2": res.mse_db2[0],
                "best_x_m": bp[0],
                "best_y_m": bp[1],
                "best_azimuth_deg": space.candidate_orientations_deg(res.candidate_idx[:1])[0, 0],
                "best_offset_db": res.offset_db[0],
                "best_distance_m": float(np.linalg.norm(bp - tp)),
            }
        else:
            row |= dict.fromkeys(
                (
                    "best_mse_db2",
                    "best_x_m",
                    "best_y_m",
                    "best_azimuth_deg",
                    "best_offset_db",
                    "best_distance_m",
                ),
                np.nan,
            )
        rows.append(row)
        if run == 0 and row["n_match_positions"] > best_example:
            best_example = row["n_match_positions"]
            mp = space.candidate_positions_m(res.candidate_idx)
            mo = space.candidate_orientations_deg(res.candidate_idx)
            example = [
                {
                    "experiment": experiment,
                    "run": run,
                    "target": t_i,
                    "target_x_m": tp[0],
                    "target_y_m": tp[1],
                    "target_azimuth_deg": ta,
                    "x_m": p[0],
                    "y_m": p[1],
                    "azimuth_deg": o[0],
                    "mse_db2": m,
                    "offset_db": d,
                }
                for p, o, m, d in zip(mp, mo, res.mse_db2, res.offset_db, strict=True)
            ]
    return {"targets": rows, "example_matches": example, "sites": _site_rows(sim, run)}


def _site_rows(sim: Simulation, run: int) -> list[Row]:
    return [
        {
            "run": run,
            "receiver_id": r.receiver_id,
            "x_m": r.x_m,
            "y_m": r.y_m,
            "azimuth_deg": r.azimuth_deg,
        }
        for r in sim.site.receivers
    ]


# ----------------------------------------------------------------------------- 3 and 4
def target_path(config: SpoofConfig, rng: np.random.Generator) -> tuple[FloatArray, ...]:
    """Times ``(n,)``, positions ``(n, 3)``, orientations ``(n, 3)`` of a straight target path."""
    sc = config.scenario
    t = np.arange(config.path_packets, dtype=np.float64) * (sc.interval_ms / 1000.0)
    pos = straight_path(rng, t, (0.0, sc.size_m, 0.0, sc.size_m), sc.z_m, sc.motion)
    ori = rotation_path(rng, t, sc.motion)
    return t, pos, ori


def _path_run(config: SpoofConfig, run: int, end_to_end: bool) -> dict[str, list[Row]]:
    sim = run_site(config, run)
    rng = _rng(config, run, "path")
    space = _space(sim)
    table = build_match_table(space)
    scorer = system_scorer(space)
    t, pos, ori = target_path(config, rng)
    snapped = snap_to_grid(space, pos, ori[:, 0])
    searches = {
        s: PathSearch(MotionLimits.of(config.tracker, scale=s)) for s in config.limit_scales
    }
    cache: dict[int, MatchResult] = {}
    for i in range(t.size):
        alive = [s for s in searches.values() if s.alive]
        if not alive:
            break
        c = int(snapped[i])
        if c not in cache:
            cache[c] = _match(space, table, scorer, c, config, rng)
        m = cache[c]
        p = space.candidate_positions_m(m.candidate_idx)
        o = space.candidate_orientations_deg(m.candidate_idx)
        for s in alive:
            s.step(float(t[i]), p, o, m.candidate_idx)
    interval_s = config.scenario.interval_ms / 1000.0
    rows = []
    results: dict[float, PathAttack] = {}
    for scale, s in searches.items():
        res = s.result()
        results[scale] = res
        rows.append(
            {
                "run": run,
                "limit_scale": scale,
                "packets_until_failure": res.packets_until_failure,
                "failed": int(res.failed),
                "sustained_packets": res.sustained_packets,
                "spoofed_packets": int(res.chain.shape[0]),
                "packets_examined": res.n_packets,
                "interval_s": interval_s,
                "time_until_failure_s": res.packets_until_failure * interval_s,
                "distinct_targets": len(cache),
                "targets_with_match": int(sum(r.any for r in cache.values())),
            }
        )
    out: dict[str, list[Row]] = {"paths": rows, "sites": _site_rows(sim, run)}
    if end_to_end:
        attack = results[config.limit_scales[0]]
        trace, summary = _end_to_end(
            sim,
            space,
            scorer,
            attack,
            cache,
            snapped,
            t,
            pos,
            ori,
            config,
            run,
            _rng(config, run, "e2e"),
        )
        out["end_to_end"] = trace
        out["end_to_end_summary"] = summary
    return out


def _end_to_end(
    sim: Simulation,
    space: CandidateSpace,
    scorer: object,
    attack: PathAttack,
    cache: dict[int, MatchResult],
    snapped: np.ndarray,
    t: FloatArray,
    pos: FloatArray,
    ori: FloatArray,
    config: SpoofConfig,
    run: int,
    rng: np.random.Generator,
) -> tuple[list[Row], list[Row]]:
    """Feed the attack (and the genuine device over the same span) through the tracker."""
    site = sim.site
    tx = site.devices[0].transmitter
    rx = site.receivers
    rx_xyz = np.array([[r.x_m, r.y_m, r.z_m] for r in rx])
    rx_ori = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in rx])
    rx_pat = tuple(site.patterns[r.pattern] for r in rx)
    ids = site.receiver_ids
    chain = attack.chain
    # The genuine device over the span the attack lasted (at least until it failed).
    end = max(int(chain[-1, 0]) + 1 if chain.size else 0, min(attack.packets_until_failure, t.size))

    sources: dict[str, list[tuple[int, FloatArray, FloatArray, float]]] = {
        "attack": [],
        "genuine": [],
    }
    for pk, cand in chain:
        m = cache[int(snapped[pk])]
        off = float(m.offset_db[np.flatnonzero(m.candidate_idx == cand)[0]])
        a_pos = space.candidate_positions_m(np.array([cand]))[0]
        a_ori = space.candidate_orientations_deg(np.array([cand]))[0]
        sources["attack"].append((int(pk), a_pos, a_ori, off))
    for pk in range(end):
        sources["genuine"].append((pk, pos[pk], ori[pk], 0.0))

    trace: list[Row] = []
    summary: list[Row] = []
    for source, sends in sources.items():
        tracker = Tracker(site, "full", config.tracker, scorers={tx: scorer})  # type: ignore[dict-item]
        rows = []
        for pk, p, o, off in sends:
            rss = link_rss_dbm(
                config.scenario.channel,
                p,
                o,
                space.pattern,
                space.tx_power_dbm + off,
                rx_xyz,
                rx_ori,
                rx_pat,
            )[0]
            rss = rss + rng.normal(0.0, config.packet_noise_db, rss.shape)
            est, reason = tracker.update(PacketObservation(str(pk), float(t[pk]), tx, ids, rss))
            row: Row = {
                "run": run,
                "source": source,
                "packet": pk,
                "timestamp_s": t[pk],
                "spoofed_x_m": pos[pk, 0],
                "spoofed_y_m": pos[pk, 1],
                "spoofed_azimuth_deg": ori[pk, 0],
                "sender_x_m": p[0],
                "sender_y_m": p[1],
                "sender_azimuth_deg": o[0],
                "power_offset_db": off,
                "estimated": int(est is not None),
                "reason": reason or "",
            }
            if est is not None:
                e = np.asarray(est.position_m)
                row |= {
                    "est_x_m": e[0],
                    "est_y_m": e[1],
                    "est_azimuth_deg": est.orientation_deg[0],
                    "error_to_spoofed_m": float(np.linalg.norm(e[:2] - pos[pk, :2])),
                    "error_to_sender_m": float(np.linalg.norm(e[:2] - p[:2])),
                    "orientation_error_deg": float(
                        abs(angle_diff_deg(est.orientation_deg[0], ori[pk, 0]))
                    ),
                }
            else:
                row |= dict.fromkeys(
                    (
                        "est_x_m",
                        "est_y_m",
                        "est_azimuth_deg",
                        "error_to_spoofed_m",
                        "error_to_sender_m",
                        "orientation_error_deg",
                    ),
                    np.nan,
                )
            rows.append(row)
        trace += rows
        summary.append(_follow_summary(rows, run, source, config.follow_radius_m, pos, t))
    return trace, summary


def _follow_summary(
    rows: list[Row], run: int, source: str, radius_m: float, pos: FloatArray, t: FloatArray
) -> Row:
    """How far and for how long the reported path stayed within ``radius_m`` of the spoofed one."""
    est = [r for r in rows if r["estimated"]]
    err = np.array([r["error_to_spoofed_m"] for r in est])
    followed_s = followed_m = 0.0
    if rows and est:
        first = rows[0]["packet"]
        last_ok = None
        for r in est:
            if r["error_to_spoofed_m"] > radius_m:
                break
            last_ok = r["packet"]
        if last_ok is not None:
            followed_s = float(t[last_ok] - t[first])
            followed_m = float(np.linalg.norm(pos[last_ok, :2] - pos[first, :2]))
    return {
        "run": run,
        "source": source,
        "packets_sent": len(rows),
        "estimates": len(est),
        "span_s": float(t[rows[-1]["packet"]] - t[rows[0]["packet"]]) if rows else 0.0,
        "followed_s": followed_s,
        "followed_m": followed_m,
        "within_radius_fraction": float(np.mean(err <= radius_m)) if err.size else np.nan,
        "median_error_to_spoofed_m": float(np.median(err)) if err.size else np.nan,
        "median_error_to_sender_m": float(np.median([r["error_to_sender_m"] for r in est]))
        if est
        else np.nan,
    }


# ----------------------------------------------------------------------------- entry
def run_experiment(experiment: str, run: int, config: SpoofConfig) -> RunOutput:
    """One run of one experiment (pure: same arguments, same rows).

    ``e2e`` includes its own ``path`` run (the attack it replays), so asking for
    both computes the path search once: :func:`plan_tasks` merges them.
    """
    import time

    t0 = time.perf_counter()
    if experiment in ("match", "pattern"):
        tables = _match_run(config, run, experiment)
    elif experiment in ("path", "e2e"):
        tables = _path_run(config, run, end_to_end=experiment == "e2e")
    else:
        raise InputError(f"unknown experiment {experiment!r}")
    return RunOutput(experiment, run, tables, time.perf_counter() - t0)


def plan_tasks(experiments: tuple[str, ...], runs: int) -> list[tuple[str, int]]:
    """``(experiment, run)`` tasks; ``path`` is dropped when ``e2e`` (a superset) is asked."""
    exps = [e for e in experiments if not (e == "path" and "e2e" in experiments)]
    return [(e, r) for e in exps for r in range(runs)]
