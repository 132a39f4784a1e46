"""The central server's database: one repository class over the SQLAlchemy tables.

Everything the server knows lives here, so that any number of server
processes can share one database (see ``docs/server.md``, "Beyond one
machine"):

* **site** — ``site_files`` (``site.toml``, ``survey.csv`` as text),
  ``receivers``, ``devices``, ``patterns`` (pattern CSV text) and
  ``site_meta`` (a version counter bumped on every change, the hash of the
  last imported directory);
* **tokens** — SHA-256 of each bearer token with its role;
* **raw reports** — ``batches`` and ``frames``, append-only: a batch is stored
  whole in one transaction together with its frames, keyed by
  ``(receiver_id, batch_id)`` so a resend stores nothing new;
* **live output** — ``packets`` (synchronised packets), ``estimates``,
  ``alarms``, ``checkpoints`` (the pickled pipeline state of each
  partition) and ``partition_summaries`` (each partition's latest summary,
  kept apart: updating one column rewrites a whole row, state included).
  Outputs are inserted idempotently (a packet, estimate or alarm
  already stored is kept, not stored twice), so that a pipeline resumed from
  an older checkpoint, or a new partitioning re-processing the stored frames,
  re-derives them without error or duplicate: exactly-once after a crash.

The tables (ORM models) and their migration are in :mod:`radiopose.server.models`;
this module is the repository over them and the engine set-up.

SQLite (default) runs in WAL mode with ``synchronous=FULL`` and writes in
``BEGIN IMMEDIATE`` transactions; PostgreSQL takes a transaction-level
advisory lock while storing a batch so that batch ids become visible in id
order (the pipeline reads batches by increasing id and must never skip one).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from sqlalchemy import (
    create_engine,
    delete,
    event,
    func,
    insert,
    select,
    text,
    tuple_,
    update,
)
from sqlalchemy.engine import Engine
from sqlalchemy.exc import (
    ArgumentError,
    DatabaseError,
    IntegrityError,
    NoSuchModuleError,
)
from sqlalchemy.orm import Session

from radiopose.errors import InputError
from radiopose.server.models import (
    ESTIMATE_FIELDS,
    ESTIMATE_STD_FIELDS,
    AlarmRow,
    Base,
    BatchRow,
    CheckpointRow,
    DeviceRow,
    EstimateRow,
    FrameRow,
    PacketRow,
    PatternRow,
    ReceiverRow,
    SiteFileRow,
    SiteMetaRow,
    SummaryRow,
    TokenRow,
    migrate,
)

_PG_BATCH_LOCK = 7_346_201  # advisory lock key serialising batch inserts


@dataclass(frozen=True)
class StoredBatch:
    """A batch read back for processing: its key, arrival and frame columns."""

    id: int
    receiver_id: str
    received_s: float
    timestamp_ns: tuple[int, ...]
    frame_sha256: tuple[str, ...]
    transmitter: tuple[str, ...]
    rss_dbm: tuple[float, ...]


def default_sqlite_url(path: str = "radiopose.db") -> str:
    """SQLAlchemy URL of a SQLite file."""
    return f"sqlite:///{path}"


class Database:
    """Repository over one SQLAlchemy engine (thread-safe; no module-level state).

    Parameters
    ----------
    url
        Any SQLAlchemy URL; ``sqlite:///FILE`` or ``postgresql+psycopg://...``
        (``postgresql://`` is taken to mean psycopg 3).
    create
        Create missing tables.

    Raises
    ------
    InputError
        Unusable URL or unreachable database (one line).
    """

    def __init__(self, url: str, *, create: bool = True) -> None:
        if url.startswith("postgresql://") or url.startswith("postgres://"):
            url = "postgresql+psycopg://" + url.split("://", 1)[1]
        self.url = url
        try:
            self.engine, self._read_engine = _make_engines(url)
            self.dialect = self.engine.dialect.name
            if create:
                Base.metadata.create_all(self.engine)
            migrate(self.engine)
        except (ArgumentError, NoSuchModuleError) as exc:
            raise InputError(f"--db {url!r}: not a usable database URL ({exc})") from None
        except DatabaseError as exc:  # unreachable, not a database, corrupt, …
            reason = " ".join(str(exc.orig).split())[:200]
            raise InputError(f"--db {url!r}: cannot open the database: {reason}") from None
        self._write_lock = threading.Lock()

    def check_writable(self) -> None:
        """Raise :class:`InputError` (one line) unless this process can write
        to the database: a read-only SQLite file (or a role without write
        rights) would otherwise be found only at the first stored report."""
        try:
            with self.engine.connect() as c:
                tx = c.begin()
                try:
                    c.execute(delete(SiteMetaRow).where(SiteMetaRow.key == "__write_probe__"))
                finally:
                    tx.rollback()
        except DatabaseError as exc:
            reason = " ".join(str(exc.orig).split())[:200]
            raise InputError(f"--db {self.url!r}: cannot write to the database: {reason}") from None

    def close(self) -> None:
        """Release all connections."""
        self.engine.dispose()
        self._read_engine.dispose()

    # ------------------------------------------------------------------ sessions
    @contextmanager
    def read(self) -> Iterator[Session]:
        """A session for reading (no commit)."""
        with Session(self._read_engine) as s:
            yield s

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A write transaction, committed on success (serialised within the process)."""
        with self._write_lock, Session(self.engine) as s, s.begin():
            yield s

    # ------------------------------------------------------------------ tokens
    def add_token(self, token_sha256: str, role: str, receiver_id: str | None) -> None:
        with self.write() as s:
            s.add(
                TokenRow(
                    token_sha256=token_sha256,
                    role=role,
                    receiver_id=receiver_id,
                    created_s=time.time(),
                )
            )

    def find_token(self, token_sha256: str) -> tuple[str, str | None] | None:
        """``(role, receiver_id)`` of a token hash, or ``None``."""
        with self.read() as s:
            row = s.execute(
                select(TokenRow.role, TokenRow.receiver_id).where(
                    TokenRow.token_sha256 == token_sha256
                )
            ).first()
        return None if row is None else (row[0], row[1])

    # ------------------------------------------------------------------ site
    def meta(self, key: str, default: str | None = None) -> str | None:
        with self.read() as s:
            row = s.get(SiteMetaRow, key)
            return default if row is None else row.value

    def note_pipeline_error(self, partition: str, message: str) -> None:
        """Record that ``partition``'s live pipeline failed a step (``/health``
        reports it until the partition commits again)."""
        import json

        value = json.dumps({"at_s": time.time(), "message": message[:500]})
        with self.write() as s:
            s.merge(SiteMetaRow(key=f"pipeline_error:{partition}", value=value))

    def pipeline_errors(self) -> dict[str, dict[str, Any]]:
        """The last recorded failure of each partition: ``{"at_s", "message"}``."""
        import json

        with self.read() as s:
            rows = s.scalars(
                select(SiteMetaRow).where(SiteMetaRow.key.startswith("pipeline_error:"))
            ).all()
            return {r.key.split(":", 1)[1]: json.loads(r.value) for r in rows}

    def site_version(self) -> int:
        return int(self.meta("site_version", "0") or 0)

    def known_ids(self) -> tuple[list[str], list[str]]:
        """Receiver ids (site order) and enrolled transmitter addresses."""
        order = [r for r in (self.meta("receiver_order", "") or "").split(",") if r]
        with self.read() as s:
            rx = list(s.scalars(select(ReceiverRow.receiver_id)))
            tx = list(s.scalars(select(DeviceRow.transmitter)))
        rank = {r: i for i, r in enumerate(order)}
        return sorted(rx, key=lambda r: (rank.get(r, len(rank)), r)), tx

    def site_rows(self) -> dict[str, Any]:
        """Everything of the site as plain values (see :mod:`radiopose.server.sitestore`)."""
        with self.read() as s:
            return {
                "files": {r.name: r.text for r in s.scalars(select(SiteFileRow))},
                "receivers": [
                    _row_dict(r, ReceiverRow)
                    for r in s.scalars(select(ReceiverRow).order_by(ReceiverRow.receiver_id))
                ],
                "devices": [
                    _row_dict(r, DeviceRow)
                    for r in s.scalars(select(DeviceRow).order_by(DeviceRow.transmitter))
                ],
                "patterns": {r.name: r.csv for r in s.scalars(select(PatternRow))},
                "order": self.meta("receiver_order", "") or "",
            }

    def replace_site(self, parts: dict[str, Any], *, source_hash: str | None = None) -> int:
        """Replace the whole site with ``parts`` (same shape as :meth:`site_rows`); new version."""
        with self.write() as s:
            for model in (SiteFileRow, ReceiverRow, DeviceRow, PatternRow):
                s.execute(delete(model))
            for name, txt in parts["files"].items():
                s.add(SiteFileRow(name=name, text=txt))
            for r in parts["receivers"]:
                s.add(ReceiverRow(**r))
            for d in parts["devices"]:
                s.add(DeviceRow(**d))
            for name, csv in parts["patterns"].items():
                s.add(PatternRow(name=name, csv=csv))
            version = _bump_version(s)
            _set_meta(s, "receiver_order", parts.get("order", ""))
            if source_hash is not None:
                _set_meta(s, "source_hash", source_hash)
        return version

    # ------------------------------------------------------------------ reports
    def store_batch(
        self,
        receiver_id: str,
        batch_id: str,
        frames: Sequence[tuple[int, str, str, float]],
    ) -> tuple[bool, int]:
        """Store a batch and its frames in one transaction.

        ``frames`` are ``(timestamp_ns, frame_sha256, transmitter, rss_dbm)``.
        Returns ``(new, batch pk)``; a known ``(receiver_id, batch_id)`` stores
        nothing and returns ``(False, pk)``.
        """
        existing = self._batch_pk(receiver_id, batch_id)
        if existing is not None:
            return False, existing
        try:
            with self.write() as s:
                if self.dialect == "postgresql":
                    s.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_BATCH_LOCK})
                pk = s.execute(
                    insert(BatchRow)
                    .values(
                        receiver_id=receiver_id,
                        batch_id=batch_id,
                        received_s=time.time(),
                        n_frames=len(frames),
                    )
                    .returning(BatchRow.id)
                ).scalar_one()
                if frames:
                    s.execute(
                        insert(FrameRow),
                        [
                            {
                                "batch_pk": pk,
                                "receiver_id": receiver_id,
                                "timestamp_ns": t,
                                "frame_sha256": h,
                                "transmitter": tx,
                                "rss_dbm": r,
                            }
                            for t, h, tx, r in frames
                        ],
                    )
        except IntegrityError:  # a concurrent resend of the same batch won the race
            pk2 = self._batch_pk(receiver_id, batch_id)
            if pk2 is None:
                raise
            return False, pk2
        return True, pk

    def _batch_pk(self, receiver_id: str, batch_id: str) -> int | None:
        with self.read() as s:
            return s.execute(
                select(BatchRow.id).where(
                    BatchRow.receiver_id == receiver_id, BatchRow.batch_id == batch_id
                )
            ).scalar_one_or_none()

    def batches_after(
        self, cursor: int, limit: int, receivers: Sequence[str] | None = None
    ) -> list[StoredBatch]:
        """Up to ``limit`` batches with id > ``cursor`` (of ``receivers`` only, if
        given), by id, with their frames in time order."""
        with self.read() as s:
            q = select(BatchRow.id, BatchRow.receiver_id, BatchRow.received_s).where(
                BatchRow.id > cursor
            )
            if receivers is not None:
                q = q.where(BatchRow.receiver_id.in_(list(receivers)))
            heads = s.execute(q.order_by(BatchRow.id).limit(limit)).all()
            if not heads:
                return []
            fq = select(
                FrameRow.batch_pk,
                FrameRow.timestamp_ns,
                FrameRow.frame_sha256,
                FrameRow.transmitter,
                FrameRow.rss_dbm,
            ).where(FrameRow.batch_pk >= heads[0][0], FrameRow.batch_pk <= heads[-1][0])
            if receivers is not None:
                fq = fq.where(FrameRow.receiver_id.in_(list(receivers)))
            rows = s.execute(
                fq.order_by(FrameRow.batch_pk, FrameRow.timestamp_ns, FrameRow.seq)
            ).all()
        by_batch: dict[int, list[Any]] = {h[0]: [] for h in heads}
        for r in rows:
            by_batch[r[0]].append(r)
        out = []
        for pk, rid, rec in heads:
            fr = by_batch[pk]
            out.append(
                StoredBatch(
                    pk,
                    rid,
                    rec,
                    tuple(r[1] for r in fr),
                    tuple(r[2] for r in fr),
                    tuple(r[3] for r in fr),
                    tuple(r[4] for r in fr),
                )
            )
        return out

    def last_batch_id(self) -> int:
        with self.read() as s:
            return int(s.execute(select(func.coalesce(func.max(BatchRow.id), 0))).scalar_one())

    def count_frames(self) -> int:
        with self.read() as s:
            return int(s.execute(select(func.count()).select_from(FrameRow)).scalar_one())

    def receiver_activity(self, window_s: float) -> dict[str, dict[str, float]]:
        """Per receiver that ever reported: last report time (server clock) and
        frames/s over the last window.

        Index lookups only (``batches (receiver_id, received_s)``): the window's
        batches, then each receiver that ever reported and its latest batch —
        not a scan of the whole table, which grows by every batch (1.85 s a call
        after a day of 4 receivers at 10 batches/s; ``/health`` and every
        dashboard call it)."""
        now = time.time()
        with self.read() as s:
            recent: dict[str, float] = {}
            for rid, n in s.execute(
                select(BatchRow.receiver_id, BatchRow.n_frames).where(
                    BatchRow.received_s >= now - window_s
                )
            ):
                recent[rid] = recent.get(rid, 0.0) + float(n)
            last = {}
            for rid in self._reporters(s):
                t = s.execute(
                    select(func.max(BatchRow.received_s)).where(BatchRow.receiver_id == rid)
                ).scalar_one()
                if t is not None:
                    last[rid] = float(t)
        return {
            rid: {"last_report_s": t, "frames_per_s": recent.get(rid, 0.0) / window_s}
            for rid, t in last.items()
        }

    def _reporters(self, s: Session) -> list[str]:
        """Every receiver id that has stored a batch, by an index skip: the next id
        after the last one found, one lookup per receiver."""
        out: list[str] = []
        while True:
            q = select(func.min(BatchRow.receiver_id))
            if out:
                q = q.where(BatchRow.receiver_id > out[-1])
            rid = s.execute(q).scalar_one()
            if rid is None:
                return out
            out.append(str(rid))

    # ------------------------------------------------------------------ live output
    def load_checkpoint(self, partition: str) -> tuple[int, bytes] | None:
        with self.read() as s:
            row = s.get(CheckpointRow, partition)
            return None if row is None else (int(row.cursor_batch), bytes(row.state))

    def summaries(self) -> dict[str, dict[str, Any]]:
        """Per partition: its latest summary, ``cursor_batch`` (its checkpoint's
        cursor) and ``updated_s``. Reads no checkpoint state (megabytes each)."""
        with self.read() as s:
            cursors = {
                part: cursor
                for part, cursor in s.execute(
                    select(CheckpointRow.partition, CheckpointRow.cursor_batch)
                )
            }
            out = {
                r.partition: {
                    **r.summary,
                    "cursor_batch": int(cursors.get(r.partition, 0)),
                    "updated_s": r.updated_s,
                }
                for r in s.scalars(select(SummaryRow))
            }
            for part in set(cursors) - set(out):  # an older database, before its first commit
                summary, updated = s.execute(
                    select(CheckpointRow.summary, CheckpointRow.updated_s).where(
                        CheckpointRow.partition == part
                    )
                ).one()
                out[part] = {**summary, "cursor_batch": int(cursors[part]), "updated_s": updated}
            return out

    def commit_step(
        self,
        partition: str,
        cursor: int,
        state: bytes | None,
        summary: dict[str, Any],
        packets: Sequence[dict[str, Any]],
        estimates: Sequence[dict[str, Any]],
        alarms: Sequence[dict[str, Any]] = (),
    ) -> None:
        """Store pipeline output — packets, estimates and spoofing alarm events
        (:class:`AlarmRow` fields but ``id``/``raised_s``) — with the partition's
        summary and, unless ``state`` is ``None``, its checkpoint (``cursor``
        and the pickled state), atomically. Outputs already stored (the same
        transmitter and packet id; an alarm of the same packet and state) are
        kept as they are: re-derived output is not stored twice."""
        with self.write() as s:
            self._insert_new(s, PacketRow, packets)
            self._insert_new(s, EstimateRow, estimates)
            self._insert_alarms(s, alarms)
            now = time.time()
            kept = s.get(SummaryRow, partition)
            if kept is None:
                s.add(SummaryRow(partition=partition, summary=summary, updated_s=now))
            else:
                kept.summary = summary
                kept.updated_s = now
            if state is None:  # output ahead of the checkpoint: its row is not touched
                return
            row = s.get(CheckpointRow, partition)
            if row is None:
                s.add(
                    CheckpointRow(
                        partition=partition,
                        cursor_batch=cursor,
                        state=state,
                        summary=summary,
                        updated_s=time.time(),
                    )
                )
            else:
                row.cursor_batch = cursor
                row.state = state
                row.summary = summary
                row.updated_s = time.time()

    def estimates(
        self,
        transmitter: str | None = None,
        since_s: float | None = None,
        after_id: int | None = None,
        limit: int = 10_000,
    ) -> list[dict[str, Any]]:
        """Estimates in time order (or id order with ``after_id``), as dicts with ``id``."""
        q = select(EstimateRow)
        if transmitter is not None:
            q = q.where(func.lower(EstimateRow.transmitter) == transmitter.lower())
        if since_s is not None:
            q = q.where(EstimateRow.timestamp_s >= since_s)
        if after_id is not None:
            q = q.where(EstimateRow.id > after_id).order_by(EstimateRow.id)
        else:
            q = q.order_by(EstimateRow.timestamp_s, EstimateRow.id)
        with self.read() as s:
            rows = s.scalars(q.limit(limit)).all()
            return [
                {
                    "id": int(r.id),
                    **{f: getattr(r, f) for f in ESTIMATE_FIELDS},
                    "last_report_s": r.last_report_s,
                    "estimated_s": r.estimated_s,
                    **{f: getattr(r, f) for f in ESTIMATE_STD_FIELDS},
                }
                for r in rows
            ]

    def drop_output_from(self, first_packet_id: int, owns: Callable[[str], bool]) -> int:
        """Delete the packets, estimates and alarm events of the transmitters
        ``owns`` accepts (one partition's) whose live packet id (a decimal
        number) is ``first_packet_id`` or later; return how many packets."""
        with self.write() as s:
            keys = [
                (tx, pid)
                for tx, pid in s.execute(select(PacketRow.transmitter, PacketRow.packet_id))
                if pid.isdigit() and int(pid) >= first_packet_id and owns(tx)
            ]
            for model in (PacketRow, EstimateRow, AlarmRow):
                for i in range(0, len(keys), 500):
                    chunk = keys[i : i + 500]
                    s.execute(
                        delete(model).where(tuple_(model.transmitter, model.packet_id).in_(chunk))
                    )
            return len(keys)

    def mark_unestimated(self, transmitters: Sequence[str], before_id: int, reason: str) -> int:
        """Give the stored packets of ``transmitters`` (case-insensitive) with a
        live packet id below ``before_id``, no skip reason and no estimate the
        reason ``reason``; return how many."""
        wanted = {t.lower() for t in transmitters}
        if not wanted:
            return 0
        with self.write() as s:
            estimated = {
                (tx.lower(), pid)
                for tx, pid in s.execute(select(EstimateRow.transmitter, EstimateRow.packet_id))
                if tx.lower() in wanted
            }
            ids = [
                row_id
                for row_id, tx, pid in s.execute(
                    select(PacketRow.id, PacketRow.transmitter, PacketRow.packet_id).where(
                        PacketRow.reason.is_(None)
                    )
                )
                if tx.lower() in wanted
                and pid.isdigit()
                and int(pid) < before_id
                and (tx.lower(), pid) not in estimated
            ]
            for i in range(0, len(ids), 500):
                s.execute(
                    update(PacketRow)
                    .where(PacketRow.id.in_(ids[i : i + 500]))
                    .values(reason=reason)
                )
            return len(ids)

    def add_alarms(self, events: Sequence[dict[str, Any]]) -> None:
        """Store spoofing alarm events (:class:`AlarmRow` fields but
        ``id``/``raised_s``); one already stored (same transmitter, packet and
        state) is not stored again."""
        if not events:
            return
        with self.write() as s:
            self._insert_alarms(s, events)

    def _insert_new(self, s: Session, model: type[Any], rows: Sequence[dict[str, Any]]) -> None:
        """Insert ``rows``, skipping those whose unique key is stored already."""
        if not rows:
            return
        if self.dialect == "sqlite":
            from sqlalchemy.dialects.sqlite import insert as sqlite_insert

            s.execute(sqlite_insert(model).on_conflict_do_nothing(), list(rows))
        elif self.dialect == "postgresql":
            from sqlalchemy.dialects.postgresql import insert as pg_insert

            s.execute(pg_insert(model).on_conflict_do_nothing(), list(rows))
        else:  # another dialect: a plain insert (re-derived output would fail)
            s.execute(insert(model), list(rows))

    def _insert_alarms(self, s: Session, events: Sequence[dict[str, Any]]) -> None:
        """Insert alarm events not stored yet (key: transmitter, packet, state)."""
        if not events:
            return
        keys = {(e["transmitter"], e["packet_id"]) for e in events}
        have = {
            (r.transmitter, r.packet_id, r.state)
            for r in s.execute(
                select(AlarmRow.transmitter, AlarmRow.packet_id, AlarmRow.state).where(
                    AlarmRow.transmitter.in_(sorted({k[0] for k in keys})),
                    AlarmRow.packet_id.in_(sorted({k[1] for k in keys})),
                )
            )
        }
        now = time.time()
        new, seen = [], set(have)
        for e in events:
            key = (e["transmitter"], e["packet_id"], e["state"])
            if key not in seen:
                seen.add(key)
                new.append({**e, "raised_s": now})
        if new:
            s.execute(insert(AlarmRow), new)

    def alarms(
        self, transmitter: str | None = None, since_s: float | None = None, limit: int = 1_000
    ) -> list[dict[str, Any]]:
        """Spoofing alarm events in time order, as dicts with ``id``."""
        q = select(AlarmRow)
        if transmitter is not None:
            q = q.where(func.lower(AlarmRow.transmitter) == transmitter.lower())
        if since_s is not None:
            q = q.where(AlarmRow.timestamp_s >= since_s)
        q = q.order_by(AlarmRow.timestamp_s, AlarmRow.id).limit(limit)
        with self.read() as s:
            return [_row_dict(r, AlarmRow) for r in s.scalars(q).all()]

    def recent_latencies_s(self, n: int = 1_000) -> list[float]:
        """Report-to-estimate latency of the last ``n`` estimates, seconds."""
        with self.read() as s:
            rows = (
                s.execute(
                    select(EstimateRow.estimated_s - EstimateRow.last_report_s)
                    .order_by(EstimateRow.id.desc())
                    .limit(n)
                )
                .scalars()
                .all()
            )
        return [float(v) for v in rows]

    def last_estimate_id(self) -> int:
        with self.read() as s:
            return int(s.execute(select(func.coalesce(func.max(EstimateRow.id), 0))).scalar_one())

    def packets(self) -> list[dict[str, Any]]:
        """Stored packets in processing order."""
        with self.read() as s:
            return [
                {
                    "packet_id": r.packet_id,
                    "transmitter": r.transmitter,
                    "timestamp_s": r.timestamp_s,
                    "receiver_ids": list(r.receiver_ids),
                    "rss_dbm": list(r.rss_dbm),
                    "reason": r.reason,
                }
                for r in s.scalars(select(PacketRow).order_by(PacketRow.id))
            ]

    def iter_frames(self, chunk: int = 50_000) -> Iterator[list[tuple[Any, ...]]]:
        """All frames in arrival order, in chunks of ``(receiver_id, ns, sha, tx, rss)``."""
        last = 0
        while True:
            with self.read() as s:
                rows = s.execute(
                    select(
                        FrameRow.seq,
                        FrameRow.receiver_id,
                        FrameRow.timestamp_ns,
                        FrameRow.frame_sha256,
                        FrameRow.transmitter,
                        FrameRow.rss_dbm,
                    )
                    .where(FrameRow.seq > last)
                    .order_by(FrameRow.seq)
                    .limit(chunk)
                ).all()
            if not rows:
                return
            last = rows[-1][0]
            yield [tuple(r[1:]) for r in rows]


