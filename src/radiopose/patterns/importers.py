"""Importers for industry pattern files and real phone measurements.

Every importer returns a :class:`~radiopose.patterns.pattern.Pattern` in the
contract's pattern coordinates (``docs/patterns.md``): azimuth ``phi``
counter-clockwise about body ``+z`` from body ``+x``, polar angle ``theta``
from body ``+z``. For a base-station antenna file the antenna is mounted in
the body frame with its **boresight along body +x** and its **zenith (up) along
body +z**, so the file's horizontal plane is the pattern's ``theta = 90°``
plane.

* :func:`read_msi` — MSI/Planet ``.msi``/``.pln`` (two 2-D cuts).
* :func:`read_basta_json` — NGMN BASTA 3-D pattern JSON (WP3.0 ``3drp``).
* :func:`read_mitll_measurements` / :func:`read_mitll` — the MIT LL
  PACT anechoic-chamber BLE captures (``btle_sniffer_*.csv``), enrolled with
  :func:`~radiopose.patterns.enrol.enrol`.

Industry files carry *gain* (directivity × efficiency) in dBi; by default the
importers keep it (``directivity_dbi = G − attenuation``) so the absolute link
budget is right. ``normalise=True`` rescales to a directivity in the
radiopose sense (mean intensity 0 dBi over the sphere, or over the slice).
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.enrol import EnrolConfig, Measurements, enrol
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
    dbm_to_mw,
    linear_to_db,
    mw_to_dbm,
    wrap_deg,
)

DBD_TO_DBI = 2.15
"""Gain of a half-wave dipole over isotropic, dB (``G_dBi = G_dBd + 2.15``)."""

_ROUND = 6


def _stem(path: str | os.PathLike[str]) -> str:
    return Path(path).stem


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a file", path=path) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text ({exc.reason})", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=path) from None


# Largest |value| of a gain, attenuation or directivity in any imported file, dB:
# real antennas span well under 100 dB; anything near 1e308 is a corrupt file.
MAX_ABS_DB = 1000.0


def _finite(
    text: str, path: Path, line: int | None, column: str, limit: float | None = None
) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"not a number: {text[:40]!r}", path=path, line=line, column=column
        ) from None
    if not math.isfinite(value):
        raise InputError(f"not a finite number: {text!r}", path=path, line=line, column=column)
    if limit is not None and abs(value) > limit:
        raise InputError(
            f"{text[:40]} is out of range [-{limit:g}, {limit:g}]",
            path=path,
            line=line,
            column=column,
        )
    return value


def _normalised(pattern: Pattern, normalise: bool) -> Pattern:
    return pattern.normalised() if normalise else pattern


# ====================================================================== MSI
def _parse_gain_dbi(text: str, path: Path, line: int) -> float:
    parts = text.split()
    if not parts:
        raise InputError("empty GAIN", path=path, line=line, column="GAIN")
    value = _finite(parts[0], path, line, "GAIN", MAX_ABS_DB)
    unit = parts[1].lower() if len(parts) > 1 else "dbd"
    if unit == "dbi":
        return value
    if unit == "dbd":
        return value + DBD_TO_DBI
    raise InputError(
        f"unknown gain unit {parts[1]!r} (dBi or dBd)", path=path, line=line, column="GAIN"
    )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


_MSI_KEYWORDS = frozenset(
    [
        "NAME",
        "MAKE",
        "FREQUENCY",
        "H_WIDTH",
        "V_WIDTH",
        "FRONT_TO_BACK",
        "GAIN",
        "TILT",
        "ELECTRICAL_TILT",
        "MECHANICAL_TILT",
        "POLARIZATION",
        "COMMENT",
        "HORIZONTAL",
        "VERTICAL",
    ]
)
_MSI_WORD = re.compile(r"[A-Za-z_][A-Za-z_-]*\Z")


def _is_msi_keyword(fields: list[str]) -> bool:
    """A header keyword line (inside a block: the block ended early, a line was deleted).

    A known keyword, or a bare word (letters, ``_``, ``-``) not followed by a
    lone number: ``x3 0.03`` or ``abc 0.03`` is a data line with a bad angle.
    """
    word = fields[0]
    if word.upper() in _MSI_KEYWORDS:
        return True
    if _is_number(word) or not _MSI_WORD.match(word):
        return False
    return not (len(fields) == 2 and _is_number(fields[1]))


def _parse_msi(
    path: Path,
) -> tuple[dict[str, str], float, FloatArray, FloatArray, FloatArray, FloatArray]:
    lines = _read_text(path).splitlines()
    header: dict[str, str] = {}
    gain_dbi: float | None = None
    cuts: dict[str, tuple[list[float], list[float]]] = {}
    # every attenuation as written: (value, line, cut) — the sign rule needs the whole file
    written: list[tuple[float, int, str]] = []
    last_block: tuple[str, int, int] | None = None  # (cut, header line, points)
    cuts_line: dict[str, int] = {}
    i = 0
    while i < len(lines):
        lineno = i + 1
        raw = lines[i].strip()
        i += 1
        if not raw:
            continue
        key, _, rest = raw.partition(" ")
        key_u = key.upper()
        if key_u in ("HORIZONTAL", "VERTICAL"):
            if key_u in cuts:
                raise InputError(
                    f"second {key_u} section (the first is at line {cuts_line[key_u]})",
                    path=path,
                    line=lineno,
                    column=key_u,
                )
            try:
                n = int(rest.split()[0])
            except (ValueError, IndexError):
                raise InputError(
                    f"{key_u} needs a point count", path=path, line=lineno, column=key_u
                ) from None
            if n < 1 or i + n > len(lines):
                raise InputError(
                    f"{key_u} announces {n} points, file has {len(lines) - i} lines left",
                    path=path,
                    line=lineno,
                    column=key_u,
                )
            angles: list[float] = []
            atten: list[float] = []
            for k in range(n):
                fields = lines[i + k].split()
                ln = i + k + 1
                if fields and _is_msi_keyword(fields):
                    raise InputError(
                        f"the {key_u} section at line {lineno} announces {n} points "
                        f"but this line ends it after {k}",
                        path=path,
                        line=ln,
                        column=key_u,
                    )
                if len(fields) != 2:
                    raise InputError(
                        f"expected 'angle attenuation_dB', got {len(fields)} fields",
                        path=path,
                        line=ln,
                        column=key_u,
                    )
                a = _finite(fields[0], path, ln, f"{key_u} angle")
                if not 0.0 <= a < 360.0:
                    raise InputError(
                        f"angle {fields[0]} out of range [0, 360)",
                        path=path,
                        line=ln,
                        column=f"{key_u} angle",
                    )
                angles.append(a)
                value = _finite(fields[1], path, ln, f"{key_u} attenuation", MAX_ABS_DB)
                written.append((value, ln, key_u))
                atten.append(value)
            _check_cut(np.array(angles), path, i + 1, key_u)
            cuts[key_u] = (angles, atten)
            cuts_line[key_u] = lineno
            last_block = (key_u, lineno, n)
            i += n
            continue
        if not header and not cuts and gain_dbi is None and not rest and key_u != "NAME":
            header["NAME"] = raw  # a bare first line is the antenna name
            continue
        if _is_number(key):
            where = (
                f"after the {last_block[2]} points the {last_block[0]} section at line "
                f"{last_block[1]} announced"
                if last_block is not None
                else "before any HORIZONTAL/VERTICAL section"
            )
            raise InputError(
                f"data line {raw[:40]!r} outside a section ({where})",
                path=path,
                line=lineno,
                column=None if last_block is None else last_block[0],
            )
        if key_u == "GAIN":
            gain_dbi = _parse_gain_dbi(rest, path, lineno)
        header[key_u] = rest.strip()
    end_line = max(len(lines), 1)
    for cut in ("HORIZONTAL", "VERTICAL"):
        if cut not in cuts:
            raise InputError(f"no {cut} section in the file", path=path, line=end_line, column=cut)
    if gain_dbi is None:
        raise InputError(
            "no GAIN line in the file (dBd, or 'dBi' after the value)",
            path=path,
            line=end_line,
            column="GAIN",
        )
    sign = _msi_sign(written, path)
    h_ang, h_att = (np.array(v) for v in cuts["HORIZONTAL"])
    v_ang, v_att = (np.array(v) for v in cuts["VERTICAL"])
    return header, gain_dbi, h_ang, sign * h_att, v_ang, sign * v_att


def _msi_sign(written: list[tuple[float, int, str]], path: Path) -> float:
    """+1 if the file writes attenuations positive, −1 if negative; mixed signs are an error.

    MSI attenuation is dB *below* the gain, normally written ``>= 0``; some
    vendors write every value ``<= 0``. A file with both signs is ambiguous (a
    lone negative value among positive ones is a typo or a gain *above* the
    stated peak): rejected at the first value of the minority sign.
    """
    pos = [w for w in written if w[0] > 0.0]
    neg = [w for w in written if w[0] < 0.0]
    if pos and neg:
        first_nonzero = next(w for w in written if w[0] != 0.0)
        majority_positive = len(pos) > len(neg) or (len(pos) == len(neg) and first_nonzero[0] > 0.0)
        value, line, cut = (neg if majority_positive else pos)[0]
        count, other = (len(pos), "positive") if majority_positive else (len(neg), "negative")
        raise InputError(
            f"attenuation {value:g} dB has the opposite sign of the file's {count} {other} "
            "values (dB below the gain: all >= 0, or all <= 0; mixed signs are ambiguous)",
            path=path,
            line=line,
            column=f"{cut} attenuation",
        )
    return -1.0 if neg else 1.0


def _check_cut(angles: FloatArray, path: Path, first_line: int, cut: str) -> None:
    """Angles of one cut (line ``first_line + k`` holds ``angles[k]``): a constant
    step from 0 covering ``[0, 360)``, each once; errors name the offending line."""
    n = angles.size
    step = 360.0 / n
    k = np.round(angles / step)
    off = np.nonzero(np.abs(angles - k * step) > 1e-6)[0]
    if off.size:
        j = int(off[0])
        raise InputError(
            f"angle {angles[j]:g} is not a multiple of {step:g} deg "
            f"({n} points must be a constant step from 0 covering [0, 360))",
            path=path,
            line=first_line + j,
            column=f"{cut} angle",
        )
    seen: dict[int, int] = {}
    for j, idx in enumerate(np.mod(k.astype(np.int64), n).tolist()):  # 359.9999999 is 0
        if idx in seen:
            raise InputError(
                f"duplicate angle {angles[j]:g} (first at line {first_line + seen[idx]})",
                path=path,
                line=first_line + j,
                column=f"{cut} angle",
            )
        seen[idx] = j


def _cut_at(angles: FloatArray, values: FloatArray, at_deg: FloatArray) -> FloatArray:
    order = np.argsort(angles)
    return np.interp(wrap_deg(at_deg), angles[order], values[order], period=360.0)


def read_msi(
    path: str | os.PathLike[str],
    *,
    mode: Literal["horizontal", "sphere"] = "horizontal",
    normalise: bool = False,
    name: str | None = None,
) -> Pattern:
    """Import an MSI/Planet antenna file.

    Conventions of the format (Planet / Radio Mobile documentation): a header
    (``NAME``, ``FREQUENCY`` MHz, ``GAIN`` — dBd unless followed by ``dBi``,
    ``TILT``, …) then ``HORIZONTAL 360`` and ``VERTICAL 360`` blocks of
    ``angle attenuation`` lines. Attenuations are dB *below the peak gain*,
    written positive; a file that writes every value ``<= 0`` is read by
    magnitude, and a file mixing both signs is rejected at the first value of
    the minority sign. The **horizontal** angle ``h`` is measured from the
    boresight, clockwise seen from above (a bearing); the **vertical** angle
    ``v`` from the front horizon, positive *downwards* (90 = nadir, 180 = back
    horizon, 270 = zenith) — a down-tilted antenna has its minimum at ``v = tilt``.

    Conversion (boresight = body ``+x``, up = body ``+z``)::

        phi   = (360 − h) mod 360                  horizontal cut, theta = 90
        theta = 90 + v       (front half-plane, phi = 0,   v in [0, 90])
        theta = 270 − v      (back half-plane,  phi = 180, v in [90, 270])
        theta = v − 270      (front half-plane, phi = 0,   v in [270, 360))
        directivity_dbi = G_dBi − attenuation_dB,   G_dBi = G_dBd + 2.15

    Parameters
    ----------
    path
        The ``.msi`` file.
    mode
        ``"horizontal"``: a slice pattern (``polar_deg = [90]``) from the
        horizontal cut alone. ``"sphere"``: a 1° full-sphere grid from both
        cuts by summing attenuations, as the 3GPP antenna model does
        (TR 36.814 / 38.901): ``A(phi, theta) = min(A_H(phi) + A_V(theta), A_max)``
        with ``A_V`` the *front* half of the vertical cut (``theta = 90 + v``)
        and ``A_max`` the largest attenuation in either cut; pole rows are set
        to their mean power. The front vertical cut is reproduced exactly
        (``A_H(0) = 0``), the horizontal cut on the cone of the vertical
        maximum (the tilt); the back half of the vertical cut is not used.
    normalise
        Rescale to mean intensity 0 dBi (radiopose directivity) instead of
        keeping the file's absolute gain.
    name
        Pattern name (default: file stem).

    Raises
    ------
    InputError
        Missing section or GAIN, bad number, angle out of range/duplicated/
        irregular, a data line outside a section, mixed attenuation signs —
        naming file, line and key.
    """
    p = Path(path)
    _, gain_dbi, h_ang, h_att, v_ang, v_att = _parse_msi(p)
    pname = name or _stem(p)
    az = np.arange(360, dtype=np.float64) * 1.0
    # pattern azimuth phi looks at horizontal angle h = 360 − phi
    a_h = _cut_at(h_ang, h_att, 360.0 - az)
    if mode == "horizontal":
        return _normalised(Pattern(pname, az, np.array([90.0]), gain_dbi - a_h), normalise)
    if mode != "sphere":
        raise ValueError(f"unknown MSI mode {mode!r}")
    theta = np.arange(181, dtype=np.float64) * 1.0
    # front vertical half-plane (phi = 0): theta = 90 + v (mod 360)
    a_v = _cut_at(v_ang, v_att, wrap_deg(theta + 270.0))  # (181,)
    # A(phi, theta) = min(A_H(phi) + A_V(theta), A_max)
    atten = np.minimum(a_h[:, None] + a_v[None, :], max(h_att.max(), v_att.max()))
    lin = db_to_linear(-atten)
    for j in (0, 180):  # each pole is one direction
        lin[:, j] = lin[:, j].mean()
    return _normalised(Pattern(pname, az, theta, gain_dbi + linear_to_db(lin)), normalise)


# ====================================================================== BASTA
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


# ====================================================================== MITLL
MITLL_CHANNELS = (37, 38, 39)
"""BLE advertising channels in the MIT LL captures."""


def _mitll_files(path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[Path]:
    if isinstance(path, (str, os.PathLike)):
        p = Path(path)
        if p.is_dir():
            files = sorted(p.glob("*.csv"))
            if not files:
                raise InputError("no *.csv files in directory", path=p)
            return files
        return [p]
    return [Path(f) for f in path]


def _read_mitll_file(path: Path) -> tuple[float, int, dict[str, dict[int, list[float]]]]:
    """(angle_deg, line of the Angle row, {mac: {channel: [rss_dbm, …]}}) of one capture."""
    angle: float | None = None
    angle_line = 0
    first_packet_line = 0
    packets: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    text = _read_text(path)
    reader = csv.reader(text.splitlines())
    for row in reader:
        line = reader.line_num
        if len(row) < 2:
            continue
        kind = row[1].strip()
        if kind == "Angle":
            if len(row) < 3:
                raise InputError("Angle row without a value", path=path, line=line, column="Angle")
            value = _finite(row[2].strip(), path, line, "Angle")
            if not 0.0 <= value <= 360.0:
                raise InputError(
                    f"angle {row[2].strip()} out of range [0, 360]",
                    path=path,
                    line=line,
                    column="Angle",
                )
            if angle is not None:
                raise InputError(
                    f"second 'Angle' row (the first, at line {angle_line}, says {angle:g})",
                    path=path,
                    line=line,
                    column="Angle",
                )
            angle, angle_line = value, line
        elif kind == "Bluetooth":
            first_packet_line = first_packet_line or line
            if len(row) < 7:
                raise InputError(
                    f"Bluetooth row has {len(row)} fields, expected 7", path=path, line=line
                )
            rss = _finite(row[3].strip(), path, line, "RSSI dBm", MAX_ABS_DB)
            if not -200.0 <= rss <= 60.0:
                raise InputError(
                    f"RSSI {row[3].strip()} dBm out of range [-200, 60]",
                    path=path,
                    line=line,
                    column="RSSI dBm",
                )
            ch_text = row[6].strip()
            if ch_text not in ("37", "38", "39"):
                raise InputError(
                    f"BLE channel {ch_text[:10]!r} not 37/38/39",
                    path=path,
                    line=line,
                    column="BLE channel",
                )
            packets[row[2].strip().lower()][int(ch_text)].append(rss)
    end_line = max(reader.line_num, 1)
    if angle is None:
        where = "before the first packet row" if first_packet_line else "in the file"
        raise InputError(
            f"no 'Angle' header row {where}",
            path=path,
            line=first_packet_line or end_line,
            column="Angle",
        )
    if not packets:
        raise InputError("no Bluetooth packet rows in the file", path=path, line=end_line)
    return angle, angle_line, packets


def read_mitll_measurements(
    path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    mac: str | None = None,
    remove_channel_means: bool = True,
) -> Measurements:
    """Read MIT LL PACT chamber captures as enrolment measurements.

    Format (``mitll/PACTTemplateDataset`` README): header rows
    ``timestamp,Environment|Device|Range|Angle|TxPower|GPS,value``; packet rows
    ``timestamp,Bluetooth,MAC,RSSI dBm,TxPower dBm,epoch s,BLE channel``.
    One file per positioner angle; the phone turns about one axis only.

    Conventions and choices (``docs/patterns.md``):

    * ``Angle`` is taken as the contract's motor azimuth (``phi = 360 − Angle``)
      and the cut as the plane of the screen (``theta = 90``): the dataset
      does not document how the phone sat on the mast.
    * One file per angle: two captures with the same ``Angle`` (``360`` is
      ``0``) are rejected, naming both files and lines — silently merging them
      would leave the other angle unmeasured and interpolated.
    * Packets: by default only the file's most frequent advertiser address is
      kept (the phone rotates its random address between files; a stray
      advertiser seen in one file is ignored). ``mac`` selects addresses
      explicitly (comma-separated).
    * Advertising channels: each channel's mean RSS differs by several dB
      (frequency response, chamber). Per (angle, channel) the packets are
      averaged in mW; then each channel's offset — the mW mean over all angles
      of that channel, in dB — is subtracted (``remove_channel_means``), so
      every channel contributes a slice of mean 0 dB, and the three channels
      are averaged in mW per angle by :func:`enrol` (one row per angle and
      channel, equal weight). Only channels heard at every angle are used.

    Returns
    -------
    Measurements
        One row per (angle, channel), elevation 90°, RSS relative to each
        channel's mean (dB) — absolute levels are not kept.

    Raises
    ------
    InputError
        Unreadable file, bad number (file, line, column), missing or repeated
        Angle (within a file or across files), no packets, or no channel heard
        at every angle.
    """
    files = _mitll_files(path)
    wanted = None if mac is None else {m.strip().lower() for m in mac.split(",") if m.strip()}
    per_angle: dict[float, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    seen: dict[float, tuple[Path, int]] = {}
    for f in files:
        angle, angle_line, packets = _read_mitll_file(f)
        key = float(wrap_deg(angle))
        if key in seen:
            other, other_line = seen[key]
            raise InputError(
                f"angle {angle:g} deg again: {other}:{other_line} has it too (one capture per "
                "angle; a repeated angle usually means another angle's file is mislabelled)",
                path=f,
                line=angle_line,
                column="Angle",
            )
        seen[key] = (f, angle_line)
        if wanted is None:
            counts = Counter(
                {m: sum(len(v) for v in chans.values()) for m, chans in packets.items()}
            )
            keep = {counts.most_common(1)[0][0]}
        else:
            keep = wanted & set(packets)
            if not keep:
                raise InputError(f"no packets from {mac}", path=f, column="MAC")
        for m in keep:
            for ch, rss in packets[m].items():
                per_angle[key][ch].extend(rss)
    angles = sorted(per_angle)
    channels = [c for c in MITLL_CHANNELS if all(c in per_angle[a] for a in angles)]
    if not channels:
        raise InputError("no BLE channel was heard at every angle", path=files[0])
    # mean power per (angle, channel), mW -> dBm: (n_angle, n_channel)
    level_dbm = np.array(
        [[float(mw_to_dbm(np.mean(dbm_to_mw(per_angle[a][c])))) for c in channels] for a in angles]
    )
    if remove_channel_means:
        offset_db = mw_to_dbm(np.mean(dbm_to_mw(level_dbm), axis=0))  # (n_channel,)
        level_dbm = level_dbm - offset_db[None, :]
    n_ch = len(channels)
    return Measurements(
        np.repeat(np.array(angles), n_ch),
        np.full(len(angles) * n_ch, 90.0),
        level_dbm.ravel(),
    )


def read_mitll(
    path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    config: EnrolConfig | None = None,
    *,
    mac: str | None = None,
    name: str | None = None,
) -> Pattern:
    """Enrol a slice pattern from MIT LL captures (see :func:`read_mitll_measurements`).

    The 8 azimuths 45° apart are filled by the enrolment's periodic
    interpolation (default: periodic cubic spline in dB), smoothed ±5° in mW and
    normalised to the slice mean (0 dBi).
    """
    measurements = read_mitll_measurements(path, mac=mac)
    if name is None:
        first = path if isinstance(path, (str, os.PathLike)) else path[0]
        name = Path(first).name if Path(first).is_dir() else _stem(first)
    return enrol(measurements, config, name=name)


__all__ = [
    "DBD_TO_DBI",
    "MITLL_CHANNELS",
    "read_basta_json",
    "read_mitll",
    "read_mitll_measurements",
    "read_msi",
]
