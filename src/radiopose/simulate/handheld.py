"""3-D pose simulation (``radiopose simulate --pose 3d``): a hand-held phone.

Beyond the paper's 2-D proof of concept (docs/pose3d.md). A person walks with
turns (:func:`~radiopose.simulate.trajectories.walk_path`) holding a phone
tilted toward the face:

* heading: the phone's top (body ``+y``) follows the direction of walking, plus
  a head/hand wobble (two sinusoids, amplitude ``wobble_deg``);
* pitch: around ``pitch_mean_deg`` within ``pitch_range_deg`` (20–70°), two
  slow sinusoids; roll: within ``±roll_amplitude_deg``, two sinusoids;
* height: within ``height_range_m`` (0.8–1.6 m), two slow sinusoids.

Receivers stand at seeded random positions at mixed heights: every other one
on the ceiling (height in ``ceiling_height_m``, mounted upside down: roll
180°), the rest on walls or shelves (``wall_height_m``), each with its own
smooth slice pattern (as in 2-D). The phone has a synthetic full-sphere
pattern (:func:`~radiopose.patterns.synthetic.smartphone_like` with a polar
axis); the shipped measured patterns (``galaxy-s10``, ``iphone-11``) are
single slices without a polar axis and are not used. The survey transmitter
(lying flat, random azimuth) is surveyed on a regular grid at each of
``survey_heights_m``. The site carries the candidate height range
``z_min_m``..``z_max_m`` and pitch/roll candidate lists, so the registry's
``filter`` method tracks it in 3-D.

Randomness: one ``np.random.Generator`` seeded from ``seed``, drawn in a fixed
order (receivers, patterns, survey, path, angles and height, noise, losses):
the same config and seed give byte-identical files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from radiopose.errors import InputError, check_setting_types
from radiopose.patterns.pattern import Pattern
from radiopose.patterns.synthetic import smartphone_like
from radiopose.simulate.channel import LogDistance, link_rss_dbm
from radiopose.simulate.scenario import (
    DEFAULT_TRANSMITTER,
    MAX_RECEIVERS,
    ScenarioConfig,
    Simulation,
    check_grid_limits,
    check_seed,
    observe_path,
    power_and_range_checks,
    survey_rows_of,
)
from radiopose.simulate.trajectories import MotionConfig, walk_path, walking_azimuth_deg
from radiopose.site import (
    MAX_HEIGHTS,
    AreaGrid,
    Device,
    OrientationGrid,
    Receiver,
    SurveyConfig,
    grid_steps,
    height_range_middle_m,
)
from radiopose.site_io import assemble_site
from radiopose.units import FloatArray, wrap_deg


@dataclass(frozen=True)
class HandheldConfig:
    """A 3-D hand-held scenario (see the module docstring).

    Attributes
    ----------
    size_m, step_m
        Side of the square area and candidate grid step, metres.
    z_min_m, z_max_m, z_step_m
        Candidate height range of the site, metres.
    survey_step_m, survey_heights_m
        Survey grid step and the heights surveyed, metres.
    n_receivers
        Receivers (3–16); rx1, rx3, … (every other one) on the ceiling.
    ceiling_height_m, wall_height_m
        Height ranges of ceiling and wall receivers, metres.
    noise_db, interval_ms, duration_s, loss_fraction
        As in :class:`~radiopose.simulate.ScenarioConfig`.
    azimuth_step_deg, pitch_deg, roll_deg
        The site's candidate orientations.
    speed_mps
        Walking speed range, m/s.
    wobble_deg, pitch_range_deg, roll_amplitude_deg, height_range_m
        Ranges of the hand-held motion (see the module docstring).
    tx_power_dbm, survey_tx_power_dbm
        Transmit powers, dBm.
    channel
        Path-loss model.
    pattern_step_deg
        Azimuth and polar step of the phone's full-sphere pattern, degrees.
    """

    size_m: float = 20.0
    step_m: float = 0.25
    z_min_m: float = 0.6
    z_max_m: float = 1.8
    z_step_m: float = 0.2
    survey_step_m: float = 1.0
    survey_heights_m: tuple[float, ...] = (1.2,)
    n_receivers: int = 6
    ceiling_height_m: tuple[float, float] = (2.5, 3.0)
    wall_height_m: tuple[float, float] = (0.8, 2.2)
    noise_db: float = 1.0
    interval_ms: float = 5.0
    duration_s: float = 2.0
    loss_fraction: float = 0.0
    azimuth_step_deg: float = 5.0
    pitch_deg: tuple[float, ...] = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0)
    roll_deg: tuple[float, ...] = (-45.0, -30.0, -15.0, 0.0, 15.0, 30.0, 45.0)
    speed_mps: tuple[float, float] = (0.5, 1.5)
    wobble_deg: tuple[float, float] = (5.0, 15.0)
    pitch_range_deg: tuple[float, float] = (20.0, 70.0)
    roll_amplitude_deg: float = 25.0
    height_range_m: tuple[float, float] = (0.8, 1.6)
    tx_power_dbm: float = 15.0
    survey_tx_power_dbm: float = 20.0
    channel: LogDistance = field(default_factory=LogDistance)
    pattern_step_deg: float = 2.0
    min_receiver_spacing_m: float = 4.0

    def validate(self) -> None:
        """Raise :class:`InputError` naming the first out-of-range setting."""
        check_setting_types(self, "3-D scenario")
        lo_p, hi_p = self.pitch_range_deg
        lo_h, hi_h = self.height_range_m
        checks = [
            ("size_m", 4 < self.size_m <= 1000, "(4, 1000]"),
            ("step_m", 0 < self.step_m <= self.size_m, "(0, size_m]"),
            (
                "z_step_m",
                self.z_step_m > 0 and self.z_min_m <= self.z_max_m,
                "> 0, with z_min_m <= z_max_m",
            ),
            ("survey_step_m", 0 < self.survey_step_m <= self.size_m, "(0, size_m]"),
            ("n_receivers", 3 <= self.n_receivers <= MAX_RECEIVERS, f"3 to {MAX_RECEIVERS}"),
            ("noise_db", 0 <= self.noise_db <= 30, "[0, 30]"),
            ("interval_ms", 0.01 <= self.interval_ms <= 60_000, "[0.01, 60000]"),
            ("duration_s", 0 < self.duration_s <= 3600, "(0, 3600]"),
            ("loss_fraction", 0 <= self.loss_fraction < 1, "[0, 1)"),
            ("pitch_range_deg", -90 <= lo_p <= hi_p <= 90, "-90 <= low <= high <= 90"),
            (
                "height_range_m",
                self.z_min_m <= lo_h <= hi_h <= self.z_max_m,
                "z_min_m <= low <= high <= z_max_m",
            ),
            ("roll_amplitude_deg", 0 <= self.roll_amplitude_deg <= 90, "[0, 90]"),
            ("survey_heights_m", len(self.survey_heights_m) >= 1, "at least one height"),
            (
                "survey_heights_m",
                all(0.0 <= z <= 100.0 for z in self.survey_heights_m),
                "each in [0, 100]",
            ),
            ("z_min_m", 0.0 <= self.z_min_m <= 100.0, "[0, 100]"),
            ("z_max_m", self.z_max_m <= 100.0, "<= 100"),
            (
                "ceiling_height_m",
                0.0 <= self.ceiling_height_m[0] <= self.ceiling_height_m[1],
                "0 <= low <= high",
            ),
            (
                "wall_height_m",
                0.0 <= self.wall_height_m[0] <= self.wall_height_m[1],
                "0 <= low <= high",
            ),
            (
                "speed_mps",
                0.0 <= self.speed_mps[0] <= self.speed_mps[1] <= 100.0,
                "0 <= low <= high <= 100",
            ),
            (
                "wobble_deg",
                0.0 <= self.wobble_deg[0] <= self.wobble_deg[1] <= 180.0,
                "0 <= low <= high <= 180",
            ),
            ("azimuth_step_deg", 0.0 < self.azimuth_step_deg <= 360.0, "(0, 360]"),
            (
                "pitch_deg",
                len(self.pitch_deg) >= 1 and all(-90 <= p <= 90 for p in self.pitch_deg),
                "at least one, each in [-90, 90]",
            ),
            (
                "roll_deg",
                len(self.roll_deg) >= 1 and all(-360 <= r <= 360 for r in self.roll_deg),
                "at least one, each in [-360, 360]",
            ),
            ("pattern_step_deg", 0.1 <= self.pattern_step_deg <= 90.0, "[0.1, 90]"),
            (
                "min_receiver_spacing_m",
                0 <= self.min_receiver_spacing_m <= 1e4,
                "[0, 10000]",
            ),
            *power_and_range_checks(self),
        ]
        for name, ok, allowed in checks:
            if not ok:
                raise InputError(
                    f"3-D scenario setting {name} = {getattr(self, name)!r} is out of range "
                    f"(allowed: {allowed})"
                )
        self.channel.validate()
        for name, step, whole in (
            ("azimuth_step_deg", self.azimuth_step_deg, 360.0),
            ("pattern_step_deg", self.pattern_step_deg, 180.0),
        ):
            n_steps = round(whole / step)
            if abs(n_steps * step - whole) > 1e-6:
                raise InputError(
                    f"3-D scenario setting {name} = {step!r} does not divide {whole:g}"
                )
        n_orient = 360.0 / self.azimuth_step_deg * len(self.pitch_deg) * len(self.roll_deg)
        check_grid_limits(
            "3-D scenario: ", self.size_m, self.step_m, self.survey_step_m, n_orient,
            "azimuth_step_deg, pitch_deg and roll_deg give",
        )  # fmt: skip
        n_z = (self.z_max_m - self.z_min_m) / self.z_step_m + 1
        if n_z > MAX_HEIGHTS:
            raise InputError(
                f"3-D scenario setting z_step_m = {self.z_step_m!r} gives {n_z:.3g} heights "
                f"(limit {MAX_HEIGHTS:,})"
            )
        for name, step, span in (
            ("step_m", self.step_m, self.size_m),
            ("survey_step_m", self.survey_step_m, self.size_m),
            ("z_step_m", self.z_step_m, self.z_max_m - self.z_min_m),
        ):
            if not grid_steps(span, step)[1]:
                raise InputError(f"3-D scenario setting {name} = {step!r} does not divide {span:g}")
        n = self.duration_s / (self.interval_ms / 1000.0)
        if not 1 <= round(n) <= 2_000_000:
            raise InputError("3-D scenario: between 1 and 2,000,000 packets, please")

    @classmethod
    def from_scenario(cls, cfg: ScenarioConfig) -> HandheldConfig:
        """The 3-D scenario with the CLI's shared settings taken from a 2-D config."""
        return cls(
            n_receivers=cfg.n_receivers,
            noise_db=cfg.noise_db,
            interval_ms=cfg.interval_ms,
            duration_s=cfg.duration_s,
            loss_fraction=cfg.loss_fraction,
            speed_mps=cfg.motion.speed_mps,
        )


