"""The packet-independent arrays of one device at one site (:class:`FilterModel`).

The survey map on the candidate grid, the device pattern, the power and the
bounds the particles live in, built once per device and read by the compiled
per-packet kernels (:mod:`radiopose.filtering.kernels`), plus the grid searches
that the filter's re-entry runs through the site's scorer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radiopose.filtering import kernels as K  # noqa: N812 - the kernels' column names read as K.X_M
from radiopose.likelihood import CandidateSpace, HeardRss, Scorer, TopK
from radiopose.site import Site
from radiopose.units import FloatArray

_SEARCH_OVERSAMPLE = 16
"""``ShiftScorer``'s screened shortlist beyond ``k`` in the re-entry's searches
(speed only; docs/performance.md, "The Bayesian tracker")."""

_LookupArrays = tuple[FloatArray, FloatArray, FloatArray, float, FloatArray, FloatArray]


@dataclass(frozen=True, eq=False)
class FilterModel:
    """The packet-independent arrays of one device at one site (built once).

    ``channel_db`` is the survey map ``(n_rx, nx, ny)`` on the candidate grid
    ``grid = [x0, dx, nx, y0, dy, ny]``; ``pattern_dbi`` the device pattern with
    ``pattern_axes = [az0, az_step, polar_step]`` degrees.
    """

    space: CandidateSpace
    scorer: Scorer
    channel_db: FloatArray
    grid: FloatArray
    receivers_m: FloatArray
    pattern_dbi: FloatArray
    pattern_axes: FloatArray
    tx_power_dbm: float
    box_m: FloatArray
    tilt_box_rad: FloatArray
    cell: tuple[float, float, float]
    """One candidate cell: (x step m, y step m, azimuth step deg)."""

    @classmethod
    def build(cls, site: Site, space: CandidateSpace, scorer: Scorer) -> FilterModel:
        """The device's arrays; ``scorer`` serves the proposals (re-entry), its
        kernel run on one thread where it can (``with_parallel``): on a busy
        2-core machine a parallel region spends more CPU waiting than it saves;
        a re-entry's several searches may instead run side by side on two Python
        threads when a core is spare (:meth:`search`; docs/performance.md, "The
        Bayesian tracker")."""
        one_thread = getattr(scorer, "with_parallel", None)
        if one_thread is not None:
            # a shorter screened shortlist: ≈ 10 % less CPU in the re-entry's
            # searches, the same answers (the kernel's exactness check widens it
            # when needed)
            # each offset's search also lowers its starting threshold on the other
            # offsets' shortlist positions (the same answers, ≈ 4 % less CPU in
            # the searches; docs/performance.md, "Sixth pass")
            scorer = one_thread(False, oversample=_SEARCH_OVERSAMPLE, borrow_hints=True)
        sm = site.survey_map
        x, y = np.asarray(sm.x_m, float), np.asarray(sm.y_m, float)
        dx = float(x[1] - x[0]) if x.size > 1 else 1.0
        dy = float(y[1] - y[0]) if y.size > 1 else 1.0
        pat = space.pattern
        o = space.orientations_deg
        az = np.unique(o[:, 0])
        return cls(
            space=space,
            scorer=scorer,
            channel_db=np.ascontiguousarray(sm.m_db, dtype=np.float64),
            grid=np.array([x[0], dx, x.size, y[0], dy, y.size], dtype=np.float64),
            receivers_m=np.ascontiguousarray(space.receiver_positions_m, dtype=np.float64),
            pattern_dbi=np.ascontiguousarray(pat.directivity_dbi, dtype=np.float64),
            pattern_axes=np.array(
                [
                    float(pat.azimuth_deg[0]),
                    float(pat.azimuth_step_deg),
                    1.0 if pat.is_slice else float(pat.polar_step_deg),
                ]
            ),
            tx_power_dbm=float(space.tx_power_dbm),
            box_m=np.array([x[0], x[-1], y[0], y[-1]], dtype=np.float64),
            tilt_box_rad=np.deg2rad(
                np.array([o[:, 1].min(), o[:, 1].max(), o[:, 2].min(), o[:, 2].max()])
            ),
            cell=(dx, dy, 360.0 / az.size if az.size else 360.0),
        )

    def search(self, heards: list[HeardRss], k: int, slots: list[int]) -> list[TopK]:
        """The scorer's top-``k`` over the full grid of each of ``heards``
        (``score_heard``). ``slots[i]`` names a recurring search (here: the power
        offset's bin) so that a scorer which keeps a threshold hint starts from
        that search's previous shortlist; the compiled scorer also runs the
        searches on both cores (:meth:`ShiftScorer.score_heard_many
        <radiopose.likelihood.compiled.ShiftScorer.score_heard_many>`). The
        results do not depend on either."""
        many = getattr(self.scorer, "score_heard_many", None)
        if many is not None:
            return list(many(heards, k, slots))
        return [self.scorer.score_heard(h, k) for h in heards]

    def candidate_states(self, candidate_idx: np.ndarray) -> FloatArray:
        """Particle rows ``(n, kernels.N_COLUMNS)`` at the candidates' poses
        (position, azimuth, pitch, roll in radians), at rest, offset 0."""
        S = np.zeros((candidate_idx.size, K.N_COLUMNS))
        S[:, K.X_M : K.Z_M + 1] = self.space.candidate_positions_m(candidate_idx)
        ori = np.deg2rad(self.space.candidate_orientations_deg(candidate_idx))
        S[:, K.AZIMUTH_RAD] = ori[:, 0]
        S[:, K.PITCH_RAD] = ori[:, 1]
        S[:, K.ROLL_RAD] = ori[:, 2]
        return S

    def jitter_in_cell(self, S: FloatArray, rng: np.random.Generator) -> None:
        """Spread rows drawn at grid candidates uniformly over their cell (x, y,
        azimuth; :attr:`cell`), in place; azimuth wrapped to ``[0, 2π)``."""
        m = S.shape[0]
        dx, dy, daz = self.cell
        S[:, K.X_M] += rng.uniform(-0.5, 0.5, m) * dx
        S[:, K.Y_M] += rng.uniform(-0.5, 0.5, m) * dy
        S[:, K.AZIMUTH_RAD] = (
            S[:, K.AZIMUTH_RAD] + np.deg2rad(rng.uniform(-0.5, 0.5, m) * daz)
        ) % (2 * np.pi)

    def expected(self, S: FloatArray, heard_index: np.ndarray) -> FloatArray:
        """Expected RSS ``(n, h)`` dBm without the offset."""
        heard = np.ascontiguousarray(heard_index, dtype=np.int64)
        out = np.empty((S.shape[0], heard.size))
        # into a Python-made array: a numba function returning a new array
        # pays for boxing it (≈ 10–30 µs, more than 100 particles' lookups)
        K.expected_rss_into(np.ascontiguousarray(S), heard, *self.lookup_arrays(), out)
        return out

    def lookup_arrays(self) -> _LookupArrays:
        """The arguments of the kernels' expected-RSS lookup after the heard
        receivers: ``(rx, chan, grid, tx_dbm, d, pat)``."""
        return (
            self.receivers_m,
            self.channel_db,
            self.grid,
            self.tx_power_dbm,
            self.pattern_dbi,
            self.pattern_axes,
        )
