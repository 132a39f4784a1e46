"""MIT LL PACT anechoic-chamber BLE captures (``btle_sniffer_*.csv``).

The captures are read into :class:`~radiopose.patterns.enrol.Measurements` and
enrolled with :func:`~radiopose.patterns.enrol.enrol`.
"""

from __future__ import annotations

import csv
import io
import os
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from radiopose.errors import InputError
from radiopose.patterns.enrol import CoverageGapError, EnrolConfig, Measurements, enrol
from radiopose.patterns.importers._common import (
    MAX_ABS_DB,
    MIN_CIRCLE_ANGLES,
    _finite,
    _read_text,
    _require_angles,
    _stem,
)
from radiopose.patterns.pattern import Pattern
from radiopose.units import (
    dbm_to_mw,
    mw_to_dbm,
    wrap_deg,
)

MITLL_CHANNELS = (37, 38, 39)
"""BLE advertising channels in the MIT LL captures."""

MITLL_HEADER_KINDS = ("Angle", "Device", "Environment", "GPS", "Range", "TxPower")
"""The header rows' kinds (second field); packet rows are ``Bluetooth``. Any
other row is an error: a row skipped silently would change the pattern."""


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
    # split on newlines only (str.splitlines also splits on U+2028, form feeds …,
    # which shifted every later line number); csv's field limit is an error here
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = iter(reader)
    while True:
        try:
            row = next(rows)
        except StopIteration:
            break
        except csv.Error as exc:
            raise InputError(f"not a CSV row: {exc}", path=path, line=reader.line_num) from None
        line = reader.line_num
        if not any(field.strip() for field in row):
            continue  # a blank line
        if len(row) < 2:
            raise InputError(
                f"not a capture row: one field {row[0].strip()[:40]!r} (a row is "
                "'timestamp,kind,…'; a line cut short?)",
                path=path,
                line=line,
            )
        kind = row[1].strip()
        if kind != "Bluetooth" and kind not in MITLL_HEADER_KINDS:
            raise InputError(
                f"unknown row kind {kind[:40]!r} (expected Bluetooth or one of "
                f"{', '.join(MITLL_HEADER_KINDS)})",
                path=path,
                line=line,
            )
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
        Angle (within a file or across files), fewer than
        :data:`~radiopose.patterns.importers._common.MIN_CIRCLE_ANGLES` (3)
        distinct angles, no packets, or no channel heard at every angle.
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
    # one file: its Angle row; several: the directory given (else the first file)
    at, at_line = seen[angles[0]] if len(files) == 1 else (files[0], None)
    if len(files) > 1 and isinstance(path, (str, os.PathLike)):
        at = Path(path)
    _require_angles(
        angles,
        MIN_CIRCLE_ANGLES,
        f"capture Angle in {len(files)} file{'' if len(files) == 1 else 's'}",
        f"a pattern needs at least {MIN_CIRCLE_ANGLES} around the circle (one file each)",
        at,
        at_line,
        "Angle",
    )
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
    normalised to the slice mean (0 dBi). Angles leaving a gap wider than
    :data:`~radiopose.patterns.enrol.MAX_FILL_GAP_DEG` (90°) are an error naming
    the directory (or first file) and column ``Angle``.
    """
    measurements = read_mitll_measurements(path, mac=mac)
    first = path if isinstance(path, (str, os.PathLike)) else path[0]
    if name is None:
        name = Path(first).name if Path(first).is_dir() else _stem(first)
    try:
        return enrol(measurements, config, name=name)
    except CoverageGapError as exc:  # the capture Angles are the motor azimuths
        raise exc.at(first, "Angle") from None
