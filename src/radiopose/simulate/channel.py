"""The simulated radio channel: log-distance path loss plus both antennas' patterns.

    RSS_r = P_tx + D_t(device → r) + D_r(r → device) − PL(d)
    PL(d) = PL(d0) + 10·n·log10(max(d, d0) / d0)                 (dB)

Defaults: ``PL(d0) = 40.0 dB`` at ``d0 = 1 m`` (free space at 2.4 GHz is
40.05 dB) and ``n = 3.0`` (a typical indoor exponent). Distances below ``d0``
are clamped to ``d0`` (the model is far-field only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from radiopose.geometry import (
    direction_to_pattern_angles_deg,
    orientation_matrices,
    pattern_angles_deg,
)
from radiopose.patterns.pattern import Pattern
from radiopose.units import FloatArray


@dataclass(frozen=True)
class LogDistance:
    """Log-distance path loss: ``PL(d) = pl_d0_db + 10·exponent·log10(d / d0_m)``."""

    pl_d0_db: float = 40.0
    d0_m: float = 1.0
    exponent: float = 3.0

    def validate(self) -> None:
        """Raise :class:`~radiopose.errors.InputError` naming the first setting
        out of range: ``pl_d0_db`` in [-100, 200] dB, ``d0_m`` in (0, 100] m,
        ``exponent`` in (0, 10]."""
        from radiopose.errors import InputError, check_setting_types

        check_setting_types(self, "channel")
        for name, ok, allowed in (
            ("pl_d0_db", -100.0 <= self.pl_d0_db <= 200.0, "[-100, 200] dB"),
            ("d0_m", 0.0 < self.d0_m <= 100.0, "(0, 100] m"),
            ("exponent", 0.0 < self.exponent <= 10.0, "(0, 10]"),
        ):
            if not ok:
                raise InputError(
                    f"channel setting {name} = {getattr(self, name)!r} is out of range "
                    f"(allowed: {allowed})"
                )

    def path_loss_db(self, distance_m: ArrayLike) -> FloatArray:
        """Path loss in dB at distances in metres (clamped below ``d0_m``)."""
        d = np.maximum(np.asarray(distance_m, float), self.d0_m)
        return self.pl_d0_db + 10.0 * self.exponent * np.log10(d / self.d0_m)


def link_rss_dbm(
    channel: LogDistance,
    tx_xyz_m: FloatArray,
    tx_orientation_deg: FloatArray,
    tx_pattern: Pattern,
    tx_power_dbm: float | FloatArray,
    rx_xyz_m: FloatArray,
    rx_orientation_deg: FloatArray,
    rx_patterns: tuple[Pattern, ...],
) -> FloatArray:
    """Noise-free RSS ``(n, k)`` in dBm of ``n`` transmitter poses at ``k`` receivers.

    Parameters
    ----------
    tx_xyz_m, tx_orientation_deg
        ``(n, 3)`` transmitter positions (m) and orientations (az, pitch, roll; deg).
    tx_power_dbm
        Scalar or ``(n,)`` transmit power.
    rx_xyz_m, rx_orientation_deg
        ``(k, 3)`` receiver positions and orientations.
    rx_patterns
        One pattern per receiver.
    """
    txp = np.asarray(tx_xyz_m, float).reshape(-1, 3)
    txo = np.asarray(tx_orientation_deg, float).reshape(-1, 3)
    rxp = np.asarray(rx_xyz_m, float).reshape(-1, 3)
    rxo = np.asarray(rx_orientation_deg, float).reshape(-1, 3)
    n, k = txp.shape[0], rxp.shape[0]
    # Transmitter directivity toward each receiver: each pose its own rotation.
    rot_t = orientation_matrices(*txo.T)
    d = rxp[None, :, :] - txp[:, None, :]  # (n, k, 3)
    v = np.einsum("nki,nij->nkj", d, rot_t)
    phi, theta = direction_to_pattern_angles_deg(v)
    d_t = tx_pattern.lookup_dbi(phi, theta)
    # Receiver directivity toward each transmitter position.
    d_r = np.empty((n, k))
    for j in range(k):
        rot_r = orientation_matrices(*rxo[j])
        ph, th = pattern_angles_deg(rxp[j], rot_r, txp)  # (1, 1, n)
        d_r[:, j] = rx_patterns[j].lookup_dbi(ph.reshape(-1), th.reshape(-1))
    dist = np.linalg.norm(d, axis=-1)
    p = np.broadcast_to(np.asarray(tx_power_dbm, float).reshape(-1, 1), (n, 1))
    return p + d_t + d_r - channel.path_loss_db(dist)
