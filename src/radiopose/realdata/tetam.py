"""The public BLE tracking dataset ("tetam") in the interchange format.

The dataset (``../shared/data/ble-tetam``; a copy ships in
``radiopose/data/ble-tetam``, CC0) has four parts that radiopose reads:

``cnf/tetam.par``
    A JSON object; ``limits`` = ``[x_min, y_min, x_max, y_max]`` metres.
``cnf/tetam.dev``
    Lines ``Dongles:{json}`` (sensors: ``MAC: [[x, y, z], colour, alias]``) and
    ``Beacons:{json}`` (the beacon: ``MAC: [[], colour, alias]``).
``hst/*.hst``
    A site survey: ``Bins:[...]`` (dBm) and ``Fingerprints:{json}``, a histogram
    of RSSI per surveyed point ``"(x, y, z)"``, sensor and beacon.
``trk/*_all_sensors.mbd``
    Tracks: one line per reading, ``timestamp, sensor MAC, beacon MAC, RSSI,
    x, y, z, m00 … m22`` (camera ground truth of the beacon's position and a
    3×3 orientation matrix, row-major).

Decisions (measured in docs/real-data.md):

* **Readings → packets.** The beacon advertises about every 0.45 s; the
  sensors that hear an advertisement report it within ~12 ms. Readings
  closer than ``burst_gap_s`` (0.05 s) to the previous one form one packet
  (one advertisement); a sensor that reports twice in one burst (two
  advertising channels) gets the mean of its readings in dBm, counted in
  :attr:`ImportSummary.merged_readings`. The packet's time is its first
  reading's time (the dataset's Unix seconds, unchanged).
* **Implausible readings.** An RSSI outside [−127, 0] dBm (two readings of
  +42 and +29 dBm in ``straight_05``) is skipped and counted. A camera truth
  position (x, y) more than :data:`TRUTH_LIMITS_MARGIN_M` outside the
  ``tetam.par`` limits is an error naming file, line and column: it would
  become a wrong truth row and, in the other tracks' held-out sites, a survey
  point outside the room.
* **Histograms → survey.** Each histogram's mean RSSI (the ``Bins`` labels are
  bin *edges* when there is one more label than values, else bin centres) is
  one survey row; both survey sets are used; an all-zero histogram is skipped
  and counted.
* **Orientation.** The matrices' third column is a unit horizontal vector that
  follows the beacon (its forward direction), while the first two columns
  carry a shared scale factor that flips between +1 and −1 within seconds, so
  only the third column is used. The beacon's forward direction is taken as
  the body ``+y`` axis ("top of the device" in the contract), so
  ``azimuth_deg = atan2(-f_x, f_y)`` and ``pitch_deg = asin(f_z)`` for the
  forward vector ``f``; roll is not observable from one vector and is written
  as 0.
* **Site.** Area: the dataset's limits plus ``margin_m`` on every side (the
  camera truth leaves the limits by up to 0.33 m), snapped outward to
  ``step_m``; candidate height: the most common surveyed height; one
  candidate azimuth and an isotropic beacon pattern (the data carry no usable
  pattern, docs/real-data.md); the survey transmitter is the beacon itself,
  so survey power and device power are both 0 dBm and cancel; linear survey
  interpolation (leave-one-set-out on the survey: 3.98 dB RMS vs 4.07 dB
  for cubic).
"""

from __future__ import annotations

import ast
import json
import math
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radiopose.errors import InputError
from radiopose.units import FloatArray, wrap_deg

BEACON_PATTERN = "isotropic"
"""Pattern name of the beacon and the survey transmitter in the imported site."""
TRACK_SUFFIX = "_all_sensors.mbd"
RSSI_RANGE_DBM = (-127.0, 0.0)
"""Plausible BLE RSSI readings, dBm; readings outside are skipped and counted."""
TRUTH_LIMITS_MARGIN_M = 1.0
"""Farthest a track's camera truth (x, y) may lie outside the ``tetam.par`` limits,
metres; farther is an error (file, line, column). The real tracks leave the limits
by at most 0.33 m (``straight_03``; docs/real-data.md); a mistyped or corrupt
coordinate (18.031 written 1803.1) leaves them by metres."""


