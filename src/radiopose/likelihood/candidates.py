"""The candidate space of one site and one device, and the exact expected RSS.

Paper, "Enhanced Localisation Pipeline", step 1 (likelihood estimation). A
*candidate* is a grid position ``p`` (``site.area``, ``ij`` order) combined with
a grid orientation ``o`` (``site.orientations``, pitch slowest, azimuth fastest).
Candidates are numbered ``candidate = position_index * n_orientations +
orientation_index``. For receiver ``r`` the expected RSS of a candidate is

    RSS_r(p, o) = M_r(p) + P_tx + D_t(direction from p to r in the frame of o)   (dBm)

with ``M_r`` the survey map (``site.survey_map``), ``P_tx`` and ``D_t`` the
device's transmit power and pattern from ``devices.csv``.

:func:`expected_rss_dbm` evaluates this exactly (float64, element by element)
for any list of candidates; the reference scorer and the final, exact pass of
the fast scorers both call it, so their values agree bit for bit.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from radiopose.errors import InputError
from radiopose.geometry import direction_to_pattern_angles_deg, stored_orientation_matrices
from radiopose.likelihood.exact import expected_rss_all_dbm, mse_db2
from radiopose.packets import PacketObservation
from radiopose.patterns.pattern import Pattern
from radiopose.site import Site
from radiopose.units import FloatArray

IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class HeardRss:
    """The receivers that heard one packet, as site receiver indices.

    Attributes
    ----------
    receiver_index
        ``(h,)`` indices into the site's receiver order, increasing, unique.
    rss_dbm
        ``(h,)`` measured RSS, dBm.
    """

    receiver_index: IntArray
    rss_dbm: FloatArray

    @property
    def n_heard(self) -> int:
        return int(self.receiver_index.size)

    @property
    def mask(self) -> int:
        """Bit mask of the heard receivers (bit ``r`` set if receiver ``r`` heard it)."""
        return int(sum(1 << int(r) for r in self.receiver_index))


@dataclass(frozen=True, eq=False)
class CandidateSpace:
    """Everything packet-independent needed to score one device's packets at one site.

    Attributes
    ----------
    transmitter
        The device's transmitter address.
    positions_m
        ``(n_pos, 3)`` candidate positions, metres, ``ij`` grid order.
    orientations_deg
        ``(n_orient, 3)`` candidate (azimuth, pitch, roll), degrees.
    rotations
        ``(n_orient, 3, 3)`` body-to-world matrices of the orientations.
    receiver_ids
        Receiver order of every receiver axis.
    receiver_positions_m
        ``(n_rx, 3)`` receiver positions, metres.
    channel_db
        ``(n_rx, n_pos)`` survey map ``M_r(p)``, dB (NaN: candidate excluded).
    tx_power_dbm
        Device transmit power ``P_tx``, dBm.
    pattern
        Device pattern ``D_t``.
    """

    transmitter: str
    positions_m: FloatArray
    orientations_deg: FloatArray
    rotations: FloatArray
    receiver_ids: tuple[str, ...]
    receiver_positions_m: FloatArray
    channel_db: FloatArray
    tx_power_dbm: float
    pattern: Pattern

    @property
    def n_positions(self) -> int:
        return int(self.positions_m.shape[0])

    @property
    def n_orientations(self) -> int:
        return int(self.orientations_deg.shape[0])

    @property
    def n_receivers(self) -> int:
        return int(self.receiver_positions_m.shape[0])

    @property
    def n_candidates(self) -> int:
        return self.n_positions * self.n_orientations

    @property
    def azimuth_only(self) -> bool:
        """True if every candidate orientation has pitch = roll = 0."""
        return bool(np.all(self.orientations_deg[:, 1:] == 0.0))

    def split(self, candidate_idx: IntArray) -> tuple[IntArray, IntArray]:
        """Candidate indices → (position index, orientation index)."""
        c = np.asarray(candidate_idx, dtype=np.int64)
        return c // self.n_orientations, c % self.n_orientations

    def candidate_positions_m(self, candidate_idx: IntArray) -> FloatArray:
        """``(n, 3)`` positions of candidates, metres."""
        return self.positions_m[self.split(candidate_idx)[0]]

    def candidate_orientations_deg(self, candidate_idx: IntArray) -> FloatArray:
        """``(n, 3)`` (azimuth, pitch, roll) of candidates, degrees."""
        return self.orientations_deg[self.split(candidate_idx)[1]]

    def heard(self, packet: PacketObservation) -> HeardRss:
        """Map a packet's receivers to site indices (sorted).

        Raises
        ------
        InputError
            A receiver not in the site, or one receiver twice in the packet.
        """
        idx = receiver_indices(packet, self.receiver_ids)
        ridx = np.asarray(idx, dtype=np.int64)
        order = np.argsort(ridx)
        return HeardRss(ridx[order], np.asarray(packet.rss_dbm, dtype=np.float64)[order])


def receiver_indices(
    packet: PacketObservation,
    receiver_ids: Sequence[str],
    path: str | os.PathLike[str] | None = None,
) -> list[int]:
    """Site indices of a packet's receivers, in the packet's row order: the one receiver check.

    Used per packet by :meth:`CandidateSpace.heard` (streaming) and for a whole
    ``packets.csv`` by the batch tracker (which passes the file's ``path``).

    Raises
    ------
    InputError
        A receiver not in ``receiver_ids``, or two rows of the packet for one
        receiver (file line and column ``receiver_id``).
    """
    index = {rid: i for i, rid in enumerate(receiver_ids)}
    seen: dict[int, int] = {}
    for k, rid in enumerate(packet.receiver_ids):
        i = index.get(rid)
        if i is None:
            raise InputError(
                f"packet {packet.packet_id!r}: receiver {rid!r} is not in the site "
                f"(site receivers: {', '.join(receiver_ids)})",
                path=path,
                line=packet.line_of(k),
                column="receiver_id",
            )
        if i in seen:
            first = packet.line_of(seen[i])
            raise InputError(
                f"packet {packet.packet_id!r} of {packet.transmitter} has two rows for "
                f"receiver {rid!r}" + ("" if first is None else f" (the first on line {first})"),
                path=path,
                line=packet.line_of(k),
                column="receiver_id",
            )
        seen[i] = k
    return list(seen)


def candidate_space(site: Site, transmitter: str) -> CandidateSpace:
    """Build the candidate space of ``transmitter`` (enrolled in ``devices.csv``) at ``site``.

    Raises
    ------
    InputError
        The transmitter is not enrolled.
    """
    device = site.device(transmitter)
    orient = site.orientations.orientations_deg()
    n_rx = len(site.receivers)
    channel = np.asarray(site.survey_map.m_db, dtype=np.float64).reshape(n_rx, -1)
    return CandidateSpace(
        transmitter=device.transmitter,
        positions_m=site.area.points_m(),
        orientations_deg=orient,
        rotations=stored_orientation_matrices(orient),
        receiver_ids=site.receiver_ids,
        receiver_positions_m=site.receiver_positions_m(),
        channel_db=channel,
        tx_power_dbm=float(device.tx_power_dbm),
        pattern=site.patterns[device.pattern],
    )


def directivity_dbi(space: CandidateSpace, pos_idx: IntArray, orient_idx: IntArray) -> FloatArray:
    """Device directivity toward every receiver, ``(n, n_rx)`` dBi, for ``n`` candidates.

    Vectorised numpy: ``v = Rᵀ (r − p)`` written out as three products and two
    sums, then :func:`~radiopose.geometry.direction_to_pattern_angles_deg` and
    :meth:`~radiopose.patterns.pattern.Pattern.lookup_dbi` (bilinear). Used to
    fill the numpy scorer's float32 table and to cross-check the compiled exact
    function (:func:`expected_rss_dbm`), which it matches to ~1e-12 dB.
    """
    p = space.positions_m[np.asarray(pos_idx, dtype=np.int64)]  # (n, 3)
    rot = space.rotations[np.asarray(orient_idx, dtype=np.int64)]  # (n, 3, 3)
    d = space.receiver_positions_m[None, :, :] - p[:, None, :]  # (n, n_rx, 3) world
    # v_j = sum_i d_i R_ij  (body frame: v = Rᵀ d), each term explicit.
    v = (
        d[:, :, 0:1] * rot[:, None, 0, :]
        + d[:, :, 1:2] * rot[:, None, 1, :]
        + d[:, :, 2:3] * rot[:, None, 2, :]
    )
    phi, theta = direction_to_pattern_angles_deg(v)
    return space.pattern.lookup_dbi(phi, theta)


def expected_rss_dbm(space: CandidateSpace, pos_idx: IntArray, orient_idx: IntArray) -> FloatArray:
    """Expected RSS ``(n, n_rx)`` in dBm: ``M_r(p) + P_tx + D_t`` (NaN where ``M_r`` is).

    Computed element by element by the compiled :mod:`radiopose.likelihood.exact`
    (the same values the reference and every fast scorer's rescoring use).
    """
    pos = np.asarray(pos_idx, dtype=np.int64)
    ori = np.asarray(orient_idx, dtype=np.int64)
    if ori.size and (int(ori.min()) < 0 or int(ori.max()) >= space.n_orientations):
        raise IndexError(f"orientation index outside [0, {space.n_orientations})")
    return expected_rss_all_dbm(space, pos * space.n_orientations + ori)


def candidate_mse_db2(expected_dbm: FloatArray, heard: HeardRss) -> FloatArray:
    """Mean squared error ``(n,)`` over the heard receivers, dB².

    ``MSE = (1/h) Σ_{r heard} (RSS_r − expected_r)²``; a receiver that missed
    the packet is left out (never zero-filled). NaN where an expected value is NaN.
    """
    acc = np.zeros(expected_dbm.shape[0])
    for r, rss in zip(heard.receiver_index, heard.rss_dbm, strict=True):
        diff = rss - expected_dbm[:, r]
        acc += diff * diff
    return acc / heard.n_heard


def exact_mse_db2(
    space: CandidateSpace, heard: HeardRss, candidate_idx: IntArray, parallel: bool = True
) -> FloatArray:
    """Exact float64 MSE ``(n,)`` of the given candidates for one packet, dB².

    Equal, bit for bit, to ``candidate_mse_db2(expected_rss_dbm(...), heard)``;
    computed for the heard receivers only, in one compiled pass (on numba's
    threads for many candidates unless ``parallel`` is false; the same values).
    """
    return mse_db2(space, heard.receiver_index, heard.rss_dbm, candidate_idx, parallel)
