"""Synchronised packets (``packets.csv``) and ground truth (``truth.csv``) tables.

``packets.csv``: one row per packet per receiver that heard it —
``packet_id, timestamp_s, transmitter, receiver_id, rss_dbm``. ``packet_id`` is
kept as text exactly as written. :func:`group_packets` turns the rows into one
:class:`PacketObservation` per packet (the unit the tracker consumes).

``truth.csv``: ``timestamp_s, transmitter, x_m, y_m, z_m, azimuth_deg,
pitch_deg, roll_deg`` — the true pose when each packet was sent.
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass

import numpy as np

from radiopose.errors import InputError
from radiopose.ids import (
    check_receiver_ids,
    check_transmitter_ids,
    receiver_id_problem,
    transmitter_id_problem,
)
from radiopose.tables import Column, Table, read_table, reject_repeated_rows, write_table
from radiopose.units import COORD_LIMIT_M, MAX_ABS_TIME_S, FloatArray

RSS_MIN_DBM, RSS_MAX_DBM = -200.0, 50.0
"""The range of an RSS reading, dBm (``packets.csv``; :func:`check_observation`)."""
PACKET_COLUMNS = (
    Column("packet_id", "str"),
    Column("timestamp_s", low=-MAX_ABS_TIME_S, high=MAX_ABS_TIME_S),
    Column("transmitter", "str"),
    Column("receiver_id", "str"),
    Column("rss_dbm", low=RSS_MIN_DBM, high=RSS_MAX_DBM),
)
POSE_COLUMNS = (
    Column("x_m", low=-COORD_LIMIT_M, high=COORD_LIMIT_M),
    Column("y_m", low=-COORD_LIMIT_M, high=COORD_LIMIT_M),
    Column("z_m", low=-COORD_LIMIT_M, high=COORD_LIMIT_M),
    Column("azimuth_deg", low=-360.0, high=360.0),
    Column("pitch_deg", low=-90.0, high=90.0),
    Column("roll_deg", low=-360.0, high=360.0),
)
"""The pose columns shared by ``truth.csv`` and ``estimates.csv``: metres, degrees."""
TRUTH_COLUMNS = (
    Column("timestamp_s", low=-MAX_ABS_TIME_S, high=MAX_ABS_TIME_S),
    Column("transmitter", "str"),
    *POSE_COLUMNS,
)


@dataclass(frozen=True, eq=False)
class Packets:
    """Rows of ``packets.csv`` as arrays (all ``(n,)``); ``lines`` = file lines if read."""

    packet_id: np.ndarray
    timestamp_s: FloatArray
    transmitter: np.ndarray
    receiver_id: np.ndarray
    rss_dbm: FloatArray
    lines: np.ndarray | None = None
    path: str | None = None

    def __len__(self) -> int:
        return int(self.timestamp_s.shape[0])


@dataclass(frozen=True, eq=False)
class PacketObservation:
    """One packet: when, from whom, and the RSS each receiver measured.

    Attributes
    ----------
    packet_id
        Identifier from ``packets.csv``.
    timestamp_s
        Packet time, seconds (the first row's time if rows differ).
    transmitter
        Transmitter address.
    receiver_ids
        ``(k,)`` receivers that heard it.
    rss_dbm
        ``(k,)`` their RSS, dBm.
    line
        First file line of the packet, for messages (``None`` if not from a file).
    row_lines
        ``(k,)`` file line of each receiver's row (empty if not from a file).
    """

    packet_id: str
    timestamp_s: float
    transmitter: str
    receiver_ids: tuple[str, ...]
    rss_dbm: FloatArray
    line: int | None = None
    row_lines: tuple[int, ...] = ()

    def line_of(self, k: int) -> int | None:
        """File line of the packet's ``k``-th row (the first line if unknown)."""
        return self.row_lines[k] if k < len(self.row_lines) else self.line


@dataclass(frozen=True, eq=False)
class Truth:
    """Rows of ``truth.csv``: ``timestamp_s (n,)``, ``transmitter (n,)``,
    ``position_m (n, 3)``, ``orientation_deg (n, 3)``."""

    timestamp_s: FloatArray
    transmitter: np.ndarray
    position_m: FloatArray
    orientation_deg: FloatArray

    def __len__(self) -> int:
        return int(self.timestamp_s.shape[0])


def read_pose_columns(t: Table) -> tuple[FloatArray, FloatArray]:
    """``(position_m (n, 3), orientation_deg (n, 3))`` from a table's :data:`POSE_COLUMNS`."""
    return (
        np.column_stack([t["x_m"], t["y_m"], t["z_m"]]).reshape(-1, 3),
        np.column_stack([t["azimuth_deg"], t["pitch_deg"], t["roll_deg"]]).reshape(-1, 3),
    )


def pose_columns(position_m: FloatArray, orientation_deg: FloatArray) -> dict[str, FloatArray]:
    """The :data:`POSE_COLUMNS` of ``(n, 3)`` positions (m) and orientations (deg), to write."""
    return {
        "x_m": position_m[:, 0],
        "y_m": position_m[:, 1],
        "z_m": position_m[:, 2],
        "azimuth_deg": orientation_deg[:, 0],
        "pitch_deg": orientation_deg[:, 1],
        "roll_deg": orientation_deg[:, 2],
    }


def read_packets_csv(path: str | os.PathLike[str]) -> Packets:
    """Read and validate ``packets.csv``."""
    t = read_table(path, PACKET_COLUMNS)
    check_transmitter_ids(t)
    check_receiver_ids(t)
    return Packets(
        t["packet_id"],
        t["timestamp_s"],
        t["transmitter"],
        t["receiver_id"],
        t["rss_dbm"],
        t.lines,
        t.path,
    )


def write_packets_csv(packets: Packets, path: str | os.PathLike[str]) -> None:
    """Write ``packets.csv`` atomically (timestamps to 1 ns, RSS to 0.001 dB)."""
    write_table(
        path,
        {
            "packet_id": packets.packet_id,
            "timestamp_s": packets.timestamp_s,
            "transmitter": packets.transmitter,
            "receiver_id": packets.receiver_id,
            "rss_dbm": packets.rss_dbm,
        },
        decimals={"timestamp_s": 9, "rss_dbm": 3},
    )


def read_truth_csv(path: str | os.PathLike[str]) -> Truth:
    """Read and validate ``truth.csv``."""
    t = read_table(path, TRUTH_COLUMNS)
    reject_repeated_rows(
        t, ("transmitter", "timestamp_s"), "a second truth row for transmitter {} at {} s"
    )
    return Truth(t["timestamp_s"], t["transmitter"], *read_pose_columns(t))


def write_truth_csv(truth: Truth, path: str | os.PathLike[str]) -> None:
    """Write ``truth.csv`` atomically."""
    write_table(
        path,
        {
            "timestamp_s": truth.timestamp_s,
            "transmitter": truth.transmitter,
            **pose_columns(truth.position_m, truth.orientation_deg),
        },
        decimals={"timestamp_s": 9},
    )


def group_packets(packets: Packets) -> list[PacketObservation]:
    """Group rows into one observation per ``(transmitter, packet_id)``, in file order
    of each packet's first row. Rows of one packet need not be adjacent.

    Raises
    ------
    InputError
        Columns of different lengths (:func:`check_packet_arrays`), or rows of one
        packet with different ``timestamp_s`` (a packet is sent once: the contract's
        "one row per packet per receiver"; ``sync`` gives all of a packet's rows
        its one time).
    """
    check_packet_arrays(packets)
    order: dict[tuple[str, str], list[int]] = {}
    for i, (tx, pid) in enumerate(zip(packets.transmitter, packets.packet_id, strict=True)):
        order.setdefault((str(tx), str(pid)), []).append(i)
    out = []
    t_s = packets.timestamp_s
    for (tx, pid), rows in order.items():
        idx = np.asarray(rows)
        other = np.flatnonzero(t_s[idx] != t_s[idx[0]])
        if other.size:
            j = int(idx[other[0]])
            first = "" if packets.lines is None else f" (line {int(packets.lines[idx[0]])})"
            raise InputError(
                f"rows of packet {pid} of {tx} disagree on timestamp_s: "
                f"{_show(t_s[j])} here, {_show(t_s[idx[0]])} in its first row{first}; "
                "a packet is sent once, at one time (a packet_id reused?)",
                path=packets.path,
                line=None if packets.lines is None else int(packets.lines[j]),
                column="timestamp_s",
            )
        out.append(
            PacketObservation(
                pid,
                float(packets.timestamp_s[idx[0]]),
                tx,
                tuple(str(r) for r in packets.receiver_id[idx]),
                packets.rss_dbm[idx].astype(float),
                None if packets.lines is None else int(packets.lines[idx[0]]),
                () if packets.lines is None else tuple(int(v) for v in packets.lines[idx]),
            )
        )
    return out


def _show(value: object) -> str:
    """A value for a message: a number to 9 significant digits, anything else as written."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return f"{float(value):.9g}"
    return repr(value)


_PACKET_ARRAYS = ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm")


def check_packet_arrays(packets: Packets) -> None:
    """Check that a :class:`Packets` built in Python has one value per row in
    each column (``read_packets_csv`` builds only such tables).

    Raises
    ------
    InputError
        A column that is not one-dimensional, or columns of different lengths
        (``lines`` too, when set).
    """
    sizes = {}
    for name in _PACKET_ARRAYS:
        a = np.asarray(getattr(packets, name))
        if a.ndim != 1:
            raise InputError(
                f"packets column {name} has shape {a.shape}: expected one value per row",
                path=packets.path,
            )
        sizes[name] = a.shape[0]
    if packets.lines is not None:
        sizes["lines"] = np.asarray(packets.lines).shape[0]
    if len(set(sizes.values())) > 1:
        raise InputError(
            "packets columns differ in length: " + ", ".join(f"{k} {v}" for k, v in sizes.items()),
            path=packets.path,
        )
    # every row's time (a packet takes its first row's): a bad one in a later row too
    try:
        t = np.asarray(packets.timestamp_s, dtype=np.float64)
    except (TypeError, ValueError):
        t = np.full(len(packets), np.nan)
    bad = np.flatnonzero(~(np.abs(t) <= MAX_ABS_TIME_S))
    if bad.size:
        row = int(bad[0])
        raise InputError(
            f"row {row} (from 0): timestamp {_show(packets.timestamp_s[row])} s is not a "
            f"finite number within ±{MAX_ABS_TIME_S:g} s",
            path=packets.path,
            line=None if packets.lines is None else int(packets.lines[row]),
            column="timestamp_s",
        )


def check_observation(
    packet: PacketObservation, path: str | os.PathLike[str] | None = None
) -> None:
    """The checks ``packets.csv`` applies to each row, for one packet however it
    was built (a file, the live server, or Python): text ids (the transmitter
    a contract id), a finite timestamp within ±:data:`~radiopose.units.MAX_ABS_TIME_S`
    seconds, and one finite RSS within [:data:`RSS_MIN_DBM`, :data:`RSS_MAX_DBM`]
    dBm per receiver.

    Raises
    ------
    InputError
        One line naming the packet (and ``path``, line and column when known).
    """
    what = f"packet {packet.packet_id!r} of {packet.transmitter!r}"
    if not isinstance(packet.packet_id, str) or not isinstance(packet.transmitter, str):
        raise InputError(f"{what}: packet_id and transmitter must be text", path=path)
    problem = transmitter_id_problem(packet.transmitter)
    if problem is not None:
        raise InputError(f"{what}: {problem}", path=path, line=packet.line, column="transmitter")
    t = packet.timestamp_s
    if not (
        isinstance(t, numbers.Real) and not isinstance(t, bool)
        and math.isfinite(t) and abs(t) <= MAX_ABS_TIME_S
    ):  # fmt: skip
        raise InputError(
            f"{what}: timestamp {_show(t)} s is not a finite number within ±{MAX_ABS_TIME_S:g} s",
            path=path,
            line=packet.line,
            column="timestamp_s",
        )
    n = len(packet.receiver_ids)
    if not all(isinstance(r, str) for r in packet.receiver_ids):
        raise InputError(f"{what}: receiver ids must be text", path=path, column="receiver_id")
    for r in packet.receiver_ids:
        if (problem := receiver_id_problem(r)) is not None:
            raise InputError(
                f"{what}: {problem}", path=path, line=packet.line, column="receiver_id"
            )
    try:
        rss = np.asarray(packet.rss_dbm, dtype=np.float64)
    except (TypeError, ValueError):
        rss = np.full(1, np.nan)
    if rss.shape != (n,):
        raise InputError(
            f"{what}: {n} receivers but RSS of shape {np.shape(packet.rss_dbm)}",
            path=path,
            line=packet.line,
            column="rss_dbm",
        )
    bad = np.flatnonzero(~((rss >= RSS_MIN_DBM) & (rss <= RSS_MAX_DBM)))  # NaN too
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{what}: RSS {_show(packet.rss_dbm[k])} dBm from receiver {packet.receiver_ids[k]!r} "
            f"is not a finite number in [{RSS_MIN_DBM:g}, {RSS_MAX_DBM:g}] dBm",
            path=path,
            line=packet.line_of(k),
            column="rss_dbm",
        )
