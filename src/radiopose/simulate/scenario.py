"""Simulated scenarios: a site, a moving device and its packets with ground truth.

The default :class:`ScenarioConfig` is the paper's 2-D proof-of-concept setup
("2D Proof of Concept Simulations"): a 20 m × 20 m area, 4 receivers (3–6
selectable) at seeded random positions (at least ``min_receiver_spacing_m``
apart) and random azimuths, each with its own smooth pattern; a survey on a
1 m grid computed from the same channel model (survey transmitter power and
pattern included, at a random azimuth per point); a 0.1 m candidate grid and
1° azimuth candidates; a transmitter moving in a straight line at constant
speed with linear rotation; a packet every 5 ms; Gaussian noise σ on every
packet's RSS at every receiver. Everything lies at one height (``z_m``), so
every direction is in the plane of the screen (polar angle 90°).

Randomness: one ``np.random.Generator`` seeded from ``seed`` is drawn in a
fixed order (receivers, patterns, survey, trajectory, noise, losses), so the
same config and seed give byte-identical files.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.packets import Packets, Truth, write_packets_csv, write_truth_csv
from radiopose.patterns.pattern import Pattern
from radiopose.patterns.synthetic import smartphone_like
from radiopose.simulate.channel import LogDistance, link_rss_dbm
from radiopose.simulate.trajectories import MotionConfig, device_path
from radiopose.site import (
    MAX_CANDIDATES,
    MAX_GRID_POINTS,
    MAX_ORIENTATIONS,
    AreaGrid,
    Device,
    OrientationGrid,
    Receiver,
    Site,
    SurveyConfig,
    SurveyRows,
    grid_steps,
)
from radiopose.site_io import assemble_site, write_site
from radiopose.tables import check_output_paths
from radiopose.units import FloatArray

DEFAULT_TRANSMITTER = "02:00:00:00:00:01"


MAX_RECEIVERS = 16
"""Most receivers a scenario may have (``n_receivers``)."""


@dataclass(frozen=True)
class ScenarioConfig:
    """A simulated scenario (defaults: the paper's standard scenario).

    Attributes
    ----------
    size_m
        Side of the square area, metres (candidates from 0 to ``size_m``).
    step_m
        Candidate grid step, metres.
    z_m
        Height of candidates, receivers, survey points and device, metres.
    survey_step_m
        Survey grid step, metres.
    n_receivers
        Number of receivers (3–6 in the paper's sweeps; 1–16 accepted here,
        ``radiopose simulate`` takes 3–16: every method skips a packet heard
        by fewer than ``TrackerConfig.min_receivers``, 3 by default).
    noise_db
        σ of the Gaussian noise on packet RSS, dB.
    survey_noise_db
        σ of Gaussian noise on survey RSS, dB (0 = noise-free survey).
    interval_ms
        Time between packets, milliseconds.
    duration_s
        Length of the trace, seconds.
    azimuth_step_deg
        Candidate azimuth step, degrees.
    loss_fraction
        Probability that a receiver misses a packet (independent per receiver).
    tx_power_dbm, survey_tx_power_dbm
        Transmit powers of the tracked device and the survey transmitter, dBm.
    channel
        Path-loss model.
    motion
        Trajectory model.
    min_receiver_spacing_m
        Minimum distance between receivers, metres.
    device_range_db, receiver_range_db, survey_range_db
        Directivity ranges (max − min, dB) of the synthetic patterns, drawn
        uniformly from these intervals.
    pose
        ``"2d"`` (this scenario) or ``"3d"``: the hand-held 3-D scenario
        (:mod:`radiopose.simulate.handheld`, docs/pose3d.md), which takes only
        ``n_receivers``, ``noise_db``, ``interval_ms``, ``duration_s``,
        ``loss_fraction`` and ``motion.speed_mps`` from here.
    """

    size_m: float = 20.0
    step_m: float = 0.1
    z_m: float = 1.0
    survey_step_m: float = 1.0
    n_receivers: int = 4
    noise_db: float = 1.0
    survey_noise_db: float = 0.0
    interval_ms: float = 5.0
    duration_s: float = 2.0
    azimuth_step_deg: float = 1.0
    loss_fraction: float = 0.0
    tx_power_dbm: float = 15.0
    survey_tx_power_dbm: float = 20.0
    channel: LogDistance = field(default_factory=LogDistance)
    motion: MotionConfig = field(default_factory=MotionConfig)
    min_receiver_spacing_m: float = 4.0
    device_range_db: tuple[float, float] = (14.0, 20.0)
    receiver_range_db: tuple[float, float] = (4.0, 8.0)
    survey_range_db: tuple[float, float] = (4.0, 8.0)
    pose: Literal["2d", "3d"] = "2d"

    @classmethod
    def smoke(cls) -> ScenarioConfig:
        """A small site (10 m, 0.25 m grid, receivers ≥ 3 m apart) and a 0.2 s
        trace: the scripts' ``--quick`` runs, which check that a script runs
        (their numbers mean nothing)."""
        return cls(size_m=10.0, step_m=0.25, duration_s=0.2, min_receiver_spacing_m=3.0)

    def validate(self) -> None:
        """Raise :class:`InputError` naming the first out-of-range setting."""
        check_setting_types(self, "scenario")
        checks = [
            ("size_m", 0 < self.size_m <= 1e6, "(0, 1e6]"),
            ("step_m", 0 < self.step_m <= self.size_m, "(0, size_m]"),
            ("survey_step_m", 0 < self.survey_step_m <= self.size_m, "(0, size_m]"),
            ("n_receivers", 1 <= self.n_receivers <= MAX_RECEIVERS, f"1 to {MAX_RECEIVERS}"),
            ("noise_db", 0 <= self.noise_db <= 30, "[0, 30]"),
            ("survey_noise_db", 0 <= self.survey_noise_db <= 30, "[0, 30]"),
            ("interval_ms", 0.01 <= self.interval_ms <= 60_000, "[0.01, 60000]"),
            ("duration_s", 0 < self.duration_s <= 3600, "(0, 3600]"),
            ("azimuth_step_deg", 0 < self.azimuth_step_deg <= 360, "(0, 360]"),
            ("loss_fraction", 0 <= self.loss_fraction < 1, "[0, 1)"),
            # a spacing the area cannot hold is relaxed by 0.8 every 10,000 tries:
            # bounded so that relaxing takes a second, not minutes
            ("min_receiver_spacing_m", 0 <= self.min_receiver_spacing_m <= 1e4, "[0, 10000]"),
            ("pose", self.pose in ("2d", "3d"), "2d or 3d"),
            ("z_m", abs(self.z_m) <= 1000.0, "[-1000, 1000]"),
            *power_and_range_checks(self),
        ]
        for name, ok, allowed in checks:
            value = getattr(self, name)
            if not ok or (isinstance(value, float) and not math.isfinite(value)):
                raise InputError(
                    f"scenario setting {name} = {value!r} is out of range (allowed: {allowed})"
                )
        if round(self.duration_s / (self.interval_ms / 1000.0)) < 1:
            raise InputError(
                f"scenario setting duration_s = {self.duration_s!r} is shorter than one "
                f"packet interval ({self.interval_ms:g} ms): no packet would be sent"
            )
        self.motion.validate()
        self.channel.validate()
        if self.size_m <= 2 * self.motion.margin_m:
            raise InputError(
                f"scenario setting size_m = {self.size_m!r} leaves no room to walk: the device "
                f"keeps {self.motion.margin_m:g} m from every edge, so size_m must exceed "
                f"{2 * self.motion.margin_m:g} m"
            )
        check_grid_limits(
            "", self.size_m, self.step_m, self.survey_step_m, 360.0 / self.azimuth_step_deg,
            f"azimuth_step_deg = {self.azimuth_step_deg!r} gives", "azimuths",
        )  # fmt: skip
        for name in ("step_m", "survey_step_m"):
            if not grid_steps(self.size_m, getattr(self, name))[1]:
                raise InputError(
                    f"scenario setting {name} = {getattr(self, name)!r} does not divide size_m = "
                    f"{self.size_m!r}: "
                    "the grid would stop short of the area's edge"
                )
        n = round(360.0 / self.azimuth_step_deg)
        if abs(n * self.azimuth_step_deg - 360.0) > 1e-6:
            raise InputError(
                f"scenario setting azimuth_step_deg = {self.azimuth_step_deg!r} does not divide 360"
            )
        if round(self.duration_s / (self.interval_ms / 1000.0)) > 2_000_000:
            raise InputError("more than 2,000,000 packets: shorten duration_s or raise interval_ms")


def check_grid_limits(
    prefix: str, size_m: float, step_m: float, survey_step_m: float, n_orientations: float,
    orientations: str, noun: str = "orientations",
) -> None:  # fmt: skip
    """The limits of a site read from disk (:mod:`radiopose.site`), checked from
    a scenario's numbers alone before anything is allocated: grid and survey
    points, orientations and candidate poses (per height). ``prefix`` starts
    each message, ``orientations`` says where the orientation count comes from."""
    n_axis = size_m / step_m + 1
    n_survey = (size_m / survey_step_m + 1) ** 2
    if n_axis**2 > MAX_GRID_POINTS or n_survey > MAX_GRID_POINTS:
        raise InputError(
            f"{prefix}size_m = {size_m!r} with step_m = {step_m!r} (survey_step_m = "
            f"{survey_step_m!r}) gives more than {MAX_GRID_POINTS:,} grid points"
        )
    if n_orientations > MAX_ORIENTATIONS or n_axis**2 * n_orientations > MAX_CANDIDATES:
        raise InputError(
            f"{prefix}{orientations} {n_orientations:.3g} {noun}, "
            f"{n_axis**2 * n_orientations:.3g} candidate poses (limits {MAX_ORIENTATIONS:,} "
            f"and {MAX_CANDIDATES:,})"
        )


def power_and_range_checks(cfg: object) -> list[tuple[str, bool, str]]:
    """The ``(name, ok, allowed)`` checks a scenario's powers and directivity
    ranges share with ``devices.csv``: powers in [-100, 60] dBm; each range
    ``(low, high)`` with 0 <= low <= high <= 60 dB (only the fields ``cfg`` has)."""
    out = []
    for name in ("tx_power_dbm", "survey_tx_power_dbm"):
        v = getattr(cfg, name)
        out.append((name, -100.0 <= v <= 60.0, "[-100, 60] dBm"))
    for name in ("device_range_db", "receiver_range_db", "survey_range_db"):
        if hasattr(cfg, name):
            lo, hi = getattr(cfg, name)
            out.append((name, 0.0 <= lo <= hi <= 60.0, "0 <= low <= high <= 60 dB"))
    return out


def check_seed(seed: object) -> int:
    """A simulation seed: an integer in [0, 2**63) (numpy's generators take no other)."""
    import numbers

    if (
        not isinstance(seed, numbers.Integral)
        or isinstance(seed, bool)
        or not 0 <= int(seed) < 2**63
    ):
        raise InputError(f"seed {seed!r} must be an integer in [0, 2**63)")
    return int(seed)


@dataclass(frozen=True, eq=False)
class Simulation:
    """A simulated scenario's outputs."""

    config: ScenarioConfig
    seed: int
    site: Site
    packets: Packets
    truth: Truth

    def write(self, directory: str | os.PathLike[str]) -> list[Path]:
        """Write ``DIR/site/``, ``DIR/packets.csv`` and ``DIR/truth.csv``; return the paths."""
        root = Path(directory)
        check_output_paths([root / "packets.csv", root / "truth.csv"], [root / "site"])
        write_site(self.site, root / "site")
        write_packets_csv(self.packets, root / "packets.csv")
        write_truth_csv(self.truth, root / "truth.csv")
        return [root / "site", root / "packets.csv", root / "truth.csv"]


def _receiver_positions(rng: np.random.Generator, cfg: ScenarioConfig) -> FloatArray:
    pts: list[FloatArray] = []
    spacing = cfg.min_receiver_spacing_m
    tries = 0
    while len(pts) < cfg.n_receivers:
        p = rng.uniform(0.0, cfg.size_m, 2)
        tries += 1
        if tries > 10_000:  # too crowded: relax the spacing rather than loop forever
            spacing *= 0.8
            tries = 0
        if all(np.hypot(*(p - q)) >= spacing for q in pts):
            pts.append(p)
    xy = np.array(pts)
    return np.column_stack([xy, np.full(len(pts), cfg.z_m)])


def seed_range(text: str) -> range:
    """Simulation seeds ``"FIRST-LAST"`` (inclusive) or ``"SEED"``, as a range; the
    scripts' ``--seeds`` type. A malformed or empty set is an
    :class:`argparse.ArgumentTypeError` (the parser's one-line usage error)."""
    lo, _, hi = text.partition("-")
    try:
        first, last = int(lo), int(hi or lo)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed set {text!r} is not FIRST-LAST") from None
    if last < first:
        raise argparse.ArgumentTypeError(f"seed set {text!r} is empty")
    return range(first, last + 1)


def simulate(config: ScenarioConfig | None = None, seed: int = 0) -> Simulation:
    """Simulate a scenario (see the module docstring)."""
    cfg = config or ScenarioConfig()
    cfg.validate()
    seed = check_seed(seed)
    if cfg.pose == "3d":  # pose3d: the hand-held scenario (docs/pose3d.md)
        from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

        return replace(simulate_handheld(HandheldConfig.from_scenario(cfg), seed), config=cfg)
    rng = np.random.default_rng(seed)

    # Receivers with their own patterns.
    rx_xyz = _receiver_positions(rng, cfg)
    rx_az = rng.uniform(0.0, 360.0, cfg.n_receivers)
    patterns: dict[str, Pattern] = {}
    receivers = []
    for i in range(cfg.n_receivers):
        pname = f"rx{i + 1}"
        patterns[pname] = smartphone_like(
            rng,
            pname,
            range_db=rng.uniform(*cfg.receiver_range_db),
            azimuth_step_deg=1.0,
        )
        receivers.append(
            Receiver(
                f"rx{i + 1}",
                float(rx_xyz[i, 0]),
                float(rx_xyz[i, 1]),
                float(rx_xyz[i, 2]),
                float(rx_az[i]),
                0.0,
                0.0,
                pname,
            )
        )
    patterns["survey-tx"] = smartphone_like(
        rng, "survey-tx", range_db=rng.uniform(*cfg.survey_range_db)
    )
    patterns["device"] = smartphone_like(rng, "device", range_db=rng.uniform(*cfg.device_range_db))
    rx_orient = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in receivers])
    rx_pats = tuple(patterns[r.pattern] for r in receivers)

    # Survey on a regular grid, one random azimuth per point.
    n_s = int(np.floor(cfg.size_m / cfg.survey_step_m + 1e-9)) + 1
    axis = np.arange(n_s) * cfg.survey_step_m
    sx, sy = np.meshgrid(axis, axis, indexing="ij")
    s_xyz = np.column_stack([sx.ravel(), sy.ravel(), np.full(sx.size, cfg.z_m)])
    s_orient = np.column_stack([rng.uniform(0, 360, sx.size), np.zeros((sx.size, 2))])
    s_rss = link_rss_dbm(
        cfg.channel,
        s_xyz,
        s_orient,
        patterns["survey-tx"],
        cfg.survey_tx_power_dbm,
        rx_xyz,
        rx_orient,
        rx_pats,
    )
    if cfg.survey_noise_db > 0:
        s_rss = s_rss + rng.normal(0.0, cfg.survey_noise_db, s_rss.shape)
    survey_rows = survey_rows_of(s_xyz, s_orient, s_rss, receivers)

    area = AreaGrid(0.0, cfg.size_m, 0.0, cfg.size_m, cfg.z_m, cfg.step_m)
    orient = OrientationGrid(cfg.azimuth_step_deg)
    device = Device(DEFAULT_TRANSMITTER, "device", cfg.tx_power_dbm)
    site = assemble_site(
        "simulated",
        area,
        orient,
        SurveyConfig(cfg.survey_tx_power_dbm, "survey-tx"),
        tuple(receivers),
        (device,),
        patterns,
        survey_rows,
    )

    # Trajectory and packets.
    n_pk = round(cfg.duration_s / (cfg.interval_ms / 1000.0))
    t = np.arange(n_pk, dtype=np.float64) * (cfg.interval_ms / 1000.0)
    pos, ori = device_path(rng, t, (0.0, cfg.size_m, 0.0, cfg.size_m), cfg.z_m, cfg.motion)
    rss = link_rss_dbm(
        cfg.channel, pos, ori, patterns["device"], cfg.tx_power_dbm, rx_xyz, rx_orient, rx_pats
    )
    packets, truth = observe_path(rng, rss, t, pos, ori, receivers, cfg.noise_db, cfg.loss_fraction)
    return Simulation(cfg, seed, site, packets, truth)


