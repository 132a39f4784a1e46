"""Site survey: raw survey RSS → the per-receiver channel map ``M_r(p)`` on the candidate grid.

Paper, "Site Survey". While the survey transmitter stands at a surveyed point
``p`` with orientation ``o`` and transmits at ``P_tx`` (dBm), receiver ``r``
measures ``R``. Its directivity toward the receiver, ``D_st``, is looked up
from the survey transmitter's pattern at the body-frame direction of the
receiver. What remains,

    M_r(p) = R − P_tx − D_st(o, p → r)          (dB)

is everything between an isotropic radiator at ``p`` and receiver ``r``'s
reported RSS: path loss, the receiver's own pattern and gain, the room.
Repeated samples at one point are averaged in dB. ``M_r`` is then interpolated
from the survey points onto the candidate grid:

* survey points forming a complete regular grid → an interpolating bicubic
  spline (``RectBivariateSpline``, ``s = 0``) for ``"cubic"`` (default), bilinear
  (``RegularGridInterpolator``) for ``"linear"``;
* irregular survey points → Clough–Tocher (C¹, piecewise cubic on a Delaunay
  triangulation) for ``"cubic"``, piecewise linear for ``"linear"``.

Both reproduce the survey values exactly at survey points. Candidate points
outside the surveyed convex hull follow ``outside``: ``"nearest"`` (default,
the value of the nearest surveyed point) or ``"exclude"`` (NaN: the candidate
is never scored). Interpolation is 2-D in ``(x, y)`` at the candidate height;
survey heights are not used for interpolation.

A loaded site (:func:`radiopose.site.load_site`) guarantees each receiver's
survey points span an area (:func:`spans_two_dimensions`) whose hull covers
most of the candidate grid (:func:`hull_coverage`). :func:`interpolate_points`
itself still accepts one point (a constant map) or collinear points (the
``outside`` policy everywhere).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from radiopose.diskcache import memo_arrays
from radiopose.errors import InputError
from radiopose.units import FloatArray

InterpolationMethod = Literal["cubic", "linear"]
OutsidePolicy = Literal["nearest", "exclude"]
METHODS: tuple[str, ...] = ("cubic", "linear")
"""The interpolation methods (:data:`InterpolationMethod`)."""
OUTSIDE_POLICIES: tuple[str, ...] = ("nearest", "exclude")
"""The policies outside the surveyed hull (:data:`OutsidePolicy`)."""


@dataclass(frozen=True, eq=False)
class SurveyPoints:
    """Corrected survey values at surveyed points, one receiver.

    Attributes
    ----------
    xy_m
        ``(n, 2)`` unique surveyed points, metres.
    m_db
        ``(n,)`` mean corrected value ``M = R − P_tx − D_st`` at each point, dB.
    n_samples
        ``(n,)`` how many raw samples were averaged.
    """

    xy_m: FloatArray
    m_db: FloatArray
    n_samples: NDArray[np.int64]


def _first_bad(a: np.ndarray) -> int | None:
    """Index (along the first axis) of the first row of ``a`` that is not all finite."""
    ok = np.isfinite(a).reshape(a.shape[0], -1).all(axis=1)
    return None if ok.all() else int(np.argmin(ok))


def _float_array(value: object, what: str, where: str) -> FloatArray:
    """``value`` as a float array, or an :class:`InputError` naming ``where`` and ``what``."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} must be numbers, got {value!r:.60}") from None


def _check_choice(value: object, name: str, choices: tuple[str, ...], where: str) -> None:
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{where}: {name} must be one of {', '.join(choices)}, got {value!r:.40}")


def _check_points(points: object, where: str) -> None:
    """Survey points usable for interpolation: at least one, finite, consistent shapes."""
    if not isinstance(points, SurveyPoints):
        raise InputError(f"{where}: expected SurveyPoints, got {type(points).__name__}")
    xy, m = np.asarray(points.xy_m), np.asarray(points.m_db)
    if xy.ndim != 2 or xy.shape[1] != 2 or m.shape != (xy.shape[0],):
        raise InputError(
            f"{where}: xy_m must be (n, 2) and m_db (n,), got shapes {xy.shape} and {m.shape}"
        )
    if xy.shape[0] == 0:
        raise InputError(f"{where}: no survey points")
    for name, arr in (("xy_m", xy), ("m_db", m)):
        bad = _first_bad(arr)
        if bad is not None:
            raise InputError(f"{where}: {name}[{bad}] = {arr[bad]} is not finite")


