"""``radiopose spoof detect``: how well the consistency detector finds each attack.

Tasks (each a pure function of its arguments, spread over processes):

* **attack runs** — :func:`radiopose.security.attacks.attack_stream`;
* **genuine chunks** — the genuine device alone for ``chunk_s`` (linear,
  periodic and beyond-the-bound ``fast`` rotation in turn).

Each keeps its packets' RSS; with ``run_filter`` also the residuals at the
causal particle filter's estimates (``radiopose.filtering``, the tracker's
settings). The detector (:mod:`radiopose.security.detection`) is then applied
in the parent to every stored track, so thresholds can be swept without
simulating again. Per ``(attack, σ)``:

``detection_probability``
    fraction of runs whose alarm is on at some packet within ``window_s``
    (0.5 s) after the attack's first packet;
``median_detection_delay_s``
    median over detected runs of the first such packet's time − attack start;
``false_alarms_per_hour``
    alarm onsets per hour of genuine traffic at that σ (genuine chunks, plus
    the genuine prefixes of the attack runs).
"""

from __future__ import annotations

import csv
import math
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from radiopose.filtering import ParticleFilter
from radiopose.likelihood import HeardRss
from radiopose.security.attacks import (
    ATTACKS,
    AttackConfig,
    PacketStream,
    SiteModel,
    attack_stream,
    genuine_stream,
    scenario_for,
)
from radiopose.security.detection import DetectorConfig, pose_residuals_db, score_track
from radiopose.tracker import TrackerConfig, filter_config
from radiopose.units import FloatArray

DETECTION_COLUMNS = (
    "attack",
    "sigma_db",
    "runs",
    "detection_probability",
    "median_detection_delay_s",
    "false_alarms_per_hour",
)
ROTATIONS = ("linear", "periodic", "fast")
DETECTOR_ANGULAR_NOISE_DPS2 = 90.0
"""The causal filter's angular-acceleration density under the detectors, °/s²/√Hz:
the value their thresholds were calibrated with (``FilterConfig``'s default
before 2026-11-27)."""
CONTRACT_ATTACKS = ("fixed", "moving", "clone", "replay")
"""The attacks of ``detection.csv`` (the contract); ``silent`` is the script's."""


@dataclass(frozen=True)
class DetectPlan:
    """What one ``spoof detect`` invocation simulates.

    Attributes
    ----------
    sigmas_db
        Noise levels.
    attack_runs
        Attack runs per attack and σ.
    genuine_chunks
        Genuine chunks per σ (rotation kinds in turn).
    chunk_s
        Length of a genuine chunk, seconds.
    seed
        Base seed of the sites: attack run ``j`` and genuine chunk ``j`` simulate
        the site of seed ``seed + j`` (their motion and noise from other streams).
    window_s
        An alarm within this long after the attack start counts as a detection.
    attacks
        The attacks simulated (names of :data:`radiopose.security.attacks.ATTACKS`).
    run_filter
        Also run the causal filter over every stream and keep the residuals at
        its estimates (what ``signal = "residual"`` and the level analysis
        need; the shipped detector, ``signal = "rss"``, reads the packets only).
    """

    sigmas_db: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0)
    attack_runs: int = 50
    genuine_chunks: int = 60
    chunk_s: float = 60.0
    seed: int = 20_000
    window_s: float = 0.5
    run_filter: bool = False
    attacks: tuple[str, ...] = CONTRACT_ATTACKS

    @classmethod
    def quick(cls, seed: int = 20_000) -> DetectPlan:
        """``--quick``: σ = 1 dB, 10 runs per attack, 10 minutes of genuine traffic."""
        return cls(sigmas_db=(1.0,), attack_runs=10, genuine_chunks=20, chunk_s=30.0, seed=seed)


@dataclass(frozen=True, eq=False)
class Track:
    """One stream: its packets' RSS and, if the filter ran, the residuals at its
    estimates (``nan`` otherwise)."""

    kind: str  # an attack name or "genuine"
    sigma_db: float
    run: int
    t_s: FloatArray
    residuals_db: FloatArray
    innovations_db: FloatArray
    new_track: np.ndarray
    t_attack_s: float
    rss_dbm: FloatArray | None = None

    def values(self, signal: str) -> FloatArray:
        """The detector's input for ``signal`` (``"rss"`` or ``"residual"``)."""
        if signal == "rss":
            if self.rss_dbm is None:
                raise ValueError("this track kept no RSS")
            return self.rss_dbm
        return self.residuals_db


