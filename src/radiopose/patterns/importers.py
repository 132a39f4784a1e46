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
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.enrol import EnrolConfig, Measurements, enrol
from radiopose.patterns.pattern import Pattern
from radiopose.units import FloatArray, dbm_to_mw, linear_to_db, mw_to_dbm, wrap_deg

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


def _finite(text: str, path: Path, line: int | None, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"not a number: {text[:40]!r}", path=path, line=line, column=column
        ) from None
    if not math.isfinite(value):
        raise InputError(f"not a finite number: {text!r}", path=path, line=line, column=column)
    return value


def _normalised(pattern: Pattern, normalise: bool) -> Pattern:
    return pattern.normalised() if normalise else pattern


# ====================================================================== MSI
def _parse_gain_dbi(text: str, path: Path, line: int) -> float:
    parts = text.split()
    if not parts:
        raise InputError("empty GAIN", path=path, line=line, column="GAIN")
    value = _finite(parts[0], path, line, "GAIN")
    unit = parts[1].lower() if len(parts) > 1 else "dbd"
    if unit == "dbi":
        return value
    if unit == "dbd":
        return value + DBD_TO_DBI
    raise InputError(
        f"unknown gain unit {parts[1]!r} (dBi or dBd)", path=path, line=line, column="GAIN"
    )