def _smooth_wave(
    rng: np.random.Generator, t: FloatArray, f_range: tuple[float, float]
) -> FloatArray:
    """A smooth signal in ``[-1, 1]``: ``(sin(2πft + a) + ½ sin(2π·2.3ft + b)) / 1.5``."""
    f = rng.uniform(*f_range)
    a, b = rng.uniform(0.0, 2 * np.pi, 2)
    return (np.sin(2 * np.pi * f * t + a) + 0.5 * np.sin(2 * np.pi * 2.3 * f * t + b)) / 1.5


def handheld_path(
    rng: np.random.Generator,
    t_s: FloatArray,
    bounds_xy_m: tuple[float, float, float, float],
    cfg: HandheldConfig,
) -> tuple[FloatArray, FloatArray]:
    """Positions ``(n, 3)`` m and orientations ``(n, 3)`` (azimuth, pitch, roll)
    degrees of the hand-held phone at times ``t_s`` (see the module docstring)."""
    t = np.asarray(t_s, float) - float(t_s[0])
    motion = MotionConfig(path="walk", speed_mps=cfg.speed_mps)
    pos = walk_path(rng, t, bounds_xy_m, 0.0, motion)
    heading = np.degrees(np.unwrap(np.radians(walking_azimuth_deg(t, pos))))
    az = heading + rng.uniform(*cfg.wobble_deg) * _smooth_wave(rng, t, (0.2, 0.6))
    lo_p, hi_p = cfg.pitch_range_deg
    pitch = 0.5 * (lo_p + hi_p) + 0.5 * (hi_p - lo_p) * _smooth_wave(rng, t, (0.1, 0.4))
    roll = cfg.roll_amplitude_deg * _smooth_wave(rng, t, (0.15, 0.5))
    lo_h, hi_h = cfg.height_range_m
    pos[:, 2] = 0.5 * (lo_h + hi_h) + 0.5 * (hi_h - lo_h) * _smooth_wave(rng, t, (0.05, 0.25))
    return pos, np.column_stack([wrap_deg(az), pitch, wrap_deg(roll)])