def survey_rows_of(
    xyz_m: FloatArray,
    orientation_deg: FloatArray,
    rss_dbm: FloatArray,
    receivers: Sequence[Receiver],
) -> SurveyRows:
    """Survey rows of ``rss_dbm`` ``(n_points, n_receivers)`` measured at the points
    ``xyz_m`` ``(n_points, 3)`` (metres) with the survey transmitter at
    ``orientation_deg`` ``(n_points, 3)``: one row per point per receiver."""
    n_pts, k = rss_dbm.shape
    return SurveyRows(
        xyz_m=np.repeat(xyz_m, k, axis=0),
        receiver_id=np.array([r.receiver_id for r in receivers] * n_pts, dtype=object),
        rss_dbm=rss_dbm.reshape(-1),
        orientation_deg=np.repeat(orientation_deg, k, axis=0),
    )


def observe_path(
    rng: np.random.Generator,
    rss_dbm: FloatArray,
    t_s: FloatArray,
    position_m: FloatArray,
    orientation_deg: FloatArray,
    receivers: Sequence[Receiver],
    noise_db: float,
    loss_fraction: float,
) -> tuple[Packets, Truth]:
    """The packets the receivers hear of a path, and its truth.

    ``rss_dbm`` ``(n_packets, n_receivers)`` is the noise-free link RSS; this
    adds Gaussian noise (``noise_db``, dB) and drops each reading with
    probability ``loss_fraction`` (in that order of random draws). Packet ids
    number the packets someone heard, 0, 1, 2, ... in time order, as a
    deployment sees them (and as `radiopose sync` numbers them): a packet no
    receiver heard leaves no row and no gap. ``truth.csv`` keeps every packet.
    """
    rss = rss_dbm + rng.normal(0.0, noise_db, rss_dbm.shape)
    heard = rng.random(rss.shape) >= loss_fraction
    pk_idx, rx_idx = np.nonzero(heard)
    ids = np.array([r.receiver_id for r in receivers], dtype=object)
    number = np.cumsum(heard.any(axis=1)) - 1
    packets = Packets(
        packet_id=np.array([str(i) for i in number[pk_idx]], dtype=object),
        timestamp_s=t_s[pk_idx],
        transmitter=np.full(pk_idx.size, DEFAULT_TRANSMITTER, dtype=object),
        receiver_id=ids[rx_idx],
        rss_dbm=np.round(rss[pk_idx, rx_idx], 3),
    )
    truth = Truth(
        t_s, np.full(t_s.size, DEFAULT_TRANSMITTER, dtype=object), position_m, orientation_deg
    )
    return packets, truth
