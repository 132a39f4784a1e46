"""MSI/Planet ``.msi``/``.pln`` antenna files: two 2-D cuts, combined into a 3-D pattern.

See :mod:`radiopose.patterns.importers` for the coordinate conventions.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Literal

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.importers._common import (
    DBD_TO_DBI,
    MAX_ABS_DB,
    MIN_CIRCLE_ANGLES,
    _finite,
    _in_file,
    _is_number,
    _normalised,
    _read_text,
    _require_angles,
    _stem,
)
from radiopose.patterns.pattern import Pattern, first_repeat
from radiopose.units import (
    FloatArray,
    db_to_linear,
    linear_to_db,
    wrap_deg,
)


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
        key, *more = raw.split(None, 1)  # the keyword, then any whitespace (spaces or tabs)
        rest = more[0] if more else ""
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
    for cut in ("HORIZONTAL", "VERTICAL"):
        _require_angles(
            cuts[cut][0],
            MIN_CIRCLE_ANGLES,
            cut,
            f"a cut needs at least {MIN_CIRCLE_ANGLES} around the circle",
            path,
            cuts_line[cut],
            cut,
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
    step from 0 covering ``[0, 360)``, each once; errors name the offending line.

    A repeated angle (equal to 1e-6 deg, 359.9999999 repeating 0) is reported
    as a duplicate before the step is checked: the repeat makes the count, and
    so the step the count implies, wrong.
    """
    n = angles.size

    def no_repeat(keys: np.ndarray) -> None:
        """The first angle whose ``key`` repeats an earlier one is a duplicate."""
        repeat = first_repeat(keys)
        if repeat is not None:
            j, first = repeat
            raise InputError(
                f"duplicate angle {angles[j]:g} (first at line {first_line + first})",
                path=path,
                line=first_line + j,
                column=f"{cut} angle",
            )

    no_repeat(np.mod(np.round(angles, 6), 360.0))
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
    no_repeat(np.mod(k.astype(np.int64), n))  # the grid index: 359.9999999 is 0


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
        irregular, a cut of fewer than :data:`MIN_CIRCLE_ANGLES` (3) angles, a
        data line outside a section, mixed attenuation signs — naming file,
        line and key.
    """
    p = Path(path)
    _, gain_dbi, h_ang, h_att, v_ang, v_att = _parse_msi(p)
    pname = name or _stem(p)
    az = np.arange(360, dtype=np.float64) * 1.0
    # pattern azimuth phi looks at horizontal angle h = 360 − phi
    a_h = _cut_at(h_ang, h_att, 360.0 - az)
    if mode == "horizontal":
        with _in_file(p):
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
    with _in_file(p):
        return _normalised(Pattern(pname, az, theta, gain_dbi + linear_to_db(lin)), normalise)