def average_by_point(xy_m: FloatArray, values_db: FloatArray, decimals: int = 6) -> SurveyPoints:
    """Average values that share a surveyed point (positions rounded to ``decimals``).

    Raises
    ------
    InputError
        ``xy_m`` not ``(n, 2)``, ``values_db`` not ``(n,)``, or a non-finite
        position or value (naming its index).
    """
    xy = _float_array(xy_m, "xy_m", "average_by_point")
    vals = _float_array(values_db, "values_db", "average_by_point")
    if xy.ndim != 2 or xy.shape[1] != 2 or vals.shape != (xy.shape[0],):
        raise InputError(
            f"average_by_point: xy_m must be (n, 2) and values_db (n,), got shapes "
            f"{xy.shape} and {vals.shape}"
        )
    for name, arr in (("xy_m", xy), ("values_db", vals)):
        bad = _first_bad(arr) if arr.size else None
        if bad is not None:
            raise InputError(f"average_by_point: {name}[{bad}] = {arr[bad]} is not finite")
    key = np.round(xy, decimals)
    uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros(uniq.shape[0])
    np.add.at(sums, inverse.reshape(-1), vals)
    return SurveyPoints(uniq, sums / counts, counts.astype(np.int64))


def spans_two_dimensions(xy_m: FloatArray, rel_tol: float = 1e-6) -> bool:
    """Whether points span an area: at least 3 of them, not all on one line.

    Parameters
    ----------
    xy_m
        ``(n, 2)`` points, metres.
    rel_tol
        The points count as collinear when their spread across their principal
        axis is at most ``rel_tol`` times their spread along it (singular values
        of the centred points).
    """
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    if xy.shape[0] < 3 or not np.all(np.isfinite(xy)):
        return False
    sv = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[1] > rel_tol * sv[0])


def hull_coverage(xy_m: FloatArray, x_m: FloatArray, y_m: FloatArray, tol_m: float = 1e-6) -> float:
    """Fraction of the grid ``x_m × y_m`` inside the convex hull of ``xy_m``.

    Exact for grid points (boundary points, within ``tol_m``, count as inside):
    for each value of the shorter axis the hull's half-planes bound an interval
    of the longer one, counted by binary search, so the cost is
    ``min(nx, ny) × hull edges``.

    Parameters
    ----------
    xy_m
        ``(n, 2)`` points spanning an area (:func:`spans_two_dimensions`).
    x_m, y_m
        ``(nx,)``, ``(ny,)`` increasing grid axes, metres.

    Returns
    -------
    In ``[0, 1]``; 0 when the hull cannot be built (degenerate points).
    """
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    # memoised on disk: scipy.spatial's import costs more than the hull (diskcache)
    out = memo_arrays(
        "hull-coverage",
        (xy, x, y, float(tol_m)),
        lambda: {"coverage": np.array(_hull_coverage(xy, x, y, tol_m))},
    )
    return float(out["coverage"])