@dataclass(frozen=True)
class Sensor:
    """A fixed BLE sensor: its MAC (12 hex digits, as in the files), alias and position (m)."""

    mac: str
    alias: str
    position_m: tuple[float, float, float]


@dataclass(frozen=True)
class SurveyPoint:
    """The mean RSSI (dBm) a sensor measured of the beacon standing at ``position_m``."""

    position_m: tuple[float, float, float]
    sensor: str
    rss_dbm: float


@dataclass(frozen=True, eq=False)
class TrackReadings:
    """The readings of one track file, in time order.

    Attributes
    ----------
    name
        File name less ``_all_sensors.mbd``.
    timestamp_s, rss_dbm
        ``(n,)`` Unix seconds and dBm.
    sensor
        ``(n,)`` sensor aliases.
    position_m
        ``(n, 3)`` camera ground truth, metres.
    forward
        ``(n, 3)`` the orientation matrix's third column (the beacon's forward direction).
    """

    name: str
    timestamp_s: FloatArray
    sensor: np.ndarray
    rss_dbm: FloatArray
    position_m: FloatArray
    forward: FloatArray


@dataclass
class ImportSummary:
    """What the importer counted (skips are documented, never silent)."""

    survey_rows: int = 0
    empty_histograms: int = 0
    other_beacon_readings: int = 0
    implausible_rss: int = 0
    readings: int = 0
    merged_readings: int = 0
    reordered_readings: int = 0
    packets: dict[str, int] = field(default_factory=dict)

    def lines(self) -> list[str]:
        out = [
            f"survey: {self.survey_rows} rows ({self.empty_histograms} empty histograms skipped)",
            f"tracks: {len(self.packets)}, {self.readings} readings -> "
            f"{sum(self.packets.values())} packets ({self.merged_readings} repeated readings of a "
            f"sensor in one burst averaged, {self.reordered_readings} out-of-order readings "
            f"sorted, {self.other_beacon_readings} readings of other beacons and "
            f"{self.implausible_rss} with RSSI outside [-127, 0] dBm skipped)",
        ]
        out += [f"  {name}: {n} packets" for name, n in self.packets.items()]
        return out


# ----------------------------------------------------------------------------- parsing
def _read_lines(path: Path) -> list[str]:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    try:
        return raw.decode("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError("not UTF-8 text", path=path, line=line) from None


def _number(text: str, path: Path, line: int, column: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise InputError(
            f"not a number: {text.strip()!r:.40}", path=path, line=line, column=column
        ) from None
    if not math.isfinite(x):
        raise InputError(
            f"not a finite number: {text.strip()!r:.40}", path=path, line=line, column=column
        )
    return x


def _mac(text: str, path: Path, line: int, column: str) -> str:
    s = text.strip().lower()
    if len(s) != 12 or any(c not in "0123456789abcdef" for c in s):
        raise InputError(
            f"not a 12-hex-digit MAC: {text.strip()!r:.40}", path=path, line=line, column=column
        )
    return s


def read_limits(path: str | os.PathLike[str]) -> tuple[float, float, float, float]:
    """``(x_min, y_min, x_max, y_max)`` in metres from ``tetam.par``."""
    p = Path(path)
    text = "\n".join(_read_lines(p))
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"not JSON ({exc.msg})", path=p, line=exc.lineno) from None
    lim = data.get("limits") if isinstance(data, dict) else None
    if not (isinstance(lim, list) and len(lim) == 4):
        raise InputError(
            "expected 'limits': [x_min, y_min, x_max, y_max]", path=p, line=1, column="limits"
        )
    x0, y0, x1, y1 = (_number(str(v), p, 1, "limits") for v in lim)
    if not (x1 > x0 and y1 > y0):
        raise InputError(f"limits {lim} are empty", path=p, line=1, column="limits")
    return x0, y0, x1, y1


def _json_line(line: str, key: str, path: Path, lineno: int) -> dict:
    try:
        data = json.loads(line[len(key) + 1 :])
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{key}: not JSON ({exc.msg})", path=path, line=lineno, column=key
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"{key}: expected a JSON object", path=path, line=lineno, column=key)
    return data