def simulate_handheld(config: HandheldConfig | None = None, seed: int = 0) -> Simulation:
    """Simulate the 3-D hand-held scenario (see the module docstring)."""
    cfg = config or HandheldConfig()
    cfg.validate()
    rng = np.random.default_rng(check_seed(seed))

    # Receivers at mixed heights, each with its own slice pattern.
    xy: list[FloatArray] = []
    spacing, tries = cfg.min_receiver_spacing_m, 0
    while len(xy) < cfg.n_receivers:
        p = rng.uniform(0.0, cfg.size_m, 2)
        tries += 1
        if tries > 10_000:
            spacing, tries = spacing * 0.8, 0
        if all(math.hypot(*(p - q)) >= spacing for q in xy):
            xy.append(p)
    patterns: dict[str, Pattern] = {}
    receivers = []
    for i in range(cfg.n_receivers):
        ceiling = i % 2 == 0
        z = rng.uniform(*(cfg.ceiling_height_m if ceiling else cfg.wall_height_m))
        az = rng.uniform(0.0, 360.0)
        pname = f"rx{i + 1}"
        patterns[pname] = smartphone_like(rng, pname, range_db=rng.uniform(4.0, 8.0))
        receivers.append(
            Receiver(pname, float(xy[i][0]), float(xy[i][1]), float(z), float(az), 0.0,
                     180.0 if ceiling else 0.0, pname)
        )  # fmt: skip
    patterns["survey-tx"] = smartphone_like(rng, "survey-tx", range_db=rng.uniform(4.0, 8.0))
    step = cfg.pattern_step_deg
    patterns["device"] = smartphone_like(
        rng, "device", range_db=rng.uniform(14.0, 20.0), azimuth_step_deg=step, polar_step_deg=step
    )
    rx_xyz = np.array([r.position_m for r in receivers])
    rx_orient = np.array([[r.azimuth_deg, r.pitch_deg, r.roll_deg] for r in receivers])
    rx_pats = tuple(patterns[r.pattern] for r in receivers)

    # Survey: a regular grid at each surveyed height, survey transmitter flat.
    n_s = grid_steps(cfg.size_m, cfg.survey_step_m)[0] + 1
    axis = np.arange(n_s) * cfg.survey_step_m
    sx, sy = np.meshgrid(axis, axis, indexing="ij")
    s_xyz = np.concatenate(
        [
            np.column_stack([sx.ravel(), sy.ravel(), np.full(sx.size, h)])
            for h in cfg.survey_heights_m
        ]
    )
    s_orient = np.column_stack([rng.uniform(0, 360, s_xyz.shape[0]), np.zeros((s_xyz.shape[0], 2))])
    s_rss = link_rss_dbm(
        cfg.channel, s_xyz, s_orient, patterns["survey-tx"], cfg.survey_tx_power_dbm,
        rx_xyz, rx_orient, rx_pats,
    )  # fmt: skip
    survey_rows = survey_rows_of(s_xyz, s_orient, s_rss, receivers)
    z_mid = height_range_middle_m(cfg.z_min_m, cfg.z_max_m, cfg.z_step_m)
    area = AreaGrid(
        0.0, cfg.size_m, 0.0, cfg.size_m, z_mid, cfg.step_m, cfg.z_min_m, cfg.z_max_m, cfg.z_step_m
    )
    orient = OrientationGrid(cfg.azimuth_step_deg, tuple(cfg.pitch_deg), tuple(cfg.roll_deg))
    site = assemble_site(
        "simulated-3d",
        area,
        orient,
        SurveyConfig(cfg.survey_tx_power_dbm, "survey-tx"),
        tuple(receivers),
        (Device(DEFAULT_TRANSMITTER, "device", cfg.tx_power_dbm),),
        patterns,
        survey_rows,
    )

    # Path, packets, truth.
    n_pk = round(cfg.duration_s / (cfg.interval_ms / 1000.0))
    t = np.arange(n_pk, dtype=np.float64) * (cfg.interval_ms / 1000.0)
    pos, ori = handheld_path(rng, t, (0.0, cfg.size_m, 0.0, cfg.size_m), cfg)
    rss = link_rss_dbm(
        cfg.channel, pos, ori, patterns["device"], cfg.tx_power_dbm, rx_xyz, rx_orient, rx_pats
    )
    packets, truth = observe_path(rng, rss, t, pos, ori, receivers, cfg.noise_db, cfg.loss_fraction)
    return Simulation(ScenarioConfig(), seed, site, packets, truth)