def _row_dict(row: Any, model: type[Base]) -> dict[str, Any]:
    return {c.key: getattr(row, c.key) for c in model.__table__.columns}


def _set_meta(s: Session, key: str, value: str) -> None:
    row = s.get(SiteMetaRow, key)
    if row is None:
        s.add(SiteMetaRow(key=key, value=value))
    else:
        row.value = value


def _bump_version(s: Session) -> int:
    row = s.get(SiteMetaRow, "site_version")
    version = (int(row.value) if row is not None else 0) + 1
    _set_meta(s, "site_version", str(version))
    return version


def _sqlite_engine(url: str, begin: str) -> Engine:
    engine = create_engine(url, connect_args={"timeout": 30.0})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # BEGIN is issued below
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute("PRAGMA synchronous=FULL")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Any) -> None:
        conn.exec_driver_sql(begin)

    return engine


def _make_engines(url: str) -> tuple[Engine, Engine]:
    """(write engine, read engine); the same engine except for SQLite."""
    if url.startswith("sqlite"):
        # writers take the lock up front (no deadlock on upgrade); readers never block in WAL
        engines = (_sqlite_engine(url, "BEGIN IMMEDIATE"), _sqlite_engine(url, "BEGIN"))
    else:
        engine = create_engine(url, pool_pre_ping=True)
        engines = (engine, engine)
    with engines[0].connect() as c:  # fail early on a bad path or server
        c.execute(text("SELECT 1"))
    return engines
