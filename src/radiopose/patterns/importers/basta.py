"""NGMN BASTA 3-D antenna pattern JSON (WP3.0 ``3drp``).

The JSON is parsed twice: once for the values (:func:`_decode`: ``Data_Set``
row by row into a float array, else :func:`json.loads`) and, only once something
is wrong, by a small offset scanner (:class:`_JsonText`) so every error names its
line.
See :mod:`radiopose.patterns.importers` for the coordinate conventions.
"""

from __future__ import annotations

import json
import math
import os
import re
from array import array
from itertools import chain
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.importers._common import (
    _ROUND,
    DBD_TO_DBI,
    MAX_ABS_DB,
    MIN_CIRCLE_ANGLES,
    MIN_SPHERE_POLAR_ANGLES,
    _in_file,
    _normalised,
    _read_text,
    _require_angles,
    _stem,
)
from radiopose.patterns.pattern import (
    MAX_ABS_DIRECTIVITY_DBI,
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


def _skip_ws(text: str, i: int) -> int:
    """Offset of the first non-whitespace (JSON whitespace) character at or after ``i``."""
    m = _JSON_WS.match(text, i)
    return i if m is None else m.end()


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
        return _skip_ws(self.text, i)

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


def _json_literal(value: Any) -> str:
    """A decoded JSON scalar as written (``"15.1"``, ``true``, ``null``), else its kind."""
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return json.dumps(value)[:40]


def _basta_gain_dbi(gain: Any, path: Path, line: int) -> float:
    """``Gain`` (``{"value": number, "unit": "dBi"|"dBd"}``) in dBi.

    The value must be a JSON number (not a string, not ``true``/``false``), finite,
    and in dBi within ``±MAX_ABS_DIRECTIVITY_DBI`` — the ``directivity_dbi`` range
    :func:`~radiopose.patterns.pattern.read_pattern_csv` accepts, so the peak of an
    imported pattern can be written and read back.

    Raises
    ------
    InputError
        At ``line`` (the ``Gain`` value), column ``Gain``.
    """

    def bad(message: str) -> InputError:
        return InputError(message, path=path, line=line, column="Gain")

    if not isinstance(gain, dict) or "value" not in gain or "unit" not in gain:
        raise bad("expected {value: number, unit: dBi|dBd}")
    value, unit = gain["value"], gain["unit"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise bad(
            f"Gain value {_json_literal(value)} is not a number "
            "(expected {value: number, unit: dBi|dBd})"
        )
    if unit not in ("dBi", "dBd"):
        raise bad(f"Gain unit {_json_literal(unit)} is not dBi or dBd")
    if isinstance(value, float) and not math.isfinite(value):  # NaN, Infinity, 1e400
        raise bad(f"Gain value {_json_literal(value)} is not a finite number")
    try:
        gain_dbi = float(value) + (DBD_TO_DBI if unit == "dBd" else 0.0)
    except OverflowError:  # an integer beyond float
        gain_dbi = math.inf
    if abs(gain_dbi) > MAX_ABS_DIRECTIVITY_DBI:
        in_dbi = "" if unit == "dBi" else f" ({gain_dbi:g} dBi)"
        raise bad(
            f"Gain {str(value)[:40]} {unit}{in_dbi} is out of range "
            f"[-{MAX_ABS_DIRECTIVITY_DBI:g}, {MAX_ABS_DIRECTIVITY_DBI:g}] dBi "
            "(the pattern CSV's directivity_dbi range)"
        )
    return gain_dbi


def _decode_rows(text: str, i: int, decoder: json.JSONDecoder) -> tuple[FloatArray | None, int]:
    """The ``Data_Set`` array starting at ``text[i] == "["``, one row at a time, as an
    ``(n_rows, n_values)`` float64 array and the offset after it.

    ``None`` for an empty array, a row that is not a list of JSON numbers (``true``,
    ``"1.5"``, ``null``, an integer beyond float) or rows of different lengths:
    :func:`_decode` then falls back to :func:`json.loads` and the checks that name
    the row.
    """
    values = array("d")
    n_rows, width = 0, -1
    i = _skip_ws(text, i + 1)
    while True:
        row, i = decoder.raw_decode(text, i)
        if type(row) is not list or not row or (width >= 0 and len(row) != width):
            return None, i
        if not all(type(v) is float or type(v) is int for v in row):  # bool is not int
            return None, i
        values.extend(row)  # OverflowError for an integer beyond float
        n_rows, width = n_rows + 1, len(row)
        i = _skip_ws(text, i)
        if text[i] == "]":
            return np.frombuffer(values, dtype=np.float64).reshape(n_rows, width), i + 1
        if text[i] != ",":
            return None, i
        i = _skip_ws(text, i + 1)


class _RepeatedKeyError(Exception):
    """A key given twice in one JSON object."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of :func:`json.loads`: a dict, refusing a repeated key
    (``json.loads`` alone keeps the last: a file with two ``Gain`` values would be
    read with one of them, without a word)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _RepeatedKeyError(key)
        out[key] = value
    return out


def _decode(text: str) -> dict[str, Any] | None:
    """``json.loads(text)`` of a BASTA object, with ``Data_Set`` decoded straight into
    a float array (:func:`_decode_rows`) instead of a list of lists: 8 bytes a value
    instead of about 60 (a float object and a list slot, plus a list per row).

    Each member is decoded by :meth:`json.JSONDecoder.raw_decode` (the same scanner
    as :func:`json.loads`). ``None`` for anything else — not an object, a syntax
    error, a key given twice, a ``Data_Set`` that is not a plain table of
    numbers — so :func:`json.loads` reads the file again and its error, or the
    row checks, say what is wrong.
    """
    decoder = json.JSONDecoder()
    out: dict[str, Any] = {}
    try:
        i = _skip_ws(text, 0)
        if text[i] != "{":
            return None
        i = _skip_ws(text, i + 1)
        while text[i] != "}":
            if text[i] != '"':
                return None
            key, i = decoder.raw_decode(text, i)
            i = _skip_ws(text, i)
            if text[i] != ":" or key in out:
                return None
            i = _skip_ws(text, i + 1)
            if key == "Data_Set" and text[i] == "[":
                out[key], i = _decode_rows(text, i, decoder)
                if out[key] is None:
                    return None
            else:
                out[key], i = decoder.raw_decode(text, i)
            i = _skip_ws(text, i)
            if text[i] == ",":
                i = _skip_ws(text, i + 1)
                if text[i] == "}":  # a trailing comma
                    return None
            elif text[i] != "}":
                return None
        if _skip_ws(text, i + 1) != len(text):
            return None
    except (ValueError, IndexError, OverflowError, RecursionError):  # JSONDecodeError too
        return None
    return out


def _basta_rows(rows: Any, structure: list[str], path: Path, where: _JsonText) -> FloatArray:
    """``Data_Set`` (a float array from :func:`_decode`, or the rows :func:`json.loads`
    made) as an ``(n_rows, n_columns)`` array; the first bad row/value is named.

    The list is checked in bulk (row types and lengths, value types) and walked
    value by value only when that fails; finite values and the range are checked
    on the array.
    """
    ncol = len(structure)
    if isinstance(rows, np.ndarray):
        table = rows  # equal-length rows of JSON numbers
        if table.shape[1] != ncol:
            _raise_first_bad_row([[0.0] * table.shape[1]], structure, path, where)
    elif not isinstance(rows, list) or not rows:
        raise InputError(
            "expected a non-empty list of rows",
            path=path,
            line=where.key_line("Data_Set"),
            column="Data_Set",
        )
    else:
        plain = (
            set(map(type, rows)) == {list}
            and set(map(len, rows)) == {ncol}
            and set(map(type, chain.from_iterable(rows))) <= {float, int}  # no bool, str, None
        )
        try:
            table = np.array(rows if plain else [], dtype=np.float64)
        except OverflowError:  # an integer beyond float
            plain = False
        if not plain:
            _raise_first_bad_row(rows, structure, path, where)
    bad = ~(np.abs(table) <= MAX_ABS_DB)  # NaN too
    if bad.any():
        r, k = (int(x) for x in np.argwhere(bad)[0])  # the first in file order
        finite = bool(np.isfinite(table[r, k]))
        what = f"out of range [-{MAX_ABS_DB:g}, {MAX_ABS_DB:g}]" if finite else None
        _raise_bad_value(r, k, what or "not a finite number", structure, path, where)
    return table


def _raise_bad_value(
    r: int, k: int, what: str, structure: list[str], path: Path, where: _JsonText
) -> None:
    raise InputError(
        f"Data_Set row {r}: {what}: {where.literal(r, k)[:40]}",
        path=path,
        line=where.row_line(r, k),
        column=structure[k],
    )


def _raise_first_bad_row(
    rows: list[Any], structure: list[str], path: Path, where: _JsonText
) -> None:
    """Walk ``Data_Set`` row by row and raise at the first row or value that is not
    a list of ``len(structure)`` JSON numbers (an integer beyond float is not finite)."""
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
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                _raise_bad_value(r, k, "not a number", structure, path, where)
            try:
                float(v)
            except OverflowError:
                _raise_bad_value(r, k, "not a finite number", structure, path, where)


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
    data: Any = _decode(text)
    if data is None:  # json.loads names the syntax error; the row checks a bad row
        try:
            data = json.loads(text, object_pairs_hook=_unique_keys)
        except _RepeatedKeyError as exc:
            spots = [m.start() for m in re.finditer(re.escape(json.dumps(exc.key)) + r"\s*:", text)]
            raise InputError(
                f"key {exc.key!r} appears twice in one object (JSON leaves which one counts "
                "undefined)",
                path=p,
                line=text.count("\n", 0, spots[1]) + 1 if len(spots) > 1 else None,
                column=exc.key,
            ) from None
        except json.JSONDecodeError as exc:
            raise InputError(
                f"invalid JSON: {exc.msg} (column {exc.colno})", path=p, line=exc.lineno
            ) from None
        except RecursionError:
            raise InputError("invalid JSON: nested too deeply", path=p) from None
        except ValueError as exc:  # e.g. an integer beyond Python's 4,300-digit limit
            raise InputError(f"invalid JSON: {str(exc).split(';')[0]}", path=p) from None
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
    gain_dbi = _basta_gain_dbi(_basta_key(data, "Gain", p, where), p, where.key_line("Gain"))

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
    del data["Data_Set"]  # json.loads's rows (about 60 bytes a value), now in table
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
    # the gain and each attenuation within their own ranges can still give a
    # directivity the pattern CSV refuses (15 dBi − 300 dB): named at its row
    directivity = gain_dbi - atten
    beyond = np.flatnonzero(~(np.abs(directivity) <= MAX_ABS_DIRECTIVITY_DBI))
    if beyond.size:
        r = int(beyond[0])
        key = "MagAttenuationTP" if "MagAttenuationTP" in col else "MagAttenuationCo"
        raise InputError(
            f"Data_Set row {r}: directivity {directivity[r]:g} dBi (Gain {gain_dbi:g} dBi − "
            f"attenuation {atten[r]:g} dB) is out of [-{MAX_ABS_DIRECTIVITY_DBI:g}, "
            f"{MAX_ABS_DIRECTIVITY_DBI:g}] dBi (the pattern CSV's range)",
            path=p,
            line=where.row_line(r, structure.index(key)),
            column=key,
        )

    polar, az = _basta_to_polar(system, theta, phi)
    polar = np.round(polar, _ROUND)
    az = np.round(az, _ROUND)
    az = np.where(az >= 360.0, 0.0, az)
    with _in_file(p):  # a GridError gets its row below; Pattern's own checks the file
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
    # a complete grid, but enough of one? (file angles and grid axes correspond one to one)
    for key, angles, n_grid, minimum, noun in (
        ("Theta", theta, pattern.polar_deg.size, MIN_SPHERE_POLAR_ANGLES, "polar angles"),
        ("Phi", phi, pattern.azimuth_deg.size, MIN_CIRCLE_ANGLES, "azimuths"),
    ):
        if n_grid < minimum:
            column = key if explicit else f"{key}_Sampling"
            _require_angles(
                angles,
                minimum,
                f"Data_Set {key}" if explicit else column,
                f"a sphere needs at least {minimum} {noun}"
                + (" (both poles and one between)" if key == "Theta" else ""),
                p,
                where.key_line("Data_Set" if explicit else column),
                column,
            )
    return _normalised(pattern, normalise)