def read_devices(path: str | os.PathLike[str]) -> tuple[tuple[Sensor, ...], str]:
    """Sensors (in file order) and the beacon's MAC from ``tetam.dev``."""
    p = Path(path)
    sensors: list[Sensor] = []
    beacons: list[str] = []
    for i, line in enumerate(_read_lines(p), start=1):
        if line.startswith("Dongles:"):
            for mac, value in _json_line(line, "Dongles", p, i).items():
                ok = (
                    isinstance(value, list)
                    and len(value) == 3
                    and isinstance(value[0], list)
                    and len(value[0]) == 3
                    and isinstance(value[2], str)
                )
                if not ok:
                    raise InputError(
                        f"sensor {mac}: expected [[x, y, z], colour, alias]",
                        path=p,
                        line=i,
                        column="Dongles",
                    )
                xyz = tuple(_number(str(v), p, i, "Dongles") for v in value[0])
                sensors.append(Sensor(_mac(mac, p, i, "Dongles"), value[2], xyz))  # type: ignore[arg-type]
        elif line.startswith("Beacons:"):
            beacons += [_mac(m, p, i, "Beacons") for m in _json_line(line, "Beacons", p, i)]
        elif line.strip():
            raise InputError("expected a line starting 'Dongles:' or 'Beacons:'", path=p, line=i)
    if not sensors:
        raise InputError("no sensors (no 'Dongles:' line)", path=p)
    if len(beacons) != 1:
        raise InputError(f"expected one beacon, found {len(beacons)}", path=p, column="Beacons")
    aliases = Counter(s.alias for s in sensors)
    dup = [a for a, n in aliases.items() if n > 1]
    if dup or len({s.mac for s in sensors}) != len(sensors):
        raise InputError(f"sensor aliases or MACs repeat ({', '.join(dup) or 'MAC'})", path=p)
    return tuple(sensors), beacons[0]


