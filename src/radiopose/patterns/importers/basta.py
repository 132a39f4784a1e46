"""NGMN BASTA 3-D antenna pattern JSON (WP3.0 ``3drp``).

The JSON is parsed twice: once by :mod:`json` for the values and once by a
small offset scanner (:class:`_JsonText`) so every error names its line.
See :mod:`radiopose.patterns.importers` for the coordinate conventions.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.importers._common import (
    _ROUND,
    DBD_TO_DBI,
    MAX_ABS_DB,
    _normalised,
    _read_text,
    _stem,
)
from radiopose.patterns.pattern import (
    MIN_GRID_STEP_DEG,
    GridError,
    Pattern,
    pattern_from_samples,
    too_fine,
)
from radiopose.units import (
    FloatArray,
    db_to_linear,
    linear_to_db,
    wrap_deg,
)

_JSON_WS = re.compile(r"[ \t\n\r]*")


class _JsonText:
    """Where things are in a JSON text :func:`json.loads` has accepted.

    ``json`` reports no positions for valid documents, so the error paths walk
    the text again with :meth:`json.JSONDecoder.raw_decode`, one value at a time:
    the offset of each top-level member's value and of each element of an
    array, turned into 1-based line numbers. Only used once something is wrong.
    """

    def __init__(self, text: str) -> None:
        self.text = text
        self._decoder = json.JSONDecoder()
        self._members: dict[str, int] | None = None
        self._rows: list[int] | None = None

    def _skip(self, i: int) -> int:
        m = _JSON_WS.match(self.text, i)
        return i if m is None else m.end()

    def _end(self, i: int) -> int:
        return self._decoder.raw_decode(self.text, i)[1]

    def line(self, offset: int) -> int:
        return self.text.count("\n", 0, offset) + 1

    def start(self) -> int:
        return self._skip(0)

    def members(self) -> dict[str, int]:
        """Top-level key -> offset of its value (the last one if repeated, as json does)."""
        if self._members is None:
            out: dict[str, int] = {}
            i = self._skip(self.start() + 1)
            while self.text[i] != "}":
                key, i = self._decoder.raw_decode(self.text, i)
                i = self._skip(self._skip(i) + 1)  # the ':'
                out[key] = i
                i = self._skip(self._end(i))
                if self.text[i] == ",":
                    i = self._skip(i + 1)
            self._members = out
        return self._members

    def elements(self, i: int) -> list[int]:
        """Offsets of the elements of the array starting at offset ``i``."""
        out: list[int] = []
        i = self._skip(i + 1)
        while self.text[i] != "]":
            out.append(i)
            i = self._skip(self._end(i))
            if self.text[i] == ",":
                i = self._skip(i + 1)
        return out

    def key_line(self, key: str) -> int:
        """Line of ``key``'s value, or of the top-level object's start if absent."""
        at = self.members().get(key)
        return self.line(self.start() if at is None else at)

    def row_offset(self, row: int, element: int | None = None) -> int:
        if self._rows is None:
            self._rows = self.elements(self.members()["Data_Set"])
        at = self._rows[row]
        if element is not None and self.text[at] == "[":
            items = self.elements(at)
            if element < len(items):
                at = items[element]
        return at

    def row_line(self, row: int, element: int | None = None) -> int:
        return self.line(self.row_offset(row, element))

    def literal(self, row: int, element: int) -> str:
        at = self.row_offset(row, element)
        return self.text[at : self._end(at)]


def _basta_key(data: dict[str, Any], key: str, path: Path, where: _JsonText) -> Any:
    if key not in data or data[key] is None:
        line = where.key_line(key)
        what = (
            "missing (the value is null)" if key in data else "missing key in the top-level object"
        )
        raise InputError(what, path=path, line=line, column=key)
    return data[key]


def _sampling(
    values: Any, key: str, path: Path, line: int, low: float, high: float, system: str
) -> FloatArray:
    """``[start, step, stop]`` as its angles, checked from the numbers before allocating:
    a step of at least :data:`MIN_GRID_STEP_DEG`, start and stop within
    ``[low, high]`` (``high`` open for phi)."""
    numbers = isinstance(values, list) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
    )
    try:
        if not numbers:
            raise TypeError
        start, step, stop = (float(v) for v in values)
    except (TypeError, ValueError, OverflowError):
        raise InputError(
            "expected [start, step, stop] numbers", path=path, line=line, column=key
        ) from None
    if not (math.isfinite(start) and math.isfinite(step) and math.isfinite(stop)) or step <= 0:
        raise InputError(
            "expected finite [start, step > 0, stop]", path=path, line=line, column=key
        )
    if too_fine(step):
        raise InputError(
            f"step {step:g} deg is finer than the {MIN_GRID_STEP_DEG:g} deg limit",
            path=path,
            line=line,
            column=key,
        )
    k = (stop - start) / step  # inf for huge ends: the range check below rejects them
    n = round(k) if math.isfinite(k) else 0
    if math.isfinite(k) and (n < 0 or abs(start + n * step - stop) > 1e-6):
        raise InputError("stop is not start + k·step", path=path, line=line, column=key)
    phi = key == "Phi_Sampling"
    # within range and step >= 0.1: at most 5401 angles
    if start < low or (stop >= high if phi else stop > high):
        rng = f"[{low:g}, {high:g}{')' if phi else ']'}"
        raise InputError(
            f"covers {start:g}…{stop:g}, out of range {rng} for {system}",
            path=path,
            line=line,
            column=key,
        )
    return start + np.arange(n + 1, dtype=np.float64) * step


_BASTA_SYSTEMS = ("SPCS_Polar", "SPCS_CW", "SPCS_CCW")
_BASTA_PHI_RANGE = (-180.0, 360.0)  # [low, high): 0…359 and −180…179 files both read


def _basta_theta_range(system: str) -> tuple[float, float]:
    return (0.0, 180.0) if system == "SPCS_Polar" else (-90.0, 90.0)


def _basta_to_polar(
    system: str, theta: FloatArray, phi: FloatArray
) -> tuple[FloatArray, FloatArray]:
    if system == "SPCS_Polar":
        polar, az = theta, phi
    elif system == "SPCS_CW":
        polar, az = theta + 90.0, -phi
    else:  # SPCS_CCW
        polar, az = theta + 90.0, phi
    return polar, wrap_deg(az)


def _basta_rows(rows: Any, structure: list[str], path: Path, where: _JsonText) -> FloatArray:
    """``Data_Set`` as an ``(n_rows, n_columns)`` array; the first bad row/value is named."""
    if not isinstance(rows, list) or not rows:
        raise InputError(
            "expected a non-empty list of rows",
            path=path,
            line=where.key_line("Data_Set"),
            column="Data_Set",
        )
    ncol = len(structure)
    for r, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != ncol:
            got = f"{len(row)} values" if isinstance(row, list) else f"a {type(row).__name__}"
            raise InputError(
                f"Data_Set row {r} is {got}, Data_Set_Row_Structure names {ncol}",
                path=path,
                line=where.row_line(r),
                column="Data_Set",
            )
        for k, v in enumerate(row):
            finite = False
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                try:
                    finite = math.isfinite(float(v))
                except OverflowError:
                    finite = False
                what = "not a finite number"
                if finite and abs(float(v)) > MAX_ABS_DB:
                    finite = False
                    what = f"out of range [-{MAX_ABS_DB:g}, {MAX_ABS_DB:g}]"
            else:
                what = "not a number"
            if not finite:
                raise InputError(
                    f"Data_Set row {r}: {what}: {where.literal(r, k)[:40]}",
                    path=path,
                    line=where.row_line(r, k),
                    column=structure[k],
                )
    return np.array(rows, dtype=np.float64)


def read_basta_json(
    path: str | os.PathLike[str], *, normalise: bool = False, name: str | None = None
) -> Pattern:
    """Import an NGMN BASTA 3-D radiation pattern JSON (WP3.0 ``3drp``).

    Conventions (NGMN BASTA AA WP3.0 schema; conversions as in Ericsson's
    ``eas-3d-pattern`` reader): ``Data_Set`` rows follow
    ``Data_Set_Row_Structure``; with uniform sampling ``Theta_Sampling`` and
    ``Phi_Sampling`` are ``[start, step, stop]`` and the rows run theta-major,
    phi fastest; otherwise each row carries ``Theta`` and ``Phi``.
    ``MagAttenuation*`` are dB below ``Gain`` (``{"value", "unit": dBi|dBd}``).
    Power: ``MagAttenuationTP`` if present, else the sum of the co- and
    cross-polar powers ``10^(−Co/10) + 10^(−Cr/10)``, else Co alone.

    Coordinate systems (boresight = body ``+x``, up = body ``+z``)::

        SPCS_Polar  theta 0…180 from zenith, phi CCW from above:
                    theta_p = theta,       phi_p = phi
        SPCS_CW     theta −90…90, +90 = nadir (down-tilt > 0), phi clockwise from above:
                    theta_p = theta + 90,  phi_p = −phi mod 360
        SPCS_CCW    as SPCS_CW with phi counter-clockwise:
                    theta_p = theta + 90,  phi_p = phi
        directivity_dbi = G_dBi − attenuation_dB,  G_dBi = G_dBd + 2.15

    Angle ranges (explicit ``Theta``/``Phi`` values and the sampling's start
    and stop): theta as above, phi in ``[−180, 360)`` (files write 0…359 or
    −180…179); anything outside is rejected, not wrapped. ``SPCS_Geo`` is
    rejected: its theta orientation is not pinned down by the schema and
    readers disagree.

    Parameters
    ----------
    path
        The JSON file.
    normalise
        Rescale to mean intensity 0 dBi instead of keeping the stated gain.
    name
        Pattern name (default: file stem).

    Raises
    ------
    InputError
        Bad JSON, a missing/invalid key, a non-number or non-finite value, an
        angle out of range, or a grid that is not a complete regular sphere —
        naming file, the line in the JSON text (of the key's value, or of the
        offending ``Data_Set`` row/value) and the key or row-structure name.
    """
    p = Path(path)
    text = _read_text(p)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"invalid JSON: {exc.msg} (column {exc.colno})", path=p, line=exc.lineno
        ) from None
    except RecursionError:
        raise InputError("invalid JSON: nested too deeply", path=p) from None
    where = _JsonText(text)
    if not isinstance(data, dict):
        raise InputError("expected a JSON object", path=p, line=where.line(where.start()))
    system = str(_basta_key(data, "Coordinate_System", p, where))
    if system not in _BASTA_SYSTEMS:
        raise InputError(
            f"unsupported coordinate system {system!r} ({', '.join(_BASTA_SYSTEMS)})",
            path=p,
            line=where.key_line("Coordinate_System"),
            column="Coordinate_System",
        )
    gain = _basta_key(data, "Gain", p, where)
    try:
        g_value = float(gain["value"])
        g_unit = str(gain["unit"])
    except (TypeError, KeyError, ValueError, OverflowError):
        raise InputError(
            "expected {value: number, unit: dBi|dBd}",
            path=p,
            line=where.key_line("Gain"),
            column="Gain",
        ) from None
    if not math.isfinite(g_value) or g_unit not in ("dBi", "dBd"):
        raise InputError(
            "expected a finite value and unit dBi or dBd",
            path=p,
            line=where.key_line("Gain"),
            column="Gain",
        )
    gain_dbi = g_value + (DBD_TO_DBI if g_unit == "dBd" else 0.0)

    structure = _basta_key(data, "Data_Set_Row_Structure", p, where)
    s_line = where.key_line("Data_Set_Row_Structure")
    if not isinstance(structure, list) or not all(isinstance(s, str) for s in structure):
        raise InputError(
            "expected a list of names", path=p, line=s_line, column="Data_Set_Row_Structure"
        )
    repeated = sorted({s for s in structure if structure.count(s) > 1})
    if repeated:
        raise InputError(
            f"{repeated[0]!r} appears more than once",
            path=p,
            line=s_line,
            column="Data_Set_Row_Structure",
        )
    if not any(s in structure for s in ("MagAttenuationTP", "MagAttenuationCo")):
        raise InputError(
            "no MagAttenuationTP or MagAttenuationCo column",
            path=p,
            line=s_line,
            column="Data_Set_Row_Structure",
        )
    if ("Theta" in structure) != ("Phi" in structure):
        raise InputError(
            "Theta and Phi come together (or neither, with Theta_/Phi_Sampling)",
            path=p,
            line=s_line,
            column="Data_Set_Row_Structure",
        )
    table = _basta_rows(_basta_key(data, "Data_Set", p, where), structure, p, where)
    col = {s: table[:, k] for k, s in enumerate(structure)}

    t_lo, t_hi = _basta_theta_range(system)
    p_lo, p_hi = _BASTA_PHI_RANGE
    explicit = "Theta" in col
    if explicit:
        theta, phi = col["Theta"], col["Phi"]
        for key, vals, lo, hi, rng in (
            ("Theta", theta, t_lo, t_hi, f"[{t_lo:g}, {t_hi:g}]"),
            ("Phi", phi, p_lo, p_hi, f"[{p_lo:g}, {p_hi:g})"),
        ):
            bad = np.nonzero((vals < lo) | (vals > hi) | ((key == "Phi") & (vals >= hi)))[0]
            if bad.size:
                r = int(bad[0])
                raise InputError(
                    f"Data_Set row {r}: {key} {vals[r]:g} out of range {rng} for {system}",
                    path=p,
                    line=where.row_line(r, structure.index(key)),
                    column=key,
                )
    else:
        th, ph = (
            _sampling(_basta_key(data, key, p, where), key, p, where.key_line(key), lo, hi, system)
            for key, lo, hi in (("Theta_Sampling", t_lo, t_hi), ("Phi_Sampling", p_lo, p_hi))
        )
        if th.size * ph.size != table.shape[0]:
            n_rows = table.shape[0]
            at = th.size * ph.size if n_rows > th.size * ph.size else n_rows - 1
            raise InputError(
                f"{n_rows} rows, Theta_Sampling × Phi_Sampling gives "
                f"{th.size}×{ph.size} = {th.size * ph.size}",
                path=p,
                line=where.row_line(at),
                column="Data_Set",
            )
        tt, pp = np.meshgrid(th, ph, indexing="ij")  # theta-major, phi fastest
        theta, phi = tt.ravel(), pp.ravel()

    if "MagAttenuationTP" in col:
        atten = col["MagAttenuationTP"]
    else:
        lin = db_to_linear(-col["MagAttenuationCo"])
        if "MagAttenuationCr" in col:
            lin = lin + db_to_linear(-col["MagAttenuationCr"])
        atten = -linear_to_db(lin)

    polar, az = _basta_to_polar(system, theta, phi)
    polar = np.round(polar, _ROUND)
    az = np.round(az, _ROUND)
    az = np.where(az >= 360.0, 0.0, az)
    try:
        pattern = pattern_from_samples(name or _stem(p), az, polar, gain_dbi - atten)
    except GridError as exc:
        r = exc.row
        msg = f"Data_Set row {r} (Theta {theta[r]:g}, Phi {phi[r]:g}): {exc.message}"
        if exc.other_row is not None:
            msg += f" (first in row {exc.other_row})"
        key = "Phi" if exc.axis == "azimuth" else "Theta"
        if explicit:
            line, column = where.row_line(r, structure.index(key)), key
        else:
            line, column = where.key_line(f"{key}_Sampling"), f"{key}_Sampling"
        raise InputError(msg, path=p, line=line, column=column) from None
    return _normalised(pattern, normalise)
