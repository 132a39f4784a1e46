"""Turn the BLE dataset into a site and tracks (``radiopose import tetam``).

:func:`import_tetam` writes, atomically (all or nothing)::

    OUT/site/                      the site: survey from the histograms only
    OUT/tracks/<name>/packets.csv  the track's advertisements (tetam.py's rule)
    OUT/tracks/<name>/truth.csv    the camera pose at each advertisement
    OUT/tracks/<name>/heldout-site/ the site with the survey extended by every
                                   *other* track's readings (never this track's)

The held-out site is the cross-validated calibration (docs/real-data.md): the
beacon's pattern, transmit power and the sensors' gains are not given by the
dataset, and the 126 surveyed points leave 2–3 m between fingerprints. The
other tracks' readings, at their camera positions, are averaged per sensor in
``cell_m`` cells (cells with at least ``min_readings`` readings) and added to
the survey as points of the survey transmitter (the beacon itself), which
absorbs the sensors' gains and the beacon's power into the map. A track is
never localised with a map that contains its own readings
(:func:`heldout_survey` takes the names to leave out; tests check it).
"""

from __future__ import annotations

import math
import os
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radiopose.errors import InputError
from radiopose.realdata.tetam import (
    BEACON_PATTERN,
    ImportSummary,
    SurveyPoint,
    TetamDataset,
    read_dataset,
    track_packets,
)
from radiopose.tables import staged_directory, write_table
from radiopose.tracker_settings import write_tracker_toml