def filter_residuals(
    site: SiteModel, stream: PacketStream, seed: int
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Run the causal filter (the tracker's settings) over ``stream``; return the
    residuals ``(n, n_rx)`` at its estimates, the innovations (at the previous
    packet's estimate) and where a track (re-)started."""
    # the density the detectors were calibrated with (DETECTOR_ANGULAR_NOISE_DPS2)
    cfg = replace(
        filter_config(TrackerConfig()), angular_accel_noise_dps2=DETECTOR_ANGULAR_NOISE_DPS2
    )
    pf = ParticleFilter(site.model, cfg, None)
    st = pf.new_state(seed)
    n, n_rx = stream.rss_dbm.shape
    idx = np.arange(n_rx, dtype=np.int64)
    pos = np.full((n, 3), np.nan)
    ori = np.full((n, 3), np.nan)
    new_track = np.zeros(n, dtype=bool)
    had_track = False
    for i in range(n):
        fresh = st.particles is None or (
            st.last_time_s is not None
            and stream.t_s[i] - st.last_time_s > pf.config.reacquire_gap_s
        )
        est = pf.step(st, float(stream.t_s[i]), HeardRss(idx, stream.rss_dbm[i]))
        if est is None:
            had_track = False
            continue
        new_track[i] = fresh or not had_track
        had_track = True
        pos[i] = est.position_m
        ori[i] = est.orientation_deg
    ok = np.isfinite(pos[:, 0])
    res = pose_residuals_db(site.model, np.nan_to_num(pos), np.nan_to_num(ori), stream.rss_dbm)
    res[~ok] = np.nan
    # innovation: this packet at the previous packet's estimate (before the filter saw it)
    prev_p = np.vstack([pos[:1], pos[:-1]])
    prev_o = np.vstack([ori[:1], ori[:-1]])
    inn = pose_residuals_db(
        site.model, np.nan_to_num(prev_p), np.nan_to_num(prev_o), stream.rss_dbm
    )
    inn[~(ok & np.isfinite(prev_p[:, 0])) | new_track] = np.nan
    return res, inn, new_track


def run_task(task: tuple[str, float, int], plan: DetectPlan) -> Track:
    """One attack run (``(attack, σ, run)``) or genuine chunk (``("genuine", σ, chunk)``)."""
    kind, sigma, run = task
    if kind == "genuine":
        rotation = ROTATIONS[run % len(ROTATIONS)]
        seed = plan.seed + run
        site = SiteModel.build(scenario_for(sigma, rotation), seed)
        rng = np.random.default_rng([seed, round(sigma * 1000), 1])
        stream = genuine_stream(site, plan.chunk_s, sigma, rng)
    else:
        seed = plan.seed + run
        site = SiteModel.build(scenario_for(sigma), seed)
        rng = np.random.default_rng([seed, round(sigma * 1000), 2 + ATTACKS.index(kind)])
        stream = attack_stream(site, kind, sigma, AttackConfig(), rng)
    if plan.run_filter:
        res, inn, new = filter_residuals(site, stream, seed)
    else:
        res = inn = np.full(stream.rss_dbm.shape, np.nan)
        new = np.concatenate([[True], np.diff(stream.t_s) > 1.0])  # the tracker's re-entry
    return Track(kind, sigma, run, stream.t_s, res, inn, new, stream.t_attack_s, stream.rss_dbm)


def plan_tasks(plan: DetectPlan) -> list[tuple[str, float, int]]:
    """Every task of ``plan``: attack runs first, then genuine chunks (longest last)."""
    tasks = [
        (a, s, r) for s in plan.sigmas_db for a in plan.attacks for r in range(plan.attack_runs)
    ]
    tasks += [("genuine", s, c) for s in plan.sigmas_db for c in range(plan.genuine_chunks)]
    return tasks


def run_tracks(
    plan: DetectPlan,
    workers: int,
    on_done: Callable[[Track], None] | None = None,
) -> list[Track]:
    """Run every task of ``plan`` (``workers`` processes; 0: this process)."""
    tasks = plan_tasks(plan)
    out: list[Track] = []
    if workers <= 0:
        for task in tasks:
            out.append(run_task(task, plan))
            if on_done is not None:
                on_done(out[-1])
        return out
    # genuine chunks are the long tasks: start them first for a short tail
    order = sorted(tasks, key=lambda t: t[0] != "genuine")
    saved = {k: os.environ.get(k) for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS")}
    os.environ.update(NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    try:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = [pool.submit(run_task, task, plan) for task in order]
            for fut in as_completed(futures):
                out.append(fut.result())
                if on_done is not None:
                    on_done(out[-1])
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return out


# ----------------------------------------------------------------------------- scoring
@dataclass(frozen=True)
class TrackOutcome:
    """What the detector did on one track."""

    kind: str
    sigma_db: float
    genuine_s: float
    false_alarms: int
    detected: bool
    delay_s: float
    attacked: bool = True  # the attacker sent a packet (a ``silent`` one may not)


def evaluate_track(track: Track, config: DetectorConfig, window_s: float) -> TrackOutcome:
    """Apply the detector to one stored track."""
    res = score_track(track.t_s, track.values(config.signal), config, track.new_track)
    onsets = res.alarm_onsets()
    t = track.t_s
    before = t < track.t_attack_s
    genuine_s = float(t[before][-1] - t[0]) if before.any() else 0.0
    false_alarms = int(np.sum(before[onsets])) if onsets.size else 0
    detected, delay = False, math.nan
    attacked = bool(np.any(t >= track.t_attack_s))
    if math.isfinite(track.t_attack_s):
        inside = np.flatnonzero((t >= track.t_attack_s) & (t <= track.t_attack_s + window_s))
        hit = inside[res.alarm[inside]]
        if hit.size:
            detected, delay = True, float(t[hit[0]] - track.t_attack_s)
    return TrackOutcome(
        track.kind, track.sigma_db, genuine_s, false_alarms, detected, delay, attacked
    )


def detection_rows(
    tracks: Sequence[Track], config: DetectorConfig, window_s: float = 0.5
) -> list[dict[str, object]]:
    """The rows of ``detection.csv`` (:data:`DETECTION_COLUMNS`) for one detector setting."""
    outcomes = [evaluate_track(t, config, window_s) for t in tracks]
    rows: list[dict[str, object]] = []
    for sigma in sorted({o.sigma_db for o in outcomes}):
        at = [o for o in outcomes if o.sigma_db == sigma]
        hours = sum(o.genuine_s for o in at) / 3600.0
        fa = sum(o.false_alarms for o in at)
        fa_rate = fa / hours if hours > 0 else math.nan
        for attack in ATTACKS:
            # runs in which the attacker sent nothing (``silent`` found no match) do not count
            runs = [o for o in at if o.kind == attack and o.attacked]
            if not runs:
                continue
            delays = [o.delay_s for o in runs if o.detected]
            rows.append(
                {
                    "attack": attack,
                    "sigma_db": sigma,
                    "runs": len(runs),
                    "detection_probability": sum(o.detected for o in runs) / len(runs),
                    "median_detection_delay_s": float(np.median(delays)) if delays else math.nan,
                    "false_alarms_per_hour": fa_rate,
                }
            )
    return rows


def genuine_hours(tracks: Sequence[Track], sigma_db: float) -> float:
    """Hours of genuine traffic behind the false-alarm rate at ``sigma_db``."""
    total = 0.0
    for tr in tracks:
        if tr.sigma_db != sigma_db:
            continue
        before = tr.t_s < tr.t_attack_s
        if before.any():
            total += float(tr.t_s[before][-1] - tr.t_s[0])
    return total / 3600.0


def roc_rows(
    tracks: Sequence[Track], base: DetectorConfig, thresholds_nats: Sequence[float], window_s: float
) -> list[dict[str, object]]:
    """``detection_rows`` for each threshold, with a ``threshold_nats`` column (the ROC)."""
    out = []
    for h in thresholds_nats:
        for row in detection_rows(tracks, replace(base, threshold_nats=float(h)), window_s):
            out.append({"threshold_nats": float(h), **row})
    return out


def write_csv(path: Path, rows: Sequence[dict[str, object]], columns: Sequence[str]) -> Path:
    """Write ``rows`` with ``columns`` (floats with 6 significant digits; a missing value,
    NaN — no run detected, so no delay — as an empty field, as in the evaluation's
    tables, not ``nan``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([_field(r[c]) for c in columns])
    return path


def _field(value: object) -> object:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"
    return value
