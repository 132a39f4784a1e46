"""Scoring estimates against ground truth (interchange contract, "Scoring").

For each estimate, the truth row of the same transmitter and packet time
(within ``tolerance_s``, default 1 µs):

* position error — Euclidean distance, metres;
* orientation error — the angle of ``R_estᵀ R_true`` in degrees (the wrapped
  azimuth difference for azimuth-only poses), :func:`radiopose.geometry.orientation_error_deg`;
* coverage — estimates ÷ packets (truth rows).

Each is reported as mean, median and 95th percentile, with coverage beside
them, per method. Position-only methods
(:func:`position_only`) get no orientation error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from radiopose.errors import InputError
from radiopose.estimates import POSITION_ONLY_METHODS, Estimates
from radiopose.geometry import orientation_error_deg
from radiopose.packets import Truth
from radiopose.units import FloatArray, seconds_to_ns


def position_only(method: str) -> bool:
    """Whether ``method`` estimates position only (its orientation columns are
    0 and get no orientation error): ``lms``
    (:data:`radiopose.estimates.POSITION_ONLY_METHODS`) and any registered
    method that says so (a plugin's ``estimates_orientation = False``)."""
    if method in POSITION_ONLY_METHODS:
        return True
    from radiopose.tracker import METHODS  # the registry (heavy: only for other names)

    return method in METHODS and not METHODS[method].estimates_orientation


@dataclass(frozen=True)
class ErrorStats:
    """Summary of errors: mean, median, 95th percentile (``None`` when there are none)."""

    n: int
    mean: float | None
    median: float | None
    p95: float | None


def error_stats(errors: FloatArray) -> ErrorStats:
    """Mean, median and 95th percentile (linear interpolation) of ``(n,)`` errors."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        return ErrorStats(0, None, None, None)
    return ErrorStats(
        int(e.size), float(e.mean()), float(np.median(e)), float(np.percentile(e, 95))
    )


@dataclass(frozen=True)
class MethodScore:
    """Scores of one method's estimates.

    Attributes
    ----------
    method
        Method name (from the ``method`` column).
    n_packets
        Packets (truth rows).
    n_estimates
        Estimates of this method.
    coverage
        ``n_estimates / n_packets``.
    position_m
        Position error statistics, metres.
    orientation_deg
        Orientation error statistics, degrees (``None`` for position-only methods).
    """

    method: str
    n_packets: int
    n_estimates: int
    coverage: float
    position_m: ErrorStats
    orientation_deg: ErrorStats | None

    def to_dict(self) -> dict:
        return asdict(self)


def unambiguous_tolerance_s(truth: Truth) -> float:
    """The widest time tolerance (s) that still gives each estimate one truth row:
    just under half the smallest gap between two truth times of one transmitter
    (an estimate that close to a row is closer to it than to any other row),
    at least 1 µs (two rows at one time: the files' own precision) and at most
    1 s; 1 µs where no transmitter has two rows (no spacing to go by). Packets
    that went through pcap and ``sync`` carry their receivers' clock estimate
    (within 0.1 ms); at the simulator's default 5 ms spacing this is 2.5 ms."""
    t_ns = seconds_to_ns(truth.timestamp_s)
    tx = np.array([str(s).lower() for s in truth.transmitter], dtype=object)
    _, which = np.unique(tx, return_inverse=True)
    order = np.lexsort((t_ns, which))  # by transmitter, then time
    gaps = np.diff(t_ns[order])[np.diff(which[order]) == 0]
    if not gaps.size:
        return 1e-6
    return float(min(max((int(gaps.min()) - 1) // 2 * 1e-9, 1e-6), 1.0))


def match_truth(truth: Truth, estimates: Estimates, tolerance_s: float = 1e-6) -> NDArray:
    """Index ``(n_est,)`` of the truth row of each estimate (same transmitter, same time).

    Raises
    ------
    InputError
        An estimate without a truth row.
    """
    out = np.empty(len(estimates), dtype=np.int64)
    tol_ns = round(tolerance_s * 1e9)
    t_ns = seconds_to_ns(truth.timestamp_s)
    tx = np.array([str(s).lower() for s in truth.transmitter], dtype=object)
    by_tx: dict[str, tuple[NDArray, NDArray]] = {}
    for key in set(tx.tolist()):
        rows = np.flatnonzero(tx == key)
        order = np.argsort(t_ns[rows], kind="stable")
        by_tx[key] = (t_ns[rows][order], rows[order])
    e_ns = seconds_to_ns(estimates.timestamp_s)
    for i in range(len(estimates)):
        key = str(estimates.transmitter[i]).lower()
        if key not in by_tx:
            raise InputError(
                f"estimate {i + 1} (packet {estimates.packet_id[i]!r}): transmitter "
                f"{estimates.transmitter[i]!r} has no truth rows",
                column="transmitter",
                **estimates.where(i),
            )
        times, rows = by_tx[key]
        j = int(np.searchsorted(times, e_ns[i]))
        best = None
        for c in (j - 1, j):
            if not 0 <= c < times.size:
                continue
            gap = abs(int(times[c]) - int(e_ns[i]))
            if gap <= tol_ns and (best is None or gap < abs(int(times[best]) - int(e_ns[i]))):
                best = c
        if best is None:
            raise InputError(
                f"estimate {i + 1} (packet {estimates.packet_id[i]!r}, "
                f"{estimates.timestamp_s[i]:.9g} s): no truth row of {estimates.transmitter[i]} "
                f"within {tolerance_s * 1e3:g} ms (score --tolerance-ms sets the window)",
                column="timestamp_s",
                **estimates.where(i),
            )
        out[i] = rows[best]
    return out


def score(
    truth: Truth, estimates: Estimates, tolerance_s: float | None = 1e-6
) -> tuple[MethodScore, ...]:
    """Score estimates against truth, one :class:`MethodScore` per method (file order).

    ``tolerance_s``: how far an estimate's time may be from its truth row's;
    ``None``: :func:`unambiguous_tolerance_s` of the truth (``radiopose score``'s
    default).

    With no estimates at all, one row with method ``"none"`` and coverage 0.

    Raises
    ------
    InputError
        A tolerance that is not a finite number >= 0; a truth row or an
        estimate whose time or pose is not finite; an estimate without a truth
        row (:func:`match_truth`); two estimates of one method matched to one
        truth row (a packet estimated twice would count twice in coverage).
    """
    if tolerance_s is None:
        tolerance_s = unambiguous_tolerance_s(truth)
    if not (isinstance(tolerance_s, int | float) and np.isfinite(tolerance_s) and tolerance_s >= 0):
        raise InputError(f"tolerance_s = {tolerance_s!r} must be a finite number >= 0")
    for what, table in (("truth row", truth), ("estimate", estimates)):
        finite = (
            np.isfinite(table.timestamp_s)
            & np.isfinite(table.position_m).all(axis=1)
            & np.isfinite(table.orientation_deg).all(axis=1)
        )
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            message = f"{what} {i + 1}: time, position or orientation is not a finite number"
            if table is estimates:
                raise InputError(message, **estimates.where(i))
            raise InputError(message)
    n_packets = len(truth)
    idx = match_truth(truth, estimates, tolerance_s)
    methods = list(dict.fromkeys(str(m) for m in estimates.method)) or ["none"]
    out = []
    for m in methods:
        sel = np.array([str(x) == m for x in estimates.method], dtype=bool)
        rows = idx[sel]
        seen, counts = np.unique(rows, return_counts=True)
        if (counts > 1).any():
            r = int(seen[counts > 1][0])
            i, j = np.flatnonzero(sel)[np.flatnonzero(rows == r)[:2]]
            raise InputError(
                f"estimates {i + 1} and {j + 1} of method {m!r} are both of truth row {r + 1} "
                f"({truth.transmitter[r]} at {truth.timestamp_s[r]:.9g} s): a packet estimated "
                "twice would count twice",
                **estimates.where(int(j)),
            )
        pos_err = np.linalg.norm(estimates.position_m[sel] - truth.position_m[rows], axis=1)
        ori = None
        if not position_only(m):
            ori = error_stats(
                orientation_error_deg(estimates.orientation_deg[sel], truth.orientation_deg[rows])
                if rows.size
                else np.empty(0)
            )
        n_est = int(sel.sum())
        out.append(
            MethodScore(
                m,
                n_packets,
                n_est,
                n_est / n_packets if n_packets else 0.0,
                error_stats(pos_err),
                ori,
            )
        )
    return tuple(out)
