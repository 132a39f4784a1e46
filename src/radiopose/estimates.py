"""Pose estimates (``estimates.csv``): one row per packet with a valid estimate.

Contract columns: ``timestamp_s, transmitter, packet_id, x_m, y_m, z_m,
azimuth_deg, pitch_deg, roll_deg, method``. Packets without a valid estimate
have no row. Position-only methods (:data:`POSITION_ONLY_METHODS`, i.e. the
``lms`` baseline) write orientation 0, 0, 0; scoring leaves their orientation
error out rather than scoring a guess.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from radiopose.packets import POSE_COLUMNS, pose_columns, read_pose_columns
from radiopose.tables import Column, read_table, reject_repeated_rows, write_table
from radiopose.units import MAX_ABS_TIME_S, FloatArray

POSITION_ONLY_METHODS = frozenset({"lms"})
"""Methods that estimate position only (their orientation columns are 0)."""

ESTIMATE_COLUMNS = (
    Column("timestamp_s", low=-MAX_ABS_TIME_S, high=MAX_ABS_TIME_S),
    Column("transmitter", "str"),
    Column("packet_id", "str"),
    *POSE_COLUMNS,
    Column("method", "str"),
)


class _Where(TypedDict):
    """``path``/``line`` keywords of :class:`~radiopose.errors.InputError`."""

    path: str | None
    line: int | None


@dataclass(frozen=True)
class PoseEstimate:
    """One packet's estimate.

    Attributes
    ----------
    timestamp_s, transmitter, packet_id
        The packet.
    position_m
        ``(3,)`` metres.
    orientation_deg
        ``(3,)`` (azimuth, pitch, roll), degrees.
    method
        The method that produced it.
    position_std_m, azimuth_std_deg
        The estimate's position standard deviation (metres) and circular
        standard deviation of azimuth (degrees); NaN where the method gives none.
    """

    timestamp_s: float
    transmitter: str
    packet_id: str
    position_m: tuple[float, float, float]
    orientation_deg: tuple[float, float, float]
    method: str
    position_std_m: float = math.nan
    azimuth_std_deg: float = math.nan


@dataclass(frozen=True, eq=False)
class Estimates:
    """Rows of ``estimates.csv`` as arrays: ``(n,)`` each, ``position_m`` and
    ``orientation_deg`` ``(n, 3)``."""

    timestamp_s: FloatArray
    transmitter: np.ndarray
    packet_id: np.ndarray
    position_m: FloatArray
    orientation_deg: FloatArray
    method: np.ndarray
    lines: np.ndarray | None = None  # file line of each row, if read from a file
    path: str | None = None  # the file, if read from one
    position_std_m: FloatArray | None = None  # optional trailing column, metres
    azimuth_std_deg: FloatArray | None = None  # optional trailing column, degrees

    def __len__(self) -> int:
        return int(self.timestamp_s.shape[0])

    def where(self, row: int) -> _Where:
        """``path``/``line`` keywords of :class:`InputError` for row ``row`` (0-based)."""
        return {
            "path": self.path,
            "line": None if self.lines is None else int(self.lines[row]),
        }

    @classmethod
    def from_poses(cls, poses: Sequence[PoseEstimate]) -> Estimates:
        """Stack a sequence of estimates (uncertainty columns only if every
        estimate has them)."""
        pos_sd = np.array([p.position_std_m for p in poses], dtype=np.float64)
        az_sd = np.array([p.azimuth_std_deg for p in poses], dtype=np.float64)
        with_sd = pos_sd.size > 0 and bool(np.all(np.isfinite(pos_sd) & np.isfinite(az_sd)))
        return cls(
            np.array([p.timestamp_s for p in poses], dtype=np.float64),
            np.array([p.transmitter for p in poses], dtype=object),
            np.array([p.packet_id for p in poses], dtype=object),
            np.array([p.position_m for p in poses], dtype=np.float64).reshape(-1, 3),
            np.array([p.orientation_deg for p in poses], dtype=np.float64).reshape(-1, 3),
            np.array([p.method for p in poses], dtype=object),
            position_std_m=pos_sd if with_sd else None,
            azimuth_std_deg=az_sd if with_sd else None,
        )

    def select(self, mask: np.ndarray) -> Estimates:
        """The rows where ``mask`` is true."""
        return Estimates(
            self.timestamp_s[mask],
            self.transmitter[mask],
            self.packet_id[mask],
            self.position_m[mask],
            self.orientation_deg[mask],
            self.method[mask],
            None if self.lines is None else self.lines[mask],
            self.path,
            None if self.position_std_m is None else self.position_std_m[mask],
            None if self.azimuth_std_deg is None else self.azimuth_std_deg[mask],
        )


STD_COLUMNS = (
    Column("position_std_m", low=0.0),
    Column("azimuth_std_deg", low=0.0, high=360.0),
)
"""Optional trailing columns: the estimate's uncertainty (both or neither)."""


def read_estimates_csv(path: str | os.PathLike[str]) -> Estimates:
    """Read and validate ``estimates.csv`` (with the optional uncertainty columns
    when the header has both)."""
    t = read_table(path, ESTIMATE_COLUMNS, optional=STD_COLUMNS)
    with_sd = STD_COLUMNS[0].name in t.columns
    reject_repeated_rows(
        t, ("transmitter", "packet_id", "method"), "a second estimate of {} packet {} by {}"
    )
    return Estimates(
        t["timestamp_s"],
        t["transmitter"],
        t["packet_id"],
        *read_pose_columns(t),
        t["method"],
        t.lines,
        t.path,
        t["position_std_m"] if with_sd else None,
        t["azimuth_std_deg"] if with_sd else None,
    )


def write_estimates_csv(
    estimates: Estimates,
    path: str | os.PathLike[str],
    extra_columns: Mapping[str, NDArray] | None = None,
) -> None:
    """Write ``estimates.csv`` atomically (timestamps to 1 ns, positions to 1 µm).

    ``extra_columns`` are further optional trailing columns, each named with its
    unit and one value per row (e.g. the spoofing detector's
    ``spoof_score_nats``, ``spoof_alarm_flag``), written after the uncertainty
    columns; readers ignore trailing columns they do not know.
    """
    write_table(
        path,
        {
            "timestamp_s": estimates.timestamp_s,
            "transmitter": estimates.transmitter,
            "packet_id": estimates.packet_id,
            **pose_columns(estimates.position_m, estimates.orientation_deg),
            "method": estimates.method,
            **(
                {}
                if estimates.position_std_m is None or estimates.azimuth_std_deg is None
                else {
                    "position_std_m": estimates.position_std_m,
                    "azimuth_std_deg": estimates.azimuth_std_deg,
                }
            ),
            **dict(extra_columns or {}),
        },
        decimals={"timestamp_s": 9},
    )