def _hull_coverage(xy_m: FloatArray, x_m: FloatArray, y_m: FloatArray, tol_m: float) -> float:
    """:func:`hull_coverage`, computed."""
    from scipy.spatial import ConvexHull, QhullError  # ≈ 0.3 s to import: only where used

    try:
        eq = ConvexHull(np.asarray(xy_m, float).reshape(-1, 2)).equations  # a·p + c <= 0 inside
    except (QhullError, ValueError):
        return 0.0
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    if x.size == 0 or y.size == 0:
        return 0.0
    u, v, au, av = (x, y, eq[:, 0], eq[:, 1]) if x.size <= y.size else (y, x, eq[:, 1], eq[:, 0])
    # For each u: a_v·v <= -c - a_u·u + tol, facet by facet.
    rhs = -eq[None, :, 2] - au[None, :] * u[:, None] + tol_m  # (nu, facets)
    flat = np.abs(av) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rhs / np.where(flat, 1.0, av)[None, :]
    hi = np.min(np.where((av > 0) & ~flat, bound, np.inf), axis=1)
    lo = np.max(np.where((av < 0) & ~flat, bound, -np.inf), axis=1)
    out = np.any(flat[None, :] & (rhs < 0), axis=1)
    count = np.searchsorted(v, hi, side="right") - np.searchsorted(v, lo, side="left")
    count = np.where(out, 0, np.maximum(count, 0))
    return float(count.sum()) / (x.size * y.size)