def _parse_msi(
    path: Path,
) -> tuple[dict[str, str], float, FloatArray, FloatArray, FloatArray, FloatArray]:
    lines = _read_text(path).splitlines()
    header: dict[str, str] = {}
    gain_dbi: float | None = None
    cuts: dict[str, tuple[list[float], list[float]]] = {}
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
                if len(fields) < 2:
                    raise InputError(
                        "expected 'angle attenuation_dB'", path=path, line=ln, column=key_u
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
                # attenuation below the peak, written positive (some vendors: negative)
                atten.append(abs(_finite(fields[1], path, ln, f"{key_u} attenuation")))
            cuts[key_u] = (angles, atten)
            _check_cut(np.array(angles), path, lineno, key_u)
            i += n
            continue
        if key_u == "GAIN":
            gain_dbi = _parse_gain_dbi(rest, path, lineno)
        elif not header and not rest and key_u not in ("NAME",):
            header["NAME"] = raw  # a bare first line is the antenna name
            continue
        header[key_u] = rest.strip()
    for cut in ("HORIZONTAL", "VERTICAL"):
        if cut not in cuts:
            raise InputError(f"no {cut} section", path=path, column=cut)
    if gain_dbi is None:
        raise InputError("no GAIN line (dBd, or 'dBi' after the value)", path=path, column="GAIN")
    h_ang, h_att = (np.array(v) for v in cuts["HORIZONTAL"])
    v_ang, v_att = (np.array(v) for v in cuts["VERTICAL"])
    return header, gain_dbi, h_ang, h_att, v_ang, v_att


def _check_cut(angles: FloatArray, path: Path, line: int, cut: str) -> None:
    n = angles.size
    got = np.sort(angles)
    if np.any(np.diff(got) == 0):
        raise InputError("duplicate angle", path=path, line=line, column=cut)
    if not np.allclose(got, got[0] + np.arange(n) * 360.0 / n, atol=1e-6) or got[0] > 1e-6:
        raise InputError(
            f"angles must be a constant step from 0 covering [0, 360) ({n} points)",
            path=path,
            line=line,
            column=cut,
        )


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
    written positive. The **horizontal** angle ``h`` is measured from the
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
        irregular — naming file, line and key.
    """
    p = Path(path)
    _, gain_dbi, h_ang, h_att, v_ang, v_att = _parse_msi(p)
    pname = name or _stem(p)
    az = np.arange(360) * 1.0
    # pattern azimuth phi looks at horizontal angle h = 360 − phi
    a_h = _cut_at(h_ang, h_att, 360.0 - az)
    if mode == "horizontal":
        return _normalised(Pattern(pname, az, np.array([90.0]), gain_dbi - a_h), normalise)
    if mode != "sphere":
        raise ValueError(f"unknown MSI mode {mode!r}")
    theta = np.arange(181) * 1.0
    # front vertical half-plane (phi = 0): theta = 90 + v (mod 360)
    a_v = _cut_at(v_ang, v_att, wrap_deg(theta + 270.0))  # (181,)
    # A(phi, theta) = min(A_H(phi) + A_V(theta), A_max)
    atten = np.minimum(a_h[:, None] + a_v[None, :], max(h_att.max(), v_att.max()))
    lin = 10.0 ** (-atten / 10.0)
    for j in (0, 180):  # each pole is one direction
        lin[:, j] = lin[:, j].mean()
    return _normalised(Pattern(pname, az, theta, gain_dbi + linear_to_db(lin)), normalise)


# ====================================================================== BASTA
def _basta_key(data: dict[str, Any], key: str, path: Path) -> Any:
    if key not in data or data[key] is None:
        raise InputError("missing key", path=path, column=key)
    return data[key]


def _sampling(values: Any, key: str, path: Path) -> FloatArray:
    try:
        start, step, stop = (float(v) for v in values)
    except (TypeError, ValueError):
        raise InputError("expected [start, step, stop] numbers", path=path, column=key) from None
    if not (math.isfinite(start) and math.isfinite(step) and math.isfinite(stop)) or step <= 0:
        raise InputError("expected finite [start, step > 0, stop]", path=path, column=key)
    n = round((stop - start) / step)
    if n < 0 or abs(start + n * step - stop) > 1e-6:
        raise InputError("stop is not start + k·step", path=path, column=key)
    return start + np.arange(n + 1) * step


def _basta_to_polar(
    system: str, theta: FloatArray, phi: FloatArray, path: Path
) -> tuple[FloatArray, FloatArray]:
    if system == "SPCS_Polar":
        polar, az = theta, phi
    elif system == "SPCS_CW":
        polar, az = theta + 90.0, -phi
    elif system == "SPCS_CCW":
        polar, az = theta + 90.0, phi
    else:
        raise InputError(
            f"unsupported coordinate system {system!r} (SPCS_Polar, SPCS_CW, SPCS_CCW)",
            path=path,
            column="Coordinate_System",
        )
    return polar, wrap_deg(az)


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

    ``SPCS_Geo`` is rejected: its theta orientation is not pinned down by the
    schema and readers disagree.

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
        Bad JSON (with line), a missing/invalid key, a non-finite value, or a
        grid that is not a complete regular sphere — naming file and key.
    """
    p = Path(path)
    text = _read_text(p)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"invalid JSON: {exc.msg} (column {exc.colno})", path=p, line=exc.lineno
        ) from None
    if not isinstance(data, dict):
        raise InputError("expected a JSON object", path=p)
    system = str(_basta_key(data, "Coordinate_System", p))
    gain = _basta_key(data, "Gain", p)
    try:
        g_value = float(gain["value"])
        g_unit = str(gain["unit"])
    except (TypeError, KeyError, ValueError):
        raise InputError("expected {value: number, unit: dBi|dBd}", path=p, column="Gain") from None
    if not math.isfinite(g_value) or g_unit not in ("dBi", "dBd"):
        raise InputError("expected a finite value and unit dBi or dBd", path=p, column="Gain")
    gain_dbi = g_value + (DBD_TO_DBI if g_unit == "dBd" else 0.0)

    structure = _basta_key(data, "Data_Set_Row_Structure", p)
    if not isinstance(structure, list) or not all(isinstance(s, str) for s in structure):
        raise InputError("expected a list of names", path=p, column="Data_Set_Row_Structure")
    rows = _basta_key(data, "Data_Set", p)
    try:
        table = np.array(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            "rows must be lists of numbers of one length", path=p, column="Data_Set"
        ) from None
    if table.ndim != 2 or table.shape[1] != len(structure) or table.shape[0] == 0:
        raise InputError(
            f"expected rows of {len(structure)} numbers (Data_Set_Row_Structure)",
            path=p,
            column="Data_Set",
        )
    bad = np.nonzero(~np.isfinite(table).all(axis=1))[0]
    if bad.size:
        raise InputError(f"row {int(bad[0])} has NaN/inf", path=p, column="Data_Set")
    col = {s: table[:, k] for k, s in enumerate(structure)}

    if "Theta" in col and "Phi" in col:
        theta, phi = col["Theta"], col["Phi"]
    else:
        th = _sampling(_basta_key(data, "Theta_Sampling", p), "Theta_Sampling", p)
        ph = _sampling(_basta_key(data, "Phi_Sampling", p), "Phi_Sampling", p)
        if th.size * ph.size != table.shape[0]:
            raise InputError(
                f"{table.shape[0]} rows, sampling gives {th.size}×{ph.size}",
                path=p,
                column="Data_Set",
            )
        tt, pp = np.meshgrid(th, ph, indexing="ij")  # theta-major, phi fastest
        theta, phi = tt.ravel(), pp.ravel()

    if "MagAttenuationTP" in col:
        atten = col["MagAttenuationTP"]
    elif "MagAttenuationCo" in col:
        lin = 10.0 ** (-col["MagAttenuationCo"] / 10.0)
        if "MagAttenuationCr" in col:
            lin = lin + 10.0 ** (-col["MagAttenuationCr"] / 10.0)
        atten = -linear_to_db(lin)
    else:
        raise InputError(
            "no MagAttenuationTP or MagAttenuationCo column",
            path=p,
            column="Data_Set_Row_Structure",
        )

    polar, az = _basta_to_polar(system, theta, phi, p)
    polar = np.round(polar, _ROUND)
    az = np.round(az, _ROUND)
    az = np.where(az >= 360.0, 0.0, az)
    if polar.min() < 0.0 or polar.max() > 180.0:
        raise InputError(f"theta out of range for {system}", path=p, column="Data_Set")
    return _grid_pattern(name or _stem(p), az, polar, gain_dbi - atten, p, normalise)


