"""Request and response bodies of the live server's JSON API (pydantic v2).

The report body is the interchange contract's ("Live server"); every limit
is here so that a bad request is answered ``422`` with a one-line reason and
stores nothing:

* at most :data:`MAX_FRAMES_PER_BATCH` frames and :data:`MAX_BODY_BYTES` bytes;
* ``timestamp_s`` finite, ``0 <= t <= 9.2e9`` s (the receiver's own clock;
  stored as nanoseconds in a signed 64-bit integer, whose limit is 9.22e9 s);
* ``frame_sha256`` 64 hex digits, ``transmitter`` a transmitter id (1–64
  printable characters, no commas or whitespace: a MAC address or a name);
* ``rss_dbm`` finite;
* numbers are JSON numbers (``strict``: ``"12.5"`` or ``true`` is a 422, not
  converted), and no text holds a NUL or another control character.

The receiver id must also be known to the site (``422``, checked by the
endpoint). A frame of a transmitter that is not enrolled, or with an RSS
outside :data:`radiopose.capture.PLAUSIBLE_RSS_DBM`, is skipped and counted
in the answer (:class:`ReportAck`), as ``radiopose sync`` skips and counts it:
a sniffer reports every frame it hears, and one stranger must not cost the
batch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from radiopose.ids import receiver_id_problem, transmitter_id_problem

MAX_FRAMES_PER_BATCH = 5_000
MAX_BODY_BYTES = 2_000_000
MAX_CSV_BYTES = 20_000_000
MAX_TIMESTAMP_S = 9.2e9
"""Largest accepted ``timestamp_s``: below 2**63 ns, the database's integer limit."""


def _id_rule(problem_of: Callable[[str], str | None]) -> AfterValidator:
    """A pydantic validator raising ``problem_of``'s reason (a 422 naming the rule)."""

    def check(value: str) -> str:
        problem = problem_of(value)
        if problem is not None:
            raise ValueError(problem)
        return value

    return AfterValidator(check)


TransmitterId = Annotated[str, _id_rule(transmitter_id_problem)]
"""A transmitter id as every reader checks it (:func:`radiopose.ids.transmitter_id_problem`:
1–64 printable characters, no comma or whitespace); a 422 naming the rule."""

ReceiverId = Annotated[str, _id_rule(receiver_id_problem)]
"""A receiver id as every reader checks it (:func:`radiopose.ids.receiver_id_problem`:
the transmitter ids' rule); a 422 naming the rule."""

_Name = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[^\x00-\x1f\x7f]+$")]
_Angle = Annotated[float, Field(strict=True, ge=-360.0, le=360.0, allow_inf_nan=False)]
_Metres = Annotated[float, Field(strict=True, ge=-1e6, le=1e6, allow_inf_nan=False)]


class FrameReport(BaseModel):
    """One frame as a receiver heard it."""

    model_config = ConfigDict(frozen=True)

    timestamp_s: Annotated[
        float, Field(strict=True, ge=0.0, le=MAX_TIMESTAMP_S, allow_inf_nan=False)
    ]
    frame_sha256: Annotated[str, Field(pattern=r"^[0-9a-fA-F]{64}$")]
    transmitter: TransmitterId
    rss_dbm: Annotated[float, Field(strict=True, allow_inf_nan=False)]


class ReportBatch(BaseModel):
    """``POST /api/v1/reports``: a batch of one receiver's frame reports."""

    model_config = ConfigDict(frozen=True)

    receiver_id: ReceiverId
    batch_id: _Name
    frames: Annotated[list[FrameReport], Field(max_length=MAX_FRAMES_PER_BATCH)]


class ReportAck(BaseModel):
    """The answer to a stored (or already stored) batch: the frames stored, and
    those skipped because their transmitter is not enrolled or their RSS is
    outside :data:`radiopose.capture.PLAUSIBLE_RSS_DBM` (counted again for a
    batch sent again; nothing is stored then)."""

    batch_id: str
    frames_stored: int
    duplicate: bool
    frames_not_enrolled: int = 0
    frames_implausible_rss: int = 0


class Estimate(BaseModel):
    """One row of ``estimates.csv`` (the optional trailing columns only when set)."""

    timestamp_s: float
    transmitter: str
    packet_id: str
    x_m: float
    y_m: float
    z_m: float
    azimuth_deg: float
    pitch_deg: float
    roll_deg: float
    method: str
    position_std_m: float | None = None
    azimuth_std_deg: float | None = None


class ReceiverIn(BaseModel):
    """``PUT /api/v1/admin/receivers/{id}``: a receiver's pose and pattern."""

    model_config = ConfigDict(extra="forbid")

    x_m: _Metres
    y_m: _Metres
    z_m: _Metres
    azimuth_deg: _Angle = 0.0
    pitch_deg: Annotated[float, Field(strict=True, ge=-90.0, le=90.0, allow_inf_nan=False)] = 0.0
    roll_deg: _Angle = 0.0
    pattern: _Name


class ReceiverOut(ReceiverIn):
    receiver_id: str


class DeviceIn(BaseModel):
    """``PUT /api/v1/admin/devices/{transmitter}``: an enrolled device."""

    model_config = ConfigDict(extra="forbid")

    pattern: _Name
    tx_power_dbm: Annotated[float, Field(strict=True, ge=-100.0, le=60.0, allow_inf_nan=False)]


class DeviceOut(DeviceIn):
    transmitter: str


class CsvIn(BaseModel):
    """A CSV file's text (a pattern or the survey)."""

    model_config = ConfigDict(extra="forbid")

    csv: Annotated[str, Field(min_length=1, max_length=MAX_CSV_BYTES, pattern=r"^[^\x00]*$")]


class Area(BaseModel):
    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    z_m: float
    step_m: float


class SiteOut(BaseModel):
    """``GET /api/v1/site``: what the dashboard draws."""

    name: str
    version: int
    area: Area
    receivers: list[ReceiverOut]
    devices: list[DeviceOut]
    patterns: list[str]


class ReceiverHealth(BaseModel):
    receiver_id: str
    last_report_s: float | None
    seconds_since_report: float | None
    frames_per_s: float
    clock_offset_s: float | None
    clock_drift_ppm: float | None
    clock_method: str | None


class Health(BaseModel):
    """``GET /health``.

    ``batches_stored`` is the newest batch's id (ids count from 1: the number of
    batches stored on SQLite, an upper bound of it where a PostgreSQL sequence
    skipped ids); ``backlog_batches`` is that id minus the slowest partition's
    cursor (the same bound)."""

    status: str
    site_version: int
    pipeline_errors: dict[str, dict[str, object]] = {}
    batches_stored: int
    backlog_batches: int
    partitions: dict[str, dict[str, object]]
    receivers: list[ReceiverHealth]
    latency_s: dict[str, float | None]