def _regular_axes(xy: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    xs = np.unique(xy[:, 0])
    ys = np.unique(xy[:, 1])
    if xs.size < 2 or ys.size < 2 or xs.size * ys.size != xy.shape[0]:
        return None
    return xs, ys


def interpolate_points(
    points: SurveyPoints,
    query_xy_m: FloatArray,
    method: InterpolationMethod = "cubic",
    outside: OutsidePolicy = "nearest",
) -> FloatArray:
    """Interpolate one receiver's corrected survey values at query points.

    Parameters
    ----------
    points
        Averaged survey values of the receiver.
    query_xy_m
        ``(q, 2)`` query points, metres.
    method
        ``"cubic"`` or ``"linear"`` (see module docstring).
    outside
        Policy outside the surveyed hull: ``"nearest"`` or ``"exclude"`` (NaN).

    Returns
    -------
    ``(q,)`` values in dB (NaN outside the hull with ``"exclude"``).

    Raises
    ------
    InputError
        No survey points, a non-finite survey point or value or query point
        (naming its index), or an unknown ``method`` or ``outside``.
    """
    _check_choice(method, "method", METHODS, "interpolate_points")
    _check_choice(outside, "outside", OUTSIDE_POLICIES, "interpolate_points")
    _check_points(points, "interpolate_points: points")
    q = _float_array(query_xy_m, "query_xy_m", "interpolate_points")
    if q.size % 2 != 0:
        raise InputError(f"interpolate_points: query_xy_m must be (q, 2), got shape {q.shape}")
    q = q.reshape(-1, 2)
    bad = _first_bad(q) if q.size else None
    if bad is not None:
        raise InputError(f"interpolate_points: query_xy_m[{bad}] = {q[bad]} is not finite")
    from scipy.interpolate import (  # ≈ 0.45 s to import: only where used
        CloughTocher2DInterpolator,
        LinearNDInterpolator,
        RectBivariateSpline,
        RegularGridInterpolator,
    )
    from scipy.spatial import cKDTree

    xy = points.xy_m
    if xy.shape[0] == 1:
        out = np.full(q.shape[0], points.m_db[0])
        return out
    axes = _regular_axes(xy)
    if axes is not None:
        xs, ys = axes
        grid = np.full((xs.size, ys.size), np.nan)
        grid[np.searchsorted(xs, xy[:, 0]), np.searchsorted(ys, xy[:, 1])] = points.m_db
        inside = (q[:, 0] >= xs[0]) & (q[:, 0] <= xs[-1]) & (q[:, 1] >= ys[0]) & (q[:, 1] <= ys[-1])
        out = np.full(q.shape[0], np.nan)
        if method == "cubic" and min(xs.size, ys.size) >= 4:
            spline = RectBivariateSpline(xs, ys, grid, kx=3, ky=3, s=0)
            out[inside] = spline.ev(q[inside, 0], q[inside, 1])
        else:
            interp = RegularGridInterpolator((xs, ys), grid, method="linear")
            out[inside] = interp(q[inside])
    else:
        cls = CloughTocher2DInterpolator if method == "cubic" else LinearNDInterpolator
        try:
            out = cls(xy, points.m_db, fill_value=np.nan)(q)
        except Exception:  # collinear / degenerate layout: Qhull cannot triangulate
            out = np.full(q.shape[0], np.nan)
    missing = ~np.isfinite(out)
    if outside == "nearest" and np.any(missing):
        _, idx = cKDTree(xy).query(q[missing])
        out[missing] = points.m_db[idx]
    return out


@dataclass(frozen=True, eq=False)
class SurveyMap:
    """The channel map of every receiver on the candidate grid.

    Attributes
    ----------
    receiver_ids
        Receiver order of the first axis.
    x_m, y_m
        Candidate grid axes ``(nx,)``, ``(ny,)``, metres.
    m_db
        ``(n_receivers, nx, ny)``: ``M_r`` at each candidate, dB (NaN = excluded).
    points
        The averaged survey values each map was interpolated from.
    """

    receiver_ids: tuple[str, ...]
    x_m: FloatArray
    y_m: FloatArray
    m_db: FloatArray
    points: tuple[SurveyPoints, ...]

    def receiver_index(self, receiver_id: str) -> int:
        """Index of ``receiver_id`` along the first axis of ``m_db``.

        Raises
        ------
        InputError
            The map holds no such receiver.
        """
        try:
            return self.receiver_ids.index(receiver_id)
        except ValueError:
            raise InputError(
                f"unknown receiver {receiver_id!r:.40}: the survey map holds "
                f"{', '.join(map(repr, self.receiver_ids))}"
            ) from None


def build_survey_map(
    receiver_ids: Sequence[str],
    points: Sequence[SurveyPoints],
    x_m: FloatArray,
    y_m: FloatArray,
    method: InterpolationMethod = "cubic",
    outside: OutsidePolicy = "nearest",
) -> SurveyMap:
    """Interpolate every receiver's survey onto the ``(x_m, y_m)`` candidate grid.

    Raises
    ------
    InputError
        No receivers, not one set of points per receiver, a repeated receiver
        id, unusable points (:func:`interpolate_points`; naming the receiver),
        empty or non-finite grid axes, or an unknown ``method`` or ``outside``.
    """
    where = "build_survey_map"
    _check_choice(method, "method", METHODS, where)
    _check_choice(outside, "outside", OUTSIDE_POLICIES, where)
    ids, pts = tuple(receiver_ids), tuple(points)
    if not ids:
        raise InputError(f"{where}: no receivers")
    if len(ids) != len(pts):
        raise InputError(
            f"{where}: {len(ids)} receiver id(s) but {len(pts)} set(s) of survey points; "
            "give one per receiver"
        )
    seen: set[str] = set()
    for i, (rid, p) in enumerate(zip(ids, pts, strict=True)):
        if rid in seen:
            raise InputError(f"{where}: receiver_ids[{i}] = {rid!r:.40} is repeated")
        seen.add(rid)
        _check_points(p, f"{where}: points[{i}] (receiver {rid!r:.40})")
    for name, axis in (("x_m", x_m), ("y_m", y_m)):
        a = _float_array(axis, name, where)
        if a.ndim != 1 or a.size == 0 or not np.isfinite(a).all():
            raise InputError(f"{where}: {name} must be a non-empty 1-D array of finite numbers")
    gx, gy = np.meshgrid(x_m, y_m, indexing="ij")

    def compute() -> dict[str, np.ndarray]:
        q = np.column_stack([gx.ravel(), gy.ravel()])
        return {
            "maps": np.stack(
                [interpolate_points(p, q, method, outside).reshape(gx.shape) for p in pts]
            ).reshape(len(pts), *gx.shape)
        }

    # memoised on disk: scipy.interpolate's import costs more than the
    # interpolation (diskcache; the same float64 numbers)
    key: list[object] = [method, outside, np.asarray(x_m, float), np.asarray(y_m, float)]
    for p in pts:
        key += [np.asarray(p.xy_m, float), np.asarray(p.m_db, float)]
    maps = memo_arrays("survey-map", key, compute)["maps"]
    for arr in (maps,):
        arr.setflags(write=False)
    return SurveyMap(ids, np.asarray(x_m), np.asarray(y_m), maps, pts)