def _grid_pattern(
    name: str, az: FloatArray, polar: FloatArray, value_dbi: FloatArray, path: Path, normalise: bool
) -> Pattern:
    az_u, a_idx = np.unique(az, return_inverse=True)
    po_u, p_idx = np.unique(polar, return_inverse=True)
    flat = a_idx.reshape(-1) * po_u.size + p_idx.reshape(-1)
    counts = np.bincount(flat, minlength=az_u.size * po_u.size)
    for bad, what in ((counts.max() > 1, "duplicate"), (counts.min() == 0, "missing")):
        if bad:
            k = int(np.argmax(counts) if what == "duplicate" else np.argmin(counts))
            az_k, po_k = az_u[k // po_u.size], po_u[k % po_u.size]
            raise InputError(
                f"{what} direction azimuth {az_k:g}, polar {po_k:g} deg",
                path=path,
                column="Data_Set",
            )
    grid = np.empty(az_u.size * po_u.size)
    grid[flat] = value_dbi
    try:
        pattern = Pattern(name, az_u, po_u, grid.reshape(az_u.size, po_u.size))
    except ValueError as exc:
        raise InputError(str(exc).split(": ", 1)[-1], path=path, column="Data_Set") from None
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


def _read_mitll_file(path: Path) -> tuple[float, dict[str, dict[int, list[float]]]]:
    """(angle_deg, {mac: {channel: [rss_dbm, …]}}) of one capture."""
    angle: float | None = None
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
            angle = _finite(row[2].strip(), path, line, "Angle")
            if not 0.0 <= angle <= 360.0:
                raise InputError(
                    f"angle {row[2].strip()} out of range [0, 360]",
                    path=path,
                    line=line,
                    column="Angle",
                )
        elif kind == "Bluetooth":
            if len(row) < 7:
                raise InputError(
                    f"Bluetooth row has {len(row)} fields, expected 7", path=path, line=line
                )
            rss = _finite(row[3].strip(), path, line, "RSSI dBm")
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
    if angle is None:
        raise InputError("no 'Angle' header row", path=path, column="Angle")
    if not packets:
        raise InputError("no Bluetooth packet rows", path=path)
    return angle, packets


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
        Unreadable file, bad number (file, line, column), missing Angle,
        no packets, or no channel heard at every angle.
    """
    files = _mitll_files(path)
    wanted = None if mac is None else {m.strip().lower() for m in mac.split(",") if m.strip()}
    per_angle: dict[float, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for f in files:
        angle, packets = _read_mitll_file(f)
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
                per_angle[float(wrap_deg(angle))][ch].extend(rss)
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