def read_histograms(
    path: str | os.PathLike[str], sensors: tuple[Sensor, ...], beacon: str, summary: ImportSummary
) -> list[SurveyPoint]:
    """Mean RSSI per surveyed point and sensor from one ``.hst`` file (the beacon only)."""
    p = Path(path)
    by_mac = {s.mac: s.alias for s in sensors}
    labels: np.ndarray | None = None
    out: list[SurveyPoint] = []
    fingerprints = False
    for i, line in enumerate(_read_lines(p), start=1):
        if line.startswith("Bins:"):
            try:
                labels = np.asarray(json.loads(line[5:]), dtype=np.float64)
            except (json.JSONDecodeError, TypeError, ValueError):
                raise InputError(
                    "Bins: expected a JSON list of numbers", path=p, line=i, column="Bins"
                ) from None
            if labels.ndim != 1 or labels.size < 2 or not np.all(np.isfinite(labels)):
                raise InputError(
                    "Bins: expected a list of finite numbers", path=p, line=i, column="Bins"
                )
            if np.any(np.diff(labels) <= 0):
                raise InputError("Bins: labels must increase", path=p, line=i, column="Bins")
        elif line.startswith("Fingerprints:"):
            if labels is None:
                raise InputError("Fingerprints before Bins", path=p, line=i, column="Fingerprints")
            fingerprints = True
            for key, per_sensor in _json_line(line, "Fingerprints", p, i).items():
                try:
                    xyz = ast.literal_eval(key)
                    xyz = tuple(float(v) for v in xyz)
                except (ValueError, SyntaxError, TypeError):
                    xyz = ()
                if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
                    raise InputError(
                        f"point {key!r:.40} is not '(x, y, z)'",
                        path=p,
                        line=i,
                        column="Fingerprints",
                    )
                if not isinstance(per_sensor, dict):
                    raise InputError(
                        f"point {key}: expected an object", path=p, line=i, column="Fingerprints"
                    )
                for mac, per_beacon in per_sensor.items():
                    m = _mac(mac, p, i, "Fingerprints")
                    if m not in by_mac:
                        raise InputError(
                            f"point {key}: unknown sensor {mac}",
                            path=p,
                            line=i,
                            column="Fingerprints",
                        )
                    if not isinstance(per_beacon, dict):
                        raise InputError(
                            f"point {key}, sensor {mac}: expected an object",
                            path=p,
                            line=i,
                            column="Fingerprints",
                        )
                    for b, hist in per_beacon.items():
                        if _mac(b, p, i, "Fingerprints") != beacon:
                            continue
                        mean = _histogram_mean(hist, labels, f"point {key}, sensor {mac}", p, i)
                        if mean is None:
                            summary.empty_histograms += 1
                            continue
                        out.append(SurveyPoint(xyz, by_mac[m], mean))
        elif line.startswith(("Dongles:", "Beacons:")) or not line.strip():
            continue
        else:
            raise InputError(
                "expected a line starting 'Bins:', 'Dongles:', 'Beacons:' or 'Fingerprints:'",
                path=p,
                line=i,
            )
    if not fingerprints:  # an empty or cut file would drop its whole survey unseen
        raise InputError("no 'Fingerprints:' line (an empty or truncated survey file?)", path=p)
    summary.survey_rows += len(out)
    return out


def _histogram_mean(
    hist: object, labels: np.ndarray, what: str, path: Path, line: int
) -> float | None:
    """Mean dBm of a histogram over ``labels`` (edges if one more than values); None if empty."""
    try:
        h = np.asarray(hist, dtype=np.float64)
    except (TypeError, ValueError):
        h = np.empty(0)
    if h.ndim != 1 or h.size == 0 or not np.all(np.isfinite(h)) or np.any(h < 0):
        raise InputError(
            f"{what}: expected a list of non-negative numbers",
            path=path,
            line=line,
            column="Fingerprints",
        )
    if h.size == labels.size:
        centres = labels
    elif h.size == labels.size - 1:
        centres = 0.5 * (labels[:-1] + labels[1:])
    else:
        raise InputError(
            f"{what}: {h.size} values for {labels.size} Bins labels",
            path=path,
            line=line,
            column="Fingerprints",
        )
    total = float(h.sum())
    return None if total <= 0 else float((h * centres).sum() / total)


_MBD_FIELDS = 16


