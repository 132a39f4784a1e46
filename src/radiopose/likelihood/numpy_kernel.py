"""A vectorised numpy scorer over a precomputed float32 table, exact on its shortlist.

Paper, "Enhanced Localisation Pipeline", steps 1–2, computed faster than the
reference but returning the same top-k.

Precomputation (once per site and device): the packet-independent table

    G'[p, o, r] = M_r(p) + P_tx + D_t(p, o → r) − c_r          (float32, dB)

centred per receiver by ``c_r`` (the mean of ``M_r + P_tx``) to keep float32
round-off small. When every candidate orientation is a pure azimuth (pitch =
roll = 0), ``D_t`` over the azimuths at one position is the pattern read at
``phi_0 − azimuth`` — a circular shift — so the table is filled with lookups
only, no per-candidate trigonometry. Also kept: ``S2_H = Σ_{r∈H} G'_r²`` for
each set ``H`` of heard receivers seen so far (``+inf`` where a heard
receiver's ``M_r`` is NaN, so such candidates are never selected).

Per packet, with ``w_r = RSS_r − c_r`` for heard receivers and 0 otherwise:

    h · MSE ≈ S2_H − 2 (G' · w) + Σ w²        (one float32 matrix-vector product)

Screening: the ``k``-th smallest of the per-position minima is an upper bound
``τ`` on the ``k``-th smallest candidate (those are ``k`` distinct candidates),
so every candidate of the true top-k has a screened value ``≤ τ + 2δ``, where
``δ`` bounds the float32 error (derived from the table's magnitudes). The
shortlist is then rescored exactly in float64 with the reference's own function
and the top-k taken with the same tie rule — identical output to the
reference, at ~50–100 ms per packet on the paper's 201 × 201 × 360 grid.

Memory: ``4 · n_candidates · (n_rx + 1)`` bytes for the table (with the full
set's ``S2``), ``4 · n_candidates`` per cached subset ``S2`` and one or two
such temporaries per packet (≈ 0.4 GB on the paper's grid).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from radiopose.geometry import direction_to_pattern_angles_deg
from radiopose.likelihood.candidates import (
    CandidateSpace,
    HeardRss,
    directivity_dbi,
    exact_mse_db2,
)
from radiopose.likelihood.capabilities import ScorerBase
from radiopose.likelihood.topk import TopK, select_topk

_EPS32 = float(np.finfo(np.float32).eps)


def build_table(space: CandidateSpace, chunk_terms: int = 4_000_000) -> tuple[np.ndarray, ...]:
    """The centred float32 table ``G'`` and its companions.

    Returns
    -------
    table
        ``(n_pos · n_orient, n_rx + 1)`` float32, column-major: columns ``r`` hold
        ``G'_r = M_r + P_tx + D − c_r`` (0 where ``M_r`` is NaN); the last column
        holds ``S2`` of the full receiver set (``+inf`` where any ``M_r`` is NaN).
        Column-major makes the per-packet product a few fast vector updates.
    centre_db
        ``(n_rx,)`` float64 centres ``c_r``, dB.
    valid
        ``(n_pos, n_rx)`` bool, ``M_r(p)`` finite.
    gmax_db
        ``(n_rx,)`` float64, ``max |G'_r|`` over the table.
    """
    n_pos, n_o, n_rx = space.n_positions, space.n_orientations, space.n_receivers
    m = space.channel_db  # (n_rx, n_pos)
    valid = np.isfinite(m).T  # (n_pos, n_rx)
    with np.errstate(invalid="ignore"):
        base = m + space.tx_power_dbm
    centre = np.array(
        [float(np.mean(base[r][valid[:, r]])) if valid[:, r].any() else 0.0 for r in range(n_rx)]
    )
    table = np.zeros((n_pos * n_o, n_rx + 1), dtype=np.float32, order="F")
    chunk = max(1, chunk_terms // max(n_o * n_rx, 1))
    az = space.orientations_deg[:, 0]
    for start in range(0, n_pos, chunk):
        stop = min(start + chunk, n_pos)
        if space.azimuth_only:
            # Rotation about z only: body-frame azimuth = world azimuth − device azimuth.
            d = space.receiver_positions_m[None, :, :] - space.positions_m[start:stop, None, :]
            phi0, theta = direction_to_pattern_angles_deg(d)  # (c, n_rx)
            dir_dbi = space.pattern.lookup_dbi(
                phi0[:, None, :] - az[None, :, None], theta[:, None, :]
            )  # (c, n_o, n_rx)
        else:
            pos = np.repeat(np.arange(start, stop), n_o)
            ori = np.tile(np.arange(n_o), stop - start)
            dir_dbi = directivity_dbi(space, pos, ori).reshape(stop - start, n_o, n_rx)
        g = base.T[start:stop, None, :] - centre[None, None, :] + dir_dbi
        g = np.where(valid[start:stop, None, :], g, 0.0).astype(np.float32)
        rows = slice(start * n_o, stop * n_o)
        for r in range(n_rx):
            col = g[:, :, r].reshape(-1)
            table[rows, r] = col
            table[rows, n_rx] += col * col
    bad = ~np.all(valid, axis=1)
    if bad.any():
        table[:, n_rx].reshape(n_pos, n_o)[bad] = np.inf
    gmax = np.abs(table[:, :n_rx]).max(axis=0).astype(np.float64)
    return table, centre, valid, gmax


class TableScorer(ScorerBase):
    """Vectorised numpy scorer (see module docstring).

    Parameters
    ----------
    space
        The device's candidate space at the site.
    cache_masks
        How many receiver subsets' ``S2`` vectors to keep (least recently used dropped).
    """

    name = "numpy"

    def __init__(self, space: CandidateSpace, cache_masks: int = 2) -> None:
        self.space = space
        self.table, self.centre_db, self.valid, self.gmax_db = build_table(space)
        self._s2: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_masks = max(1, cache_masks)

    def _sum_squares(self, heard: HeardRss) -> np.ndarray:
        """``S2_H`` for a subset ``H`` of receivers (not the full set), cached."""
        key = heard.mask
        if key in self._s2:
            self._s2.move_to_end(key)
            return self._s2[key]
        s2 = np.zeros(self.table.shape[0], dtype=np.float32)
        for r in heard.receiver_index:
            col = self.table[:, r]
            s2 += col * col
        bad = ~np.all(self.valid[:, heard.receiver_index], axis=1)  # (n_pos,)
        if bad.any():
            s2.reshape(self.space.n_positions, -1)[bad] = np.inf
        self._s2[key] = s2
        while len(self._s2) > self._cache_masks:
            self._s2.popitem(last=False)
        return s2

    def score_heard(self, heard: HeardRss, k: int) -> TopK:
        """Top-k candidates for one packet given as site receiver indices."""
        s = self.space
        n_rx, n_o = s.n_receivers, s.n_orientations
        r = heard.receiver_index
        w64 = heard.rss_dbm - self.centre_db[r]
        # h·MSE ≈ S2_H − 2 G'·w + Σ w²  (float32 screen, one matrix-vector product)
        w = np.zeros(n_rx + 1, dtype=np.float32)
        w[r] = -2.0 * w64
        if heard.n_heard == n_rx:
            w[n_rx] = 1.0  # S2 of the full set is the table's last column
            v = self.table @ w
        else:  # S2 of a subset (the last column may hold inf: leave it out of the product)
            v = self.table[:, :n_rx] @ w[:n_rx]
            v += self._sum_squares(heard)
        v += np.float32(np.sum(w64 * w64))
        g = self.gmax_db[r]
        delta = (
            4.0
            * (heard.n_heard + 4)
            * _EPS32
            * float(np.sum(g * g) + 2.0 * np.sum(np.abs(w64) * g) + np.sum(w64 * w64))
        )
        pos_min = v.reshape(s.n_positions, n_o).min(axis=1)
        if pos_min.size >= k:
            tau = float(np.partition(pos_min, k - 1)[k - 1])
        else:
            tau = np.inf
        if np.isfinite(tau):
            shortlist = np.flatnonzero(v <= tau + 2.0 * delta)
        else:  # fewer than k scorable positions: rescore every scorable candidate
            shortlist = np.flatnonzero(np.isfinite(v))
        mse = exact_mse_db2(s, heard, shortlist)
        return select_topk(shortlist, mse, k)
