"""The central server's tables: SQLAlchemy 2 ORM models and their migration.

One class per table (``*Row``), described in :mod:`radiopose.server.db`, which
holds the repository that reads and writes them. :func:`migrate` adds the
columns introduced after the first release to an existing database.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
    inspect,
    text,
)
from sqlalchemy.engine import Engine
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from radiopose.estimates import ESTIMATE_COLUMNS
from radiopose.ids import MAX_METHOD_NAME_CHARS

# SQLite only auto-increments an INTEGER PRIMARY KEY.
_BigId = BigInteger().with_variant(Integer, "sqlite")

# Output tables that clients follow by id (``after_id``): on SQLite, AUTOINCREMENT,
# so that an id is never used twice. Without it SQLite reuses the ids of deleted
# rows at the table's end, and output re-derived after a restart
# (:meth:`radiopose.server.db.Database.drop_output_from`) took ids a client had
# already read past. (PostgreSQL's sequences never reuse ids.)
_NEVER_REUSED: dict[str, Any] = {"sqlite_autoincrement": True}


class Base(DeclarativeBase):
    """Declarative base of all tables."""


class TokenRow(Base):
    __tablename__ = "tokens"
    id: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    receiver_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    created_s: Mapped[float] = mapped_column(Float)


class SiteMetaRow(Base):
    __tablename__ = "site_meta"
    key: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[str] = mapped_column(Text)


class SiteFileRow(Base):
    __tablename__ = "site_files"
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    text: Mapped[str] = mapped_column(Text)


class ReceiverRow(Base):
    __tablename__ = "receivers"
    receiver_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    z_m: Mapped[float] = mapped_column(Float)
    azimuth_deg: Mapped[float] = mapped_column(Float)
    pitch_deg: Mapped[float] = mapped_column(Float)
    roll_deg: Mapped[float] = mapped_column(Float)
    pattern: Mapped[str] = mapped_column(String(128))


class DeviceRow(Base):
    __tablename__ = "devices"
    transmitter: Mapped[str] = mapped_column(String(64), primary_key=True)
    pattern: Mapped[str] = mapped_column(String(128))
    tx_power_dbm: Mapped[float] = mapped_column(Float)


class PatternRow(Base):
    __tablename__ = "patterns"
    name: Mapped[str] = mapped_column(String(128), primary_key=True)
    csv: Mapped[str] = mapped_column(Text)


class BatchRow(Base):
    __tablename__ = "batches"
    __table_args__ = (
        UniqueConstraint("receiver_id", "batch_id"),
        # each receiver's latest report and a window's batches, by index (/health)
        Index("ix_batches_receiver_received", "receiver_id", "received_s"),
    )
    id: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    receiver_id: Mapped[str] = mapped_column(String(64), index=True)
    batch_id: Mapped[str] = mapped_column(String(128))
    received_s: Mapped[float] = mapped_column(Float, index=True)
    n_frames: Mapped[int] = mapped_column(Integer)


class FrameRow(Base):
    __tablename__ = "frames"
    seq: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    batch_pk: Mapped[int] = mapped_column(ForeignKey("batches.id"), index=True)
    receiver_id: Mapped[str] = mapped_column(String(64))
    timestamp_ns: Mapped[int] = mapped_column(BigInteger)
    frame_sha256: Mapped[str] = mapped_column(String(64))
    transmitter: Mapped[str] = mapped_column(String(64))
    rss_dbm: Mapped[float] = mapped_column(Float)


class PacketRow(Base):
    __tablename__ = "packets"
    __table_args__ = (UniqueConstraint("transmitter", "packet_id"), _NEVER_REUSED)
    id: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    packet_id: Mapped[str] = mapped_column(String(32))
    transmitter: Mapped[str] = mapped_column(String(64), index=True)
    timestamp_s: Mapped[float] = mapped_column(Float)
    receiver_ids: Mapped[list[str]] = mapped_column(JSON)
    rss_dbm: Mapped[list[float]] = mapped_column(JSON)
    reason: Mapped[str | None] = mapped_column(String(64), nullable=True)


class EstimateRow(Base):
    __tablename__ = "estimates"
    __table_args__ = (UniqueConstraint("transmitter", "packet_id"), _NEVER_REUSED)
    id: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    timestamp_s: Mapped[float] = mapped_column(Float, index=True)
    transmitter: Mapped[str] = mapped_column(String(64), index=True)
    packet_id: Mapped[str] = mapped_column(String(32))
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    z_m: Mapped[float] = mapped_column(Float)
    azimuth_deg: Mapped[float] = mapped_column(Float)
    pitch_deg: Mapped[float] = mapped_column(Float)
    roll_deg: Mapped[float] = mapped_column(Float)
    method: Mapped[str] = mapped_column(String(MAX_METHOD_NAME_CHARS))
    last_report_s: Mapped[float] = mapped_column(Float)
    estimated_s: Mapped[float] = mapped_column(Float)
    # optional uncertainty columns (added by migration to databases created before them)
    position_std_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    azimuth_std_deg: Mapped[float | None] = mapped_column(Float, nullable=True)


class AlarmRow(Base):
    """A spoofing alarm event (:mod:`radiopose.server.alarms`): raised or cleared."""

    __tablename__ = "alarms"
    __table_args__ = (_NEVER_REUSED,)
    id: Mapped[int] = mapped_column(_BigId, primary_key=True, autoincrement=True)
    transmitter: Mapped[str] = mapped_column(String(64), index=True)
    packet_id: Mapped[str] = mapped_column(String(32))
    timestamp_s: Mapped[float] = mapped_column(Float, index=True)
    state: Mapped[str] = mapped_column(String(16))
    score_nats: Mapped[float] = mapped_column(Float)
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    raised_s: Mapped[float] = mapped_column(Float)


class CheckpointRow(Base):
    __tablename__ = "checkpoints"
    partition: Mapped[str] = mapped_column(String(32), primary_key=True)
    cursor_batch: Mapped[int] = mapped_column(BigInteger)
    state: Mapped[bytes] = mapped_column(LargeBinary)
    summary: Mapped[dict[str, Any]] = mapped_column(JSON)
    updated_s: Mapped[float] = mapped_column(Float)


class SummaryRow(Base):
    """A partition's latest summary (``/health``), apart from its checkpoint: a
    database rewrites a whole row to update one column, and a lagged method's
    checkpoint row holds megabytes (its state), which its output-only commits,
    several a second, rewrote with every summary (a database from before this
    table gains it when opened; until its first commit ``/health`` reads the
    checkpoint row's summary)."""

    __tablename__ = "partition_summaries"
    partition: Mapped[str] = mapped_column(String(32), primary_key=True)
    summary: Mapped[dict[str, Any]] = mapped_column(JSON)
    updated_s: Mapped[float] = mapped_column(Float)


ESTIMATE_FIELDS = tuple(c.name for c in ESTIMATE_COLUMNS)
"""The ``estimates.csv`` columns, in contract order: the fields of an estimate row."""
ESTIMATE_STD_FIELDS = ("position_std_m", "azimuth_std_deg")
"""The optional trailing uncertainty columns of ``estimates.csv`` (``NULL`` where a
method gives none)."""
_ADDED_COLUMNS: tuple[tuple[str, str], ...] = tuple(
    ("estimates", name) for name in ESTIMATE_STD_FIELDS
)
"""Nullable columns added after the first release: :func:`migrate` adds them to
an existing database (old rows read ``NULL``)."""
_WIDENED_COLUMNS: tuple[tuple[str, str], ...] = (("frames", "transmitter"),)
"""Text columns made longer after the first release (``frames.transmitter``: 17
characters, a MAC address, before transmitter ids of up to 64): :func:`migrate`
widens them in an existing PostgreSQL database (SQLite does not enforce lengths)."""


_BATCH_INDEX = "ix_batches_receiver_received"


def _has_index(engine: Engine, table: str, name: str) -> bool:
    return name in {i["name"] for i in inspect(engine).get_indexes(table)}


def migrate(engine: Engine) -> None:
    """Add the nullable columns of :data:`_ADDED_COLUMNS` that an existing table lacks,
    the index of ``batches`` on ``(receiver_id, received_s)``, and widen the text
    columns of :data:`_WIDENED_COLUMNS` (PostgreSQL).

    Idempotent and safe to race: another process adding the same column first
    is not an error.
    """
    insp = inspect(engine)
    tables = set(insp.get_table_names())
    if "batches" in tables and not _has_index(engine, "batches", _BATCH_INDEX):
        # added after the first release (/health's lookups). Two processes opening an
        # older database at once may both create it: PostgreSQL's IF NOT EXISTS is
        # not safe under that race, so a failure with the index now there is fine.
        try:
            with engine.begin() as c:
                c.execute(
                    text(
                        f"CREATE INDEX IF NOT EXISTS {_BATCH_INDEX} "
                        "ON batches (receiver_id, received_s)"
                    )
                )
        except DBAPIError:
            if not _has_index(engine, "batches", _BATCH_INDEX):
                raise
    for table, column in _ADDED_COLUMNS:
        if table not in tables:
            continue
        if column in {c["name"] for c in insp.get_columns(table)}:
            continue
        kind = Base.metadata.tables[table].c[column].type.compile(dialect=engine.dialect)
        exists = "IF NOT EXISTS " if engine.dialect.name == "postgresql" else ""
        try:
            with engine.begin() as c:
                c.execute(text(f"ALTER TABLE {table} ADD COLUMN {exists}{column} {kind}"))
        except OperationalError as exc:  # SQLite: added meanwhile by another process
            if "duplicate column" not in str(exc.orig):
                raise
    if engine.dialect.name != "postgresql":
        return
    for table, column in _WIDENED_COLUMNS:
        if table not in tables:
            continue
        want = Base.metadata.tables[table].c[column].type
        have = next(c["type"] for c in insp.get_columns(table) if c["name"] == column)
        have_len, want_len = getattr(have, "length", None), getattr(want, "length", None)
        if have_len is not None and want_len is not None and have_len < want_len:
            kind = want.compile(dialect=engine.dialect)
            with engine.begin() as c:  # widening twice (a racing process) is harmless
                c.execute(text(f"ALTER TABLE {table} ALTER COLUMN {column} TYPE {kind}"))