def read_track(
    path: str | os.PathLike[str],
    sensors: tuple[Sensor, ...],
    beacon: str,
    summary: ImportSummary,
    limits_m: tuple[float, float, float, float] | None = None,
) -> TrackReadings:
    """The beacon's readings of one ``*_all_sensors.mbd`` file (sorted by time).

    ``limits_m`` (``x_min, y_min, x_max, y_max`` metres, :func:`read_limits`):
    a truth position farther than :data:`TRUTH_LIMITS_MARGIN_M` outside them is
    an error naming the line and column (``x`` or ``y``); ``None`` checks nothing.
    """
    p = Path(path)
    by_mac = {s.mac: s.alias for s in sensors}
    rows: list[tuple] = []
    for i, line in enumerate(_read_lines(p), start=1):
        if not line.strip():
            continue
        f = line.split(",")
        if len(f) != _MBD_FIELDS:
            raise InputError(
                f"expected {_MBD_FIELDS} comma-separated fields (timestamp, sensor, beacon, RSSI, "
                f"x, y, z, 9 matrix values), got {len(f)}",
                path=p,
                line=i,
            )
        if _mac(f[2], p, i, "beacon") != beacon:
            summary.other_beacon_readings += 1
            continue
        mac = _mac(f[1], p, i, "sensor")
        if mac not in by_mac:
            raise InputError(
                f"sensor {f[1].strip()} is not in tetam.dev", path=p, line=i, column="sensor"
            )
        t = _number(f[0], p, i, "timestamp")
        if not 0 <= t < 9.2e9:
            raise InputError(f"timestamp {t:g} s out of range", path=p, line=i, column="timestamp")
        rss = _number(f[3], p, i, "RSSI")
        if not RSSI_RANGE_DBM[0] <= rss <= RSSI_RANGE_DBM[1]:
            summary.implausible_rss += 1  # e.g. two readings of +42 and +29 dBm in straight_05
            continue
        xyz = [_number(v, p, i, c) for v, c in zip(f[4:7], "xyz", strict=True)]
        if limits_m is not None:
            _check_in_room(xyz, limits_m, p, i)
        m = [_number(v, p, i, "orientation") for v in f[7:16]]
        fwd = (m[2], m[5], m[8])  # third column of the row-major matrix
        if not 0.5 <= math.hypot(*fwd) <= 1.5:
            raise InputError(
                f"orientation's third column has length {math.hypot(*fwd):.3g} (expected ~1)",
                path=p,
                line=i,
                column="orientation",
            )
        rows.append((t, by_mac[mac], rss, *xyz, *fwd))
    if not rows:
        raise InputError("no readings of the beacon", path=p)
    t_s = np.array([r[0] for r in rows])
    order = np.argsort(t_s, kind="stable")
    summary.reordered_readings += int(np.count_nonzero(order != np.arange(t_s.size)))
    summary.readings += t_s.size
    name = p.name[: -len(TRACK_SUFFIX)] if p.name.endswith(TRACK_SUFFIX) else p.stem
    num = np.array([[r[0], r[2], *r[3:]] for r in rows], dtype=np.float64)[order]
    forward = num[:, 5:8]
    forward = forward / np.linalg.norm(forward, axis=1, keepdims=True)
    return TrackReadings(
        name,
        num[:, 0],
        np.array([r[1] for r in rows], dtype=object)[order],
        num[:, 1],
        num[:, 2:5],
        forward,
    )


def _check_in_room(
    xyz: list[float], limits_m: tuple[float, float, float, float], path: Path, line: int
) -> None:
    """Raise if ``x`` or ``y`` (metres) lies more than :data:`TRUTH_LIMITS_MARGIN_M`
    outside the limits ``(x_min, y_min, x_max, y_max)`` metres."""
    for k, axis in enumerate("xy"):
        lo, hi = limits_m[k], limits_m[k + 2]
        out_m = max(lo - xyz[k], xyz[k] - hi)
        if out_m > TRUTH_LIMITS_MARGIN_M:
            raise InputError(
                f"truth {axis} = {xyz[k]:g} m lies {out_m:.2f} m outside the room "
                f"(tetam.par limits {lo:.3f}–{hi:.3f} m; at most "
                f"{TRUTH_LIMITS_MARGIN_M:g} m allowed)",
                path=path,
                line=line,
                column=axis,
            )


# ----------------------------------------------------------------------------- packets
@dataclass(frozen=True, eq=False)
class TrackPackets:
    """One track as packets and truth (rows of packets.csv and truth.csv).

    ``packet_*`` arrays have one entry per (packet, sensor); ``truth_*`` one per packet.
    """

    name: str
    packet_id: np.ndarray
    packet_time_s: FloatArray
    receiver_id: np.ndarray
    rss_dbm: FloatArray
    truth_time_s: FloatArray
    truth_position_m: FloatArray
    truth_orientation_deg: FloatArray


