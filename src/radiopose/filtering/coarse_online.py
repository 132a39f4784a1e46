"""Causal: the coarse-grid HMM's forward filter, and a re-lock it proposes.

Beyond the paper (issue 15, the live filter's wrong locks; docs/filter.md,
"A causal re-lock"). Offline, :mod:`radiopose.filtering.coarse_track` runs
the coarse-grid HMM over the whole file and hands its best path to the
arbiter. The live server has no whole file: its particle filter leaves a
wrong lock only through re-entry, which weighs a hypothesis against the
filter on one evidence window (0.1 s), and at σ = 3 dB one window rarely
outweighs the jump prior. The HMM's *forward* pass is causal: after each
window it holds ``p(pose, b | readings so far)`` on the coarse grid (the
same grid, windows, weights and random walk as offline), which integrates
every window since the track began, with the motion's continuity.

:class:`OnlineCoarse` runs that forward pass packet by packet (a window is
closed, and the compiled forward step runs, when the first packet beyond it
arrives). :func:`relock_proposal` compares it with a particle cloud: the
HMM's posterior mass ``p_in`` of the cells the cloud occupies (dilated by
one cell in x, y and azimuth) against the mass outside. When the log odds
``log((1 − p_in) / p_in)`` exceed a threshold the filter is re-locked
(:meth:`radiopose.filtering.particle.ParticleFilter` with
``FilterConfig.coarse_relock``): a fraction of its particles is replaced by
draws from the HMM's posterior outside the cloud's cells, and the two parts'
weights are set to the HMM's masses, so the filter's own likelihood decides
from there on.

Nothing here reads the future: the proposal at a packet uses the windows
closed before it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from radiopose.filtering.coarse_track import (
    CoarseSettings,
    _forward_window,
    _grid_shape,
    _kernel,
    _window_terms,
)
from radiopose.filtering.offset_profile import CoarseTable
from radiopose.likelihood import HeardRss
from radiopose.units import FloatArray


@dataclass(frozen=True, eq=False)
class CoarseGrid:
    """The coarse grid as the online HMM uses it (built once per device model).

    Attributes
    ----------
    table
        The grid's poses and expected RSS.
    shape
        ``(nx, ny, na)``.
    origin
        ``(x0 m, y0 m)`` of cell ``(0, 0)``.
    step
        ``(dx m, dy m, da deg)``: the cells' spacing.
    """

    table: CoarseTable
    shape: tuple[int, int, int]
    origin: tuple[float, float]
    step: tuple[float, float, float]

    @classmethod
    def build(cls, table: CoarseTable) -> CoarseGrid:
        shape = _grid_shape(table)
        xs = np.unique(table.poses[:, 0])
        ys = np.unique(table.poses[:, 1])
        dx = float(xs[1] - xs[0]) if xs.size > 1 else 1.0
        dy = float(ys[1] - ys[0]) if ys.size > 1 else 1.0
        return cls(table, shape, (float(xs[0]), float(ys[0])), (dx, dy, 360.0 / shape[2]))

    def cells(self, x_m: FloatArray, y_m: FloatArray, azimuth_deg: FloatArray) -> tuple:
        """The nearest cell ``(i, j, a)`` of each pose (clipped to the grid)."""
        nx, ny, na = self.shape
        i = np.clip(np.rint((x_m - self.origin[0]) / self.step[0]), 0, nx - 1).astype(np.int64)
        j = np.clip(np.rint((y_m - self.origin[1]) / self.step[1]), 0, ny - 1).astype(np.int64)
        a = np.rint(np.asarray(azimuth_deg) / self.step[2]).astype(np.int64) % na
        return i, j, a


class OnlineCoarse:
    """The coarse HMM's forward filter, fed one packet at a time (module docstring).

    Picklable (a live checkpoint carries it): the grid is passed to each call,
    not kept.
    """

    def __init__(self, grid: CoarseGrid, settings: CoarseSettings, reacquire_gap_s: float):
        self.settings = settings
        self.reacquire_gap_s = float(reacquire_gap_s)
        self.offsets_db = np.asarray(settings.offsets_db, dtype=float)
        self.alpha = np.empty((self.offsets_db.size, *grid.shape))
        self.log_evidence = np.zeros(self.offsets_db.size)
        self.n_windows = 0  # windows read (enough receivers)
        self._t0: float | None = None
        self._index = 0
        self._per: dict[int, list[float]] = {}
        self._times: list[float] = []
        self._last_read_s = -math.inf

    def add(self, grid: CoarseGrid, t_s: float, heard: HeardRss, sigma_db: float) -> bool:
        """Take one packet (time order); returns whether a window with a reading
        was closed before it (the posterior changed). ``sigma_db``: the readings'
        noise σ now (the filter's estimate), dB."""
        if self._t0 is None:
            self._t0 = t_s
        k = math.floor((t_s - self._t0) / self.settings.window_s)
        closed = False
        if k != self._index:
            closed = self._close(grid, sigma_db)
            self._per = {}
            self._times = []
            self._index = k
        if heard.n_heard:
            self._times.append(t_s)
        for r, v in zip(heard.receiver_index.tolist(), heard.rss_dbm.tolist(), strict=True):
            self._per.setdefault(r, []).append(v)
        return closed

    def _close(self, grid: CoarseGrid, sigma_db: float) -> bool:
        cs = self.settings
        if len(self._per) < cs.min_receivers or not self._times:
            return False
        rx = np.array(sorted(self._per), dtype=np.int64)
        med = np.array([float(np.median(self._per[r])) for r in rx])
        n = np.array([float(len(self._per[r])) for r in rx])
        t = float(np.mean(self._times))
        if t - self._last_read_s > self.reacquire_gap_s:
            steps = 0
        else:
            steps = min(max(round((t - self._last_read_s) / cs.window_s), 1), cs.max_steps)
        self._last_read_s = t
        w = n / ((math.pi / 2) * sigma_db**2 + cs.grid_sigma_db**2 * n)
        terms = _window_terms(grid.table.table_dbm, rx, med, w)
        _forward_window(
            self.alpha, steps, *terms, self.offsets_db, _kernel(cs.step_sd_cells),
            _kernel(cs.turn_sd_cells), self.log_evidence,
        )  # fmt: skip
        self.n_windows += 1
        return True

    def offset_posterior(self, prior_db: float, prior_sd_db: float) -> FloatArray:
        """``p(b | readings so far)`` over :attr:`offsets_db` under a Gaussian prior."""
        lp = self.log_evidence - 0.5 * ((self.offsets_db - prior_db) / prior_sd_db) ** 2
        lp = np.where(np.isfinite(lp), lp, -np.inf)
        p = np.exp(lp - lp.max())
        return p / p.sum()


@dataclass(frozen=True)
class Relock:
    """A re-lock proposal (:func:`relock_proposal`): the HMM's posterior masses
    of the cloud's cells and of the mode outside them, ``log_odds`` =
    ``log(p_mode / p_in)``, and the drawn hypotheses ``x_m``, ``y_m``,
    ``azimuth_deg``, ``offset_db`` (each ``(m,)``) from that mode."""

    p_in: float
    p_mode: float
    log_odds: float
    x_m: FloatArray
    y_m: FloatArray
    azimuth_deg: FloatArray
    offset_db: FloatArray


def dilated(grid: CoarseGrid, i: np.ndarray, j: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Boolean ``(nx, ny, na)``: the cells ``(i, j, a)`` dilated by one cell in x
    and y (clipped) and in azimuth (wrapping)."""
    nx, ny, na = grid.shape
    mask = np.zeros(grid.shape, dtype=bool)
    for di in (-1, 0, 1):
        ii = np.clip(i + di, 0, nx - 1)
        for dj in (-1, 0, 1):
            jj = np.clip(j + dj, 0, ny - 1)
            for da in (-1, 0, 1):
                mask[ii, jj, (a + da) % na] = True
    return mask


def relock_proposal(
    hmm: OnlineCoarse,
    grid: CoarseGrid,
    x_m: FloatArray,
    y_m: FloatArray,
    azimuth_deg: FloatArray,
    prior_db: float,
    prior_sd_db: float,
    m: int,
    rng: np.random.Generator,
) -> Relock | None:
    """Compare the HMM's posterior with a particle cloud (poses ``x_m``,
    ``y_m``, ``azimuth_deg``): ``p_in`` is the pose posterior's mass on the
    cloud's cells (dilated by one cell), ``p_mode`` its mass on the
    neighbourhood (one cell) of its largest cell outside them, the log odds
    ``log(p_mode / p_in)``; ``m`` hypotheses are drawn from the joint
    posterior over (offset, pose) on that neighbourhood, placed uniformly
    within their cells. ``None`` before any window was read or when the
    posterior has no mass outside the cloud.

    A mode, not all the mass outside: early in a track, and at σ = 3 dB, the
    posterior is broad, and its mass outside a compact cloud can exceed the
    mass inside without any other pose being more likely than the cloud's
    (session 16's first version compared with all the mass outside and
    re-locked good tracks)."""
    if hmm.n_windows == 0:
        return None
    p_b = hmm.offset_posterior(prior_db, prior_sd_db)
    joint = p_b[:, None, None, None] * hmm.alpha
    pose = joint.sum(axis=0)
    cloud = dilated(grid, *grid.cells(x_m, y_m, azimuth_deg))
    outside = np.where(cloud, 0.0, pose)
    best = int(np.argmax(outside))
    if not outside.flat[best] > 0:
        return None
    region = dilated(grid, *(np.atleast_1d(v) for v in np.unravel_index(best, grid.shape)))
    region &= ~cloud
    p_in = float(np.clip(pose[cloud].sum(), 1e-300, 1.0))
    p_mode = float(pose[region].sum())
    w = np.where(region[None], joint, 0.0).ravel()
    pick = rng.choice(w.size, size=m, p=w / w.sum())
    b, i, j, a = np.unravel_index(pick, joint.shape)
    dx, dy, da = grid.step
    x = grid.origin[0] + (i + rng.uniform(-0.5, 0.5, m)) * dx
    y = grid.origin[1] + (j + rng.uniform(-0.5, 0.5, m)) * dy
    az = ((a + rng.uniform(-0.5, 0.5, m)) * da) % 360.0
    log_odds = math.log(p_mode) - math.log(p_in)
    return Relock(p_in, p_mode, log_odds, x, y, az, hmm.offsets_db[b].astype(float))