@dataclass(frozen=True)
class ImportSettings:
    """How the dataset becomes a site (defaults measured in docs/real-data.md).

    Attributes
    ----------
    step_m
        Candidate grid step, metres.
    margin_m
        Added to the dataset's limits on every side, metres.
    burst_gap_s
        Readings closer than this to the previous one belong to one advertisement, seconds.
    cell_m, min_readings
        The held-out sites: other tracks' readings averaged per sensor in
        ``cell_m`` cells holding at least ``min_readings`` readings.
    filter_settings
        Written to ``site/tracker.toml`` (read by ``radiopose locate``):
        ``[filter]`` keys of :class:`radiopose.filtering.FilterConfig` and
        ``smoothing_lag_s``.
    """

    step_m: float = 0.1
    margin_m: float = 0.5
    burst_gap_s: float = 0.05
    cell_m: float = 1.0
    min_readings: int = 3
    filter_settings: tuple[tuple[str, float | str], ...] = ()
    smoothing_lag_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("step_m", "burst_gap_s", "cell_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"import setting {name} = {v!r} must be > 0")
        if not (math.isfinite(self.margin_m) and self.margin_m >= 0):
            raise InputError(f"import setting margin_m = {self.margin_m!r} must be >= 0")
        if self.min_readings < 1:
            raise InputError(f"import setting min_readings = {self.min_readings!r} must be >= 1")


def _snap_out(lo: float, hi: float, step: float) -> tuple[float, float]:
    a = math.floor(round(lo / step, 9)) * step
    b = math.ceil(round(hi / step, 9)) * step
    return round(a, 9), round(b, 9)


def survey_height_m(survey: Iterable[SurveyPoint]) -> float:
    """The most common surveyed height (the candidate height of the 2-D search), metres."""
    zs, counts = np.unique([round(p.position_m[2], 3) for p in survey], return_counts=True)
    return float(zs[int(np.argmax(counts))])


def heldout_survey(
    ds: TetamDataset, leave_out: Collection[str], cell_m: float, min_readings: int
) -> list[SurveyPoint]:
    """Survey points from the readings of every track *not* in ``leave_out``: per
    sensor, the mean RSSI (dBm) of the readings whose camera position falls in
    each ``cell_m`` cell, placed at the cell centre, for cells with at least
    ``min_readings`` readings."""
    names = {t.name for t in ds.tracks}
    unknown = set(leave_out) - names
    if unknown:
        raise InputError(f"unknown track(s) {sorted(unknown)} (tracks: {sorted(names)})")
    cells: dict[tuple[str, int, int], list[tuple[float, float]]] = {}
    for tr in ds.tracks:
        if tr.name in leave_out:
            continue
        ij = np.floor(tr.position_m[:, :2] / cell_m).astype(np.int64)
        for k in range(tr.timestamp_s.size):
            key = (str(tr.sensor[k]), int(ij[k, 0]), int(ij[k, 1]))
            cells.setdefault(key, []).append((float(tr.rss_dbm[k]), float(tr.position_m[k, 2])))
    out = []
    for (sensor, i, j), values in sorted(cells.items()):
        if len(values) >= min_readings:
            v = np.asarray(values)
            xyz = ((i + 0.5) * cell_m, (j + 0.5) * cell_m, float(v[:, 1].mean()))
            out.append(SurveyPoint(xyz, sensor, float(v[:, 0].mean())))
    return out


def write_site_dir(
    ds: TetamDataset,
    directory: str | os.PathLike[str],
    settings: ImportSettings,
    extra_survey: Iterable[SurveyPoint] = (),
) -> Path:
    """Write a site directory for the dataset (survey = histograms + ``extra_survey``)."""
    d = Path(directory)
    (d / "patterns").mkdir(parents=True, exist_ok=True)
    x0, y0, x1, y1 = ds.limits_m
    m = settings.margin_m
    xa, xb = _snap_out(x0 - m, x1 + m, settings.step_m)
    ya, yb = _snap_out(y0 - m, y1 + m, settings.step_m)
    z = survey_height_m(ds.survey)
    (d / "site.toml").write_text(
        "# Imported by `radiopose import tetam` (docs/real-data.md).\n"
        'name = "ble-tetam"\n\n'
        f"[area]\nx_min_m = {xa!r}\nx_max_m = {xb!r}\ny_min_m = {ya!r}\ny_max_m = {yb!r}\n"
        f"z_m = {z!r}\nstep_m = {settings.step_m!r}\n\n"
        "# The beacon's pattern is isotropic here (no usable pattern signal): one azimuth.\n"
        "[orientations]\nazimuth_step_deg = 360.0\npitch_deg = [0.0]\nroll_deg = [0.0]\n\n"
        "# The survey transmitter is the beacon itself: power and pattern cancel.\n"
        f'[survey]\ntx_power_dbm = 0.0\npattern = "{BEACON_PATTERN}"\ninterpolation = "linear"\n',
        encoding="utf-8",
    )
    write_table(
        d / "patterns" / f"{BEACON_PATTERN}.csv",
        {
            "azimuth_deg": np.arange(0.0, 360.0, 90.0),
            "polar_deg": np.full(4, 90.0),
            "directivity_dbi": np.zeros(4),
        },
    )
    s = ds.sensors
    write_table(
        d / "receivers.csv",
        {
            "receiver_id": [r.alias for r in s],
            "x_m": np.array([r.position_m[0] for r in s]),
            "y_m": np.array([r.position_m[1] for r in s]),
            "z_m": np.array([r.position_m[2] for r in s]),
            "azimuth_deg": np.zeros(len(s)),
            "pitch_deg": np.zeros(len(s)),
            "roll_deg": np.zeros(len(s)),
            "pattern": [BEACON_PATTERN] * len(s),
        },
    )
    write_table(
        d / "devices.csv",
        {"transmitter": [ds.beacon_id], "pattern": [BEACON_PATTERN], "tx_power_dbm": np.zeros(1)},
    )
    pts = [*ds.survey, *extra_survey]
    write_table(
        d / "survey.csv",
        {
            "x_m": np.array([p.position_m[0] for p in pts]),
            "y_m": np.array([p.position_m[1] for p in pts]),
            "z_m": np.array([p.position_m[2] for p in pts]),
            "receiver_id": [p.sensor for p in pts],
            "rss_dbm": np.array([p.rss_dbm for p in pts]),
            "azimuth_deg": np.zeros(len(pts)),
            "pitch_deg": np.zeros(len(pts)),
            "roll_deg": np.zeros(len(pts)),
        },
        decimals={"rss_dbm": 3},
    )
    if settings.filter_settings or settings.smoothing_lag_s is not None:
        write_tracker_toml(
            d / "tracker.toml",
            dict(settings.filter_settings),
            settings.smoothing_lag_s,
            comment="Filter settings for this site, chosen by leave-one-track-out "
            "(docs/real-data.md).",
        )
    return d


def write_track_dir(packets, directory: str | os.PathLike[str], beacon_id: str) -> Path:
    """Write one track's ``packets.csv`` and ``truth.csv`` (a :class:`TrackPackets`)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    n = packets.packet_id.size
    write_table(
        d / "packets.csv",
        {
            "packet_id": packets.packet_id,
            "timestamp_s": packets.packet_time_s,
            "transmitter": [beacon_id] * n,
            "receiver_id": packets.receiver_id,
            "rss_dbm": packets.rss_dbm,
        },
        decimals={"timestamp_s": 6, "rss_dbm": 2},
    )
    o = packets.truth_orientation_deg
    write_table(
        d / "truth.csv",
        {
            "timestamp_s": packets.truth_time_s,
            "transmitter": [beacon_id] * packets.truth_time_s.size,
            "x_m": packets.truth_position_m[:, 0],
            "y_m": packets.truth_position_m[:, 1],
            "z_m": packets.truth_position_m[:, 2],
            "azimuth_deg": o[:, 0],
            "pitch_deg": o[:, 1],
            "roll_deg": o[:, 2],
        },
        decimals={"timestamp_s": 6, "azimuth_deg": 3, "pitch_deg": 3, "roll_deg": 3},
    )
    return d


def import_tetam(
    dataset_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    settings: ImportSettings | None = None,
) -> ImportSummary:
    """Import the dataset into ``out_dir`` (see the module docstring); all or nothing."""
    settings = settings or ImportSettings()
    ds = read_dataset(dataset_dir)
    with staged_directory(out_dir) as stage:
        write_site_dir(ds, stage / "site", settings)
        for tr in ds.tracks:
            pk = track_packets(tr, settings.burst_gap_s, ds.summary)
            d = write_track_dir(pk, stage / "tracks" / tr.name, ds.beacon_id)
            extra = heldout_survey(ds, {tr.name}, settings.cell_m, settings.min_readings)
            write_site_dir(ds, d / "heldout-site", settings, extra)
    return ds.summary


SHIPPED_FILTER_SETTINGS: tuple[tuple[str, float | str], ...] = (
    ("huber_c", 1.0),
    ("sigma_prior_db", 5.0),
    ("sigma_floor_db", 5.0),
    ("offset_prior_sd_db", 1.0),
    ("accel_noise_mps2", 0.2),
    ("likelihood", "huber"),
)
"""The ``filter`` settings ``radiopose import tetam`` writes into ``site/tracker.toml``:
the candidate that leave-one-track-out chose for most tracks (docs/real-data.md).
The scored numbers never use this constant: each track's settings are chosen on
the other tracks (:func:`radiopose.realdata.experiment.choose_filter_settings`)."""
SHIPPED_SMOOTHING_LAG_S = 10.0
"""The offline smoother's lag for this site (advertisements come every ~0.45 s)."""


def shipped_import_settings() -> ImportSettings:
    """The importer's settings with the site's tracker settings (``tracker.toml``)."""
    return ImportSettings(
        filter_settings=SHIPPED_FILTER_SETTINGS, smoothing_lag_s=SHIPPED_SMOOTHING_LAG_S
    )