def forward_to_orientation_deg(forward: FloatArray) -> FloatArray:
    """``(n, 3)`` (azimuth, pitch, roll) degrees of a beacon whose body ``+y`` points along
    ``forward`` ``(n, 3)`` (unit vectors): ``R e_y = (-sin a cos p, cos a cos p, sin p)``;
    roll is not observable from one vector and is 0."""
    f = np.asarray(forward, dtype=np.float64).reshape(-1, 3)
    az = wrap_deg(np.degrees(np.arctan2(-f[:, 0], f[:, 1])))
    pitch = np.degrees(np.arcsin(np.clip(f[:, 2], -1.0, 1.0)))
    return np.column_stack([az, pitch, np.zeros(len(f))])


def track_packets(track: TrackReadings, burst_gap_s: float, summary: ImportSummary) -> TrackPackets:
    """Group a track's readings into advertisements (see the module docstring)."""
    t = track.timestamp_s
    starts = np.flatnonzero(np.concatenate([[True], np.diff(t) > burst_gap_s]))
    group = np.cumsum(np.isin(np.arange(t.size), starts)) - 1
    ids, times, rx, rss = [], [], [], []
    for g, s in enumerate(starts):
        members = np.flatnonzero(group == g)
        by_sensor: dict[str, list[float]] = {}
        for k in members:
            by_sensor.setdefault(str(track.sensor[k]), []).append(float(track.rss_dbm[k]))
        for sensor, values in by_sensor.items():
            summary.merged_readings += len(values) - 1
            ids.append(str(g + 1))
            times.append(float(t[s]))
            rx.append(sensor)
            rss.append(float(np.mean(values)))
    summary.packets[track.name] = int(starts.size)
    return TrackPackets(
        track.name,
        np.array(ids, dtype=object),
        np.array(times),
        np.array(rx, dtype=object),
        np.array(rss),
        t[starts].copy(),
        track.position_m[starts].copy(),
        forward_to_orientation_deg(track.forward[starts]),
    )


# ----------------------------------------------------------------------------- dataset
@dataclass(frozen=True, eq=False)
class TetamDataset:
    """Everything radiopose reads from the dataset directory."""

    root: Path
    limits_m: tuple[float, float, float, float]
    sensors: tuple[Sensor, ...]
    beacon: str
    survey: tuple[SurveyPoint, ...]
    tracks: tuple[TrackReadings, ...]
    summary: ImportSummary

    @property
    def beacon_id(self) -> str:
        """The beacon as a transmitter id (colon-separated lower-case MAC)."""
        return ":".join(self.beacon[i : i + 2] for i in range(0, 12, 2))

    def track(self, name: str) -> TrackReadings:
        for tr in self.tracks:
            if tr.name == name:
                return tr
        raise InputError(f"no track {name!r} (tracks: {', '.join(t.name for t in self.tracks)})")


def read_dataset(root: str | os.PathLike[str]) -> TetamDataset:
    """Read and validate the dataset directory (``cnf/``, ``hst/``, ``trk/``)."""
    r = Path(root)
    if not r.is_dir():
        raise InputError("not a directory (expected the dataset with cnf/, hst/, trk/)", path=r)
    summary = ImportSummary()
    limits = read_limits(r / "cnf" / "tetam.par")
    sensors, beacon = read_devices(r / "cnf" / "tetam.dev")
    hst = sorted((r / "hst").glob("*.hst"))
    if not hst:
        raise InputError("no survey files (hst/*.hst)", path=r / "hst")
    survey = [pt for f in hst for pt in read_histograms(f, sensors, beacon, summary)]
    trk = sorted((r / "trk").glob(f"*{TRACK_SUFFIX}"))
    if not trk:
        raise InputError(f"no track files (trk/*{TRACK_SUFFIX})", path=r / "trk")
    tracks = tuple(read_track(f, sensors, beacon, summary, limits) for f in trk)
    return TetamDataset(r, limits, sensors, beacon, tuple(survey), tracks, summary)


def shipped_dataset_dir() -> Path:
    """The copy of the dataset inside the package (``radiopose/data/ble-tetam``)."""
    return Path(__file__).resolve().parent.parent / "data" / "ble-tetam"
