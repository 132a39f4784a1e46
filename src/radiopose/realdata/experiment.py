"""Localise every track of the BLE site and score it against the camera truth.

Cross-validation (docs/real-data.md): each track is localised on its
*held-out* site (:func:`radiopose.realdata.build.heldout_survey` leaves the
track out), and the ``filter``'s settings for a track are chosen among
:data:`FILTER_CANDIDATES` by their mean error on the *other* tracks, each of
those localised on a site that leaves out both itself and the test track. So
nothing learnt from a track — map, gains, power or settings — is used on it.

Anchors, run on the same packets and the same held-out map:

* ``lms`` (log-distance least squares), ``top`` and ``full`` (the paper's);
* ``hmm`` / ``hmm-fb``: the simple grid HMM of the issue — a 0.2 m grid of
  the survey map, Gaussian blur motion (``hmm_speed_mps`` per second), robust
  (Huber) Gaussian readings with σ = ``hmm_sigma_db`` — causally and with
  forward-backward smoothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from radiopose.estimates import Estimates, PoseEstimate
from radiopose.evaluate.scoring import match_truth
from radiopose.filtering import FilterConfig
from radiopose.packets import Packets, Truth, group_packets
from radiopose.realdata.build import ImportSettings, heldout_survey, write_site_dir
from radiopose.realdata.tetam import TetamDataset, TrackPackets, track_packets
from radiopose.site import Site
from radiopose.site_io import load_site
from radiopose.tracker import TrackerConfig, locate

FilterSetting = tuple[str, float | str]
"""One ``FilterConfig`` field and its value."""

_LIKELIHOODS: tuple[tuple[FilterSetting, ...], ...] = (
    (("likelihood", "mixture"), ("outlier_probability", 0.3), ("outlier_range_db", 20.0)),
    (("likelihood", "huber"),),
)

FILTER_CANDIDATES: tuple[tuple[FilterSetting, ...], ...] = tuple(
    (
        ("huber_c", 1.0),
        ("sigma_prior_db", 5.0),
        ("sigma_floor_db", 5.0),
        ("offset_prior_sd_db", 1.0),
        ("accel_noise_mps2", acc),
        *likelihood,
    )
    for likelihood in _LIKELIHOODS
    for acc in (0.1, 0.2, 0.5)
)
"""The ``filter`` settings tried per held-out track: white acceleration in
m/s²/√Hz, and the per-receiver likelihood — the filter's default outlier
mixture (at 30 % over 20 dB for this site's heavy tails: every track chose it
over the simulator's 5 % over 60 dB) or the previous design's Huber-weighted
Gaussian (``likelihood = "huber"``, threshold ``huber_c`` = 1σ;
docs/real-data.md, "Which part of the filter"); σ floor and prior 5 dB (the
only value a track chose when 3 dB was also a candidate); ``huber_c`` is also
the clip of the σ estimate's residuals; power offset prior 1 dB since the
survey transmitter is the beacon itself."""

OFFLINE_LAG_S = 10.0
"""The fixed lag of the offline ``filter`` here: advertisements come every ~0.45 s."""


@dataclass(frozen=True, eq=False)
class TrackData:
    """A track as radiopose tables."""

    name: str
    packets: Packets
    truth: Truth


def track_tables(tp: TrackPackets, beacon_id: str) -> TrackData:
    """:class:`Packets` and :class:`Truth` of an imported track (no files)."""
    n = tp.packet_id.size
    pk = Packets(
        tp.packet_id,
        tp.packet_time_s,
        np.array([beacon_id] * n, dtype=object),
        tp.receiver_id,
        tp.rss_dbm,
    )
    m = tp.truth_time_s.size
    tr = Truth(
        tp.truth_time_s,
        np.array([beacon_id] * m, dtype=object),
        tp.truth_position_m,
        tp.truth_orientation_deg,
    )
    return TrackData(tp.name, pk, tr)


class SiteCache:
    """Held-out sites by the set of tracks left out (built once, in ``work_dir``)."""

    def __init__(self, ds: TetamDataset, work_dir: Path, settings: ImportSettings) -> None:
        self.ds, self.work_dir, self.settings = ds, work_dir, settings
        self._sites: dict[frozenset[str], Site] = {}

    def site(self, leave_out: Iterable[str]) -> Site:
        key = frozenset(leave_out)
        if key not in self._sites:
            d = self.work_dir / ("site-" + "-".join(sorted(key)) if key else "site")
            extra = heldout_survey(self.ds, key, self.settings.cell_m, self.settings.min_readings)
            self._sites[key] = load_site(write_site_dir(self.ds, d, self.settings, extra))
        return self._sites[key]


def position_errors_m(truth: Truth, est: Estimates) -> np.ndarray:
    """Euclidean position error of each estimate (the contract's scoring), metres."""
    idx = match_truth(truth, est)
    return np.linalg.norm(est.position_m - truth.position_m[idx], axis=1)


def filter_config(overrides: Sequence[FilterSetting], lag_s: float | None) -> TrackerConfig:
    return TrackerConfig(
        filter=replace(FilterConfig(), **dict[str, Any](overrides)), smoothing_lag_s=lag_s
    )


def run_filter(site: Site, track: TrackData, overrides, lag_s: float | None) -> Estimates:
    return locate(site, track.packets, "filter", filter_config(overrides, lag_s)).estimates


def choose_filter_settings(
    cache: SiteCache,
    tracks: Sequence[TrackData],
    test: str,
    progress: Callable[[str], None] | None = None,
) -> tuple[FilterSetting, ...]:
    """The candidate with the lowest mean error over the tracks other than ``test``,
    each localised on the site that leaves out itself and ``test``."""
    best, best_err = FILTER_CANDIDATES[0], math.inf
    for cand in FILTER_CANDIDATES:
        errs = []
        for tr in tracks:
            if tr.name == test:
                continue
            site = cache.site({tr.name, test})
            errs.append(position_errors_m(tr.truth, run_filter(site, tr, cand, OFFLINE_LAG_S)))
        err = float(np.concatenate(errs).mean())
        if progress is not None:
            progress(f"{test}: {dict(cand)} -> {err:.3f} m on the other tracks")
        if err < best_err:
            best, best_err = cand, err
    return best


# ----------------------------------------------------------------------------- grid HMM
def grid_hmm(
    site: Site,
    packets: Packets,
    *,
    stride: int = 2,
    sigma_db: float = 5.5,
    huber_c: float = 1.5,
    speed_mps: float = 1.0,
    smooth: bool = False,
) -> Estimates:
    """The simple grid HMM baseline (the issue's anchor): the survey map on every
    ``stride``-th candidate, a Gaussian-blur motion of σ = ``speed_mps``·Δt, Huber
    readings; causal (posterior mean of the filter) or forward-backward."""
    sm = site.survey_map
    rx = {r: i for i, r in enumerate(sm.receiver_ids)}
    maps = sm.m_db[:, ::stride, ::stride]
    xs, ys = sm.x_m[::stride], sm.y_m[::stride]
    cell = float(xs[1] - xs[0])
    obs = group_packets(packets)
    n = len(obs)
    loglik = np.empty((n, *maps.shape[1:]))
    for k, o in enumerate(obs):
        idx = [rx[r] for r in o.receiver_ids]
        z = (np.asarray(o.rss_dbm)[:, None, None] - maps[idx]) / sigma_db
        a = np.abs(z)
        loglik[k] = -np.where(a <= huber_c, 0.5 * z * z, huber_c * a - 0.5 * huber_c**2).sum(axis=0)
    times = np.array([o.timestamp_s for o in obs])
    alpha = np.empty_like(loglik)
    prior = np.full(maps.shape[1:], 1.0 / maps[0].size)
    for k in range(n):
        if k:
            s = speed_mps * (times[k] - times[k - 1]) / cell
            prior = gaussian_filter(alpha[k - 1], s, mode="constant") if s > 0 else alpha[k - 1]
        p = prior * np.exp(loglik[k] - loglik[k].max())
        alpha[k] = p / p.sum()
    post = alpha
    if smooth:
        post = np.empty_like(alpha)
        beta = np.ones(maps.shape[1:])
        post[-1] = alpha[-1]
        for k in range(n - 2, -1, -1):
            s = speed_mps * (times[k + 1] - times[k]) / cell
            b = beta * np.exp(loglik[k + 1] - loglik[k + 1].max())
            beta = gaussian_filter(b, s, mode="constant") if s > 0 else b
            beta /= beta.max()
            q = alpha[k] * beta
            post[k] = q / q.sum()
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    z_m = float(site.area.z_m)
    poses = [
        PoseEstimate(
            o.timestamp_s,
            o.transmitter,
            o.packet_id,
            (float((post[k] * gx).sum()), float((post[k] * gy).sum()), z_m),
            (0.0, 0.0, 0.0),
            "hmm",
        )
        for k, o in enumerate(obs)
    ]
    return Estimates.from_poses(poses)


# ----------------------------------------------------------------------------- run
@dataclass(frozen=True)
class TrackResult:
    """Position errors of every variant on one track, metres, and the filter settings used."""

    name: str
    n_packets: int
    errors_m: dict[str, np.ndarray]
    coverage: dict[str, float]
    filter_settings: tuple[FilterSetting, ...]


VARIANTS = ("filter", "filter-causal", "full", "top", "lms", "hmm", "hmm-fb")


def run_track(
    cache: SiteCache,
    tracks: Sequence[TrackData],
    test: TrackData,
    progress: Callable[[str], None] | None = None,
) -> TrackResult:
    """Every variant on ``test`` with nothing learnt from it."""
    settings = choose_filter_settings(cache, tracks, test.name, progress)
    site = cache.site({test.name})
    est: dict[str, Estimates] = {
        "filter": run_filter(site, test, settings, OFFLINE_LAG_S),
        "filter-causal": run_filter(site, test, settings, None),
        "hmm": grid_hmm(site, test.packets),
        "hmm-fb": grid_hmm(site, test.packets, smooth=True),
    }
    for m in ("full", "top", "lms"):
        est[m] = locate(site, test.packets, m, TrackerConfig()).estimates
    n = len(test.truth)
    errors = {k: position_errors_m(test.truth, e) for k, e in est.items()}
    cov = {k: len(e) / n for k, e in est.items()}
    return TrackResult(test.name, n, errors, cov, settings)


def load_tracks(ds: TetamDataset, settings: ImportSettings) -> list[TrackData]:
    return [
        track_tables(track_packets(t, settings.burst_gap_s, ds.summary), ds.beacon_id)
        for t in ds.tracks
    ]


# ----------------------------------------------------------------------------- orientation
def _circ_abs_diff_deg(a: np.ndarray, b: np.ndarray | float) -> np.ndarray:
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def most_common_heading_deg(tracks: Iterable[TrackData], bin_deg: float = 10.0) -> float:
    """The centre of the fullest ``bin_deg`` azimuth bin of the tracks' truth, degrees."""
    az = np.concatenate([t.truth.orientation_deg[:, 0] for t in tracks]) % 360.0
    counts, edges = np.histogram(az, bins=np.arange(0.0, 360.0 + bin_deg, bin_deg))
    k = int(np.argmax(counts))
    return float(0.5 * (edges[k] + edges[k + 1]))


@dataclass(frozen=True)
class PatternCheck:
    """Is there a repeatable body-frame pattern? For one held-out track.

    Attributes
    ----------
    residual_sd_db
        Std of the readings' residual against the held-out map at the true position, dB.
    after_pattern_sd_db
        The same after subtracting the pattern learnt from the other tracks
        (mean residual per 45° bin of the sensor's bearing in the body frame), dB.
    pattern_range_db
        Max − min of the learnt pattern's bins, dB.
    """

    residual_sd_db: float
    after_pattern_sd_db: float
    pattern_range_db: float


def _residuals(site: Site, track: TrackData) -> tuple[np.ndarray, np.ndarray]:
    """Residual (dB) of every reading against the map at the true position, and the
    bearing of its sensor in the body frame (degrees; 0 = the beacon's forward, +y)."""
    sm = site.survey_map
    from scipy.interpolate import RegularGridInterpolator

    fn = {
        r: RegularGridInterpolator(
            (sm.x_m, sm.y_m), sm.m_db[i], bounds_error=False, fill_value=None
        )
        for i, r in enumerate(sm.receiver_ids)
    }
    rx = {r.receiver_id: r.position_m for r in site.receivers}
    idx = {}
    t_ns = np.round(track.truth.timestamp_s * 1e6).astype(np.int64)
    for k, t in enumerate(t_ns):
        idx[int(t)] = k
    res, bearing = [], []
    for i in range(len(track.packets)):
        k = idx[int(np.round(track.packets.timestamp_s[i] * 1e6))]
        p = track.truth.position_m[k]
        r = str(track.packets.receiver_id[i])
        res.append(track.packets.rss_dbm[i] - float(fn[r]([p[:2]])[0]))
        world = math.degrees(math.atan2(rx[r][1] - p[1], rx[r][0] - p[0]))
        forward = track.truth.orientation_deg[k, 0] + 90.0  # body +y in world, degrees
        bearing.append((world - forward) % 360.0)
    return np.asarray(res), np.asarray(bearing)


def pattern_check(cache: SiteCache, tracks: Sequence[TrackData], test: str) -> PatternCheck:
    """Learn a 45°-bin body-frame pattern from the other tracks' residuals (each on its
    own held-out map); apply it to ``test``'s residuals (on ``test``'s held-out map)."""
    bins = np.arange(0.0, 405.0, 45.0)
    sums, counts = np.zeros(8), np.zeros(8)
    for tr in tracks:
        if tr.name == test:
            continue
        r, b = _residuals(cache.site({tr.name, test}), tr)
        r = r - r.mean()
        k = np.clip(np.digitize(b, bins) - 1, 0, 7)
        np.add.at(sums, k, r)
        np.add.at(counts, k, 1)
    pattern = sums / np.maximum(counts, 1)
    me = next(t for t in tracks if t.name == test)
    r, b = _residuals(cache.site({test}), me)
    r = r - r.mean()
    k = np.clip(np.digitize(b, bins) - 1, 0, 7)
    return PatternCheck(
        float(r.std()), float((r - pattern[k]).std()), float(pattern.max() - pattern.min())
    )


def heading_errors_deg(track: TrackData, heading_deg: float) -> np.ndarray:
    """Azimuth error of always answering ``heading_deg``, degrees."""
    return _circ_abs_diff_deg(track.truth.orientation_deg[:, 0], heading_deg)
