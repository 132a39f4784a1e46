"""Receiver agent: ship one receiver's frame reports to the central server.

``radiopose receiver --server URL --token TOKEN --id RECEIVER_ID
(--replay CAPTURE [--speed X] | --interface IFACE)``

Frames come from a capture replayed at its own pace (``--replay``; pcap,
pcapng or the CSV capture form, X times real time) or from a monitor-mode
interface (``--interface``; Linux ``AF_PACKET`` socket, needs root or
``CAP_NET_RAW``, decoded exactly like a pcap file). They are batched (every
``batch_interval_s``, default 100 ms) and posted to ``/api/v1/reports``.

Delivery guarantees:

* each batch gets a ``batch_id`` once and keeps it on every resend (the
  server stores a batch at most once);
* a batch that cannot be delivered (network error, 5xx, 408, 429) is written
  to the *spool* — one JSON file per batch in ``spool_dir/<receiver_id>/``,
  written atomically and fsynced — and so is every later batch until the spool
  is empty again, so the server always receives one receiver's batches in
  time order. The sender retries with exponential backoff (with jitter) and
  removes a spool file only after the server acknowledged it (2xx). Spool
  files left by an earlier run are sent first;
* a batch the server rejects with another 4xx is never deleted: it is moved
  to ``spool_dir/<receiver_id>/rejected/`` and logged. A batch rejected for a
  transmitter that is not enrolled is first filtered against the server's
  current list and resent.

Nothing acknowledged or spooled is lost; frames still in memory (at most one
batch interval plus the in-memory queue) are lost only if the agent itself
dies.
"""

from __future__ import annotations

import json
import logging
import os
import random
import secrets
import socket
import struct
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.capture.pcapfile import is_pcap_start
from radiopose.capture.records import FrameRecords, read_capture, read_pcap
from radiopose.errors import InputError

log = logging.getLogger("radiopose.receiver")

REPORTS_PATH = "/api/v1/reports"
TRANSMITTERS_PATH = "/api/v1/transmitters"
_RETRYABLE = frozenset({408, 425, 429, 500, 502, 503, 504})


def default_spool_dir() -> Path:
    """The receiver agent's default spool: ``$XDG_DATA_HOME/radiopose/spool``.

    ``XDG_DATA_HOME`` defaults to ``~/.local/share`` (the XDG base directory
    rules), so the spool never depends on the directory the agent starts in.
    """
    base = os.environ.get("XDG_DATA_HOME") or ""
    root = Path(base) if Path(base).is_absolute() else Path.home() / ".local" / "share"
    return root / "radiopose" / "spool"


@dataclass(frozen=True)
class AgentConfig:
    """Settings of a receiver agent.

    Attributes
    ----------
    server_url
        Base URL of the central server, e.g. ``http://127.0.0.1:8000``.
    token
        The receiver's bearer token.
    receiver_id
        The receiver this agent reports for.
    spool_dir
        Where undelivered batches are kept (one subdirectory per receiver);
        default :func:`default_spool_dir`, a per-user data directory.
    batch_interval_s
        Batching period, seconds.
    max_batch_frames
        Frames per batch at most (the server accepts up to 5,000).
    max_queue_batches
        Batches held in memory before they go to the spool.
    timeout_s
        HTTP timeout, seconds.
    backoff_initial_s, backoff_max_s
        Retry delays: doubling from the first to the cap, ±25 % jitter.
    """

    server_url: str
    token: str
    receiver_id: str
    spool_dir: Path = field(default_factory=default_spool_dir)
    batch_interval_s: float = 0.1
    max_batch_frames: int = 2_000
    max_queue_batches: int = 50
    timeout_s: float = 10.0
    backoff_initial_s: float = 0.2
    backoff_max_s: float = 2.0


@dataclass
class AgentStats:
    """Counters of an agent (for its summary line and tests)."""

    frames_in: int = 0
    frames_filtered: int = 0
    batches_made: int = 0
    batches_acked: int = 0
    duplicates: int = 0
    resends: int = 0
    spooled: int = 0
    rejected: int = 0
    last_rejection: str = ""
    """The server's answer to the last rejected batch (status and detail)."""
    errors: list[str] = field(default_factory=list)


class Spool:
    """Undelivered batches, one fsynced JSON file each, oldest first."""

    def __init__(self, directory: Path) -> None:
        self.dir = directory
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "rejected").mkdir(exist_ok=True)

    def files(self) -> list[Path]:
        return sorted(self.dir.glob("*.json"))

    def __len__(self) -> int:
        return len(self.files())

    def put(self, batch: dict[str, Any]) -> Path:
        name = f"{time.time_ns():020d}-{batch['seq']:09d}.json"
        path = self.dir / name
        fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(batch, fh, separators=(",", ":"))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        _fsync_dir(self.dir)
        return path

    @staticmethod
    def read(path: Path) -> dict[str, Any]:
        return json.loads(path.read_text("utf-8"))

    def remove(self, path: Path) -> None:
        path.unlink(missing_ok=True)

    def reject(self, path: Path | None, batch: dict[str, Any], reason: str = "") -> Path:
        """Move ``batch`` to ``rejected/``, with the server's ``reason`` beside it
        (``<batch>.reason.txt``)."""
        dest = self.dir / "rejected" / f"{batch['batch_id'].replace(':', '_')}.json"
        if path is not None:
            os.replace(path, dest)
        else:
            dest.write_text(json.dumps(batch), encoding="utf-8")
        if reason:
            dest.with_suffix(".reason.txt").write_text(reason + "\n", encoding="utf-8")
        return dest


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class ReceiverAgent:
    """Batches frames, sends them in order, spools and retries (see module docstring).

    Parameters
    ----------
    config
        Settings.
    client
        An ``httpx.Client`` (default: a new one with ``config.timeout_s``).
    """

    def __init__(self, config: AgentConfig, client: Any = None) -> None:
        import httpx

        self.config = config
        self.client = client or httpx.Client(timeout=config.timeout_s)
        self.url = config.server_url.rstrip("/")
        self.stats = AgentStats()
        self.spool = Spool(Path(config.spool_dir) / _safe(config.receiver_id))
        self._queue: deque[dict[str, Any]] = deque()
        self._lock = threading.Lock()
        self._spooling = len(self.spool) > 0
        self._have_work = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._boot = f"{time.time_ns():x}{secrets.token_hex(3)}"
        self._seq = 0
        self._transmitters: set[str] | None = None
        self._thread = threading.Thread(target=self._sender, name="radiopose-agent", daemon=True)
        self._thread.start()
        if self._spooling:
            self._have_work.set()

    # ------------------------------------------------------------------ input
    def refresh_transmitters(self) -> bool:
        """Fetch the enrolled transmitters; ``False`` if the server cannot be reached."""
        import httpx

        try:
            r = self.client.get(self.url + TRANSMITTERS_PATH, headers=self._headers())
        except httpx.HTTPError:
            return False
        if r.status_code in (401, 403):
            raise InputError(f"the server refused the token ({r.status_code}: {_detail(r)})")
        if r.status_code != 200:
            return False
        self._transmitters = {t.lower() for t in r.json()}
        return True

    def submit(self, frames: FrameRecords) -> None:
        """Queue one receiver's frames (time order) as one or more batches."""
        n = len(frames)
        self.stats.frames_in += n
        if n == 0:
            return
        keep = np.ones(n, dtype=bool)
        if self._transmitters is not None:
            keep = np.fromiter((t in self._transmitters for t in frames.transmitter), bool, n)
            self.stats.frames_filtered += int(n - keep.sum())
        idx = np.flatnonzero(keep)
        step = self.config.max_batch_frames
        for s in range(0, idx.size, step):
            sel = idx[s : s + step]
            self._enqueue(
                [
                    {
                        "timestamp_s": int(frames.timestamp_ns[i]) / 1e9,
                        "frame_sha256": str(frames.frame_sha256[i]),
                        "transmitter": str(frames.transmitter[i]),
                        "rss_dbm": float(frames.rss_dbm[i]),
                    }
                    for i in sel
                ]
            )

    def _enqueue(self, frames: list[dict[str, Any]]) -> None:
        self._seq += 1
        batch = {
            "receiver_id": self.config.receiver_id,
            "batch_id": f"{self.config.receiver_id}:{self._boot}:{self._seq}",
            "seq": self._seq,
            "frames": frames,
        }
        self.stats.batches_made += 1
        with self._lock:
            if self._spooling or len(self._queue) >= self.config.max_queue_batches:
                self._to_spool_locked(batch)
            else:
                self._queue.append(batch)
        self._idle.clear()
        self._have_work.set()

    def _to_spool_locked(self, batch: dict[str, Any]) -> None:
        # keep order: whatever is still in memory goes to the spool first
        while self._queue:
            self.spool.put(self._queue.popleft())
            self.stats.spooled += 1
        self.spool.put(batch)
        self.stats.spooled += 1
        self._spooling = True

    def pending(self) -> int:
        """Batches not yet acknowledged (memory + spool)."""
        with self._lock:
            return len(self._queue) + len(self.spool)

    def drain(self, timeout_s: float | None = None) -> bool:
        """Wait until every batch is acknowledged (or rejected); ``False`` on timeout."""
        end = None if timeout_s is None else time.monotonic() + timeout_s
        while self.pending() > 0:
            if end is not None and time.monotonic() >= end:
                return False
            self._have_work.set()
            time.sleep(0.05)
        return True

    def close(self) -> None:
        """Stop the sender; undelivered batches in memory are spooled."""
        self._stop.set()
        self._have_work.set()
        self._thread.join(self.config.timeout_s + 5)
        with self._lock:
            while self._queue:
                self.spool.put(self._queue.popleft())
                self.stats.spooled += 1
        self.client.close()

    # ------------------------------------------------------------------ sending
    def _headers(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.config.token}"}

    def _next(self) -> tuple[Path | None, dict[str, Any]] | None:
        with self._lock:
            files = self.spool.files()
            if files:
                return files[0], self.spool.read(files[0])
            self._spooling = False
            if self._queue:
                return None, self._queue[0]
            return None

    def _sender(self) -> None:
        delay = self.config.backoff_initial_s
        while True:
            item = self._next()
            if item is None:
                if self._stop.is_set():
                    return
                self._idle.set()
                self._have_work.wait(0.5)
                self._have_work.clear()
                continue
            path, batch = item
            outcome = self._post(batch)
            if outcome == "ok":
                delay = self.config.backoff_initial_s
                with self._lock:
                    if path is not None:
                        self.spool.remove(path)
                    elif self._queue and self._queue[0] is batch:
                        self._queue.popleft()
                continue
            if outcome == "refilter":
                if self.refresh_transmitters() and self._transmitters is not None:
                    batch = {
                        **batch,
                        "frames": [
                            f
                            for f in batch["frames"]
                            if f["transmitter"].lower() in self._transmitters
                        ],
                    }
                    self._replace(path, batch)
                    continue
                outcome = "rejected"
            if outcome == "rejected":
                with self._lock:
                    if path is None and self._queue and self._queue[0] is batch:
                        self._queue.popleft()
                    dest = self.spool.reject(path, batch, self.stats.last_rejection)
                self.stats.rejected += 1
                log.warning(
                    "batch rejected by the server (%s); kept in %s", self.stats.last_rejection, dest
                )
                continue
            # retry later: make sure it is on disk, then back off
            if path is None:
                with self._lock:
                    self._to_spool_locked_front()
            if self._stop.is_set():
                return
            self._stop.wait(delay * random.uniform(0.75, 1.25))
            delay = min(delay * 2, self.config.backoff_max_s)
            self.stats.resends += 1

    def _to_spool_locked_front(self) -> None:
        while self._queue:
            self.spool.put(self._queue.popleft())
            self.stats.spooled += 1
        self._spooling = True

    def _replace(self, path: Path | None, batch: dict[str, Any]) -> None:
        with self._lock:
            if path is not None:
                path.write_text(json.dumps(batch), encoding="utf-8")
            elif self._queue:
                self._queue[0] = batch

    def _post(self, batch: dict[str, Any]) -> str:
        import httpx

        body = {k: batch[k] for k in ("receiver_id", "batch_id", "frames")}
        try:
            r = self.client.post(self.url + REPORTS_PATH, json=body, headers=self._headers())
        except httpx.HTTPError as exc:
            self._note(f"server unreachable: {type(exc).__name__}")
            return "retry"
        if 200 <= r.status_code < 300:
            self.stats.batches_acked += 1
            if r.status_code == 200:
                self.stats.duplicates += 1
            return "ok"
        if r.status_code in _RETRYABLE:
            self._note(f"server answered {r.status_code}")
            return "retry"
        detail = _detail(r)
        self.stats.last_rejection = f"{r.status_code} {detail}"
        self._note(f"server rejected batch {batch['batch_id']}: {r.status_code} {detail}")
        if r.status_code == 422 and "not enrolled" in detail:
            return "refilter"
        return "rejected"

    def _note(self, message: str) -> None:
        if not self.stats.errors or self.stats.errors[-1] != message:
            log.info(message)
        self.stats.errors.append(message)
        del self.stats.errors[:-20]


def _detail(r: Any) -> str:
    try:
        return str(r.json().get("detail", ""))[:200]
    except ValueError:
        return r.text[:200]


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "_"


# ----------------------------------------------------------------------------- sources
def replay_frames(path: str | os.PathLike[str], receiver_id: str) -> FrameRecords:
    """One receiver's frames of a capture, in time order.

    A pcap/pcapng is taken to be this receiver's; a CSV capture contributes
    its rows whose ``receiver_id`` matches.

    Raises
    ------
    InputError
        Unreadable capture, or a CSV capture without rows of this receiver.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", path=p)
    with open(p, "rb") as fh:
        head = fh.read(4)
    if is_pcap_start(head):
        frames = read_pcap(p, receiver_id).frames
    else:
        cap = read_capture(p)
        frames = cap.frames.take(cap.frames.receiver_id == receiver_id)
        if len(frames) == 0:
            known = ", ".join(s.receiver_id for s in cap.stats) or "none"
            raise InputError(f"no frames of receiver {receiver_id!r} (receivers: {known})", path=p)
    return frames.time_ordered()


def run_replay(
    agent: ReceiverAgent,
    frames: FrameRecords,
    *,
    speed: float = 1.0,
    stop: threading.Event | None = None,
    progress: Callable[[int], None] | None = None,
) -> int:
    """Send ``frames`` paced by their timestamps, ``speed`` times real time.

    Returns the number of frames submitted (all of them unless stopped).
    """
    if not speed > 0:
        raise InputError(f"--speed must be > 0, got {speed}")
    stop = stop or threading.Event()
    n = len(frames)
    if n == 0:
        return 0
    due_s = (frames.timestamp_ns - frames.timestamp_ns[0]) / 1e9 / speed
    t0 = time.monotonic()
    i = 0
    while i < n and not stop.is_set():
        now = time.monotonic() - t0
        j = int(np.searchsorted(due_s, now, side="right"))
        if j > i:
            agent.submit(frames.take(slice(i, j)))
            i = j
            if progress is not None:
                progress(i)
        if i < n:  # one batch interval, or until the next frame is due
            stop.wait(max(agent.config.batch_interval_s, float(due_s[i]) - now))
    return i


# ----------------------------------------------------------------------------- live capture
_ETH_P_ALL = 0x0003
_PCAP_HEADER = struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 262_144, 127)  # ns, radiotap


def capture_interface(
    agent: ReceiverAgent,
    interface: str,
    *,
    stop: threading.Event | None = None,
    sock: Any = None,
) -> int:
    """Capture from a monitor-mode interface until stopped; return frames submitted.

    Each batch interval's raw radiotap frames are written to an in-memory-sized
    temporary pcap and decoded by :func:`radiopose.capture.read_pcap`, so
    live frames are hashed and filtered exactly like captured files.
    Timestamps are the host clock at reception.

    Raises
    ------
    InputError
        The interface cannot be opened (not found, no permission).
    """
    stop = stop or threading.Event()
    if sock is None:
        try:
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(_ETH_P_ALL))
            sock.bind((interface, 0))
        except (OSError, AttributeError) as exc:
            raise InputError(
                f"--interface {interface}: cannot capture ({getattr(exc, 'strerror', exc)}); "
                "needs Linux, root or CAP_NET_RAW, and a monitor-mode interface"
            ) from None
    sock.settimeout(agent.config.batch_interval_s)
    total = 0
    with tempfile.TemporaryDirectory(prefix="radiopose-live-") as tmp:
        path = Path(tmp) / "batch.pcap"
        while not stop.is_set():
            records: list[tuple[int, bytes]] = []
            end = time.monotonic() + agent.config.batch_interval_s
            while time.monotonic() < end:
                try:
                    data = sock.recv(65_535)
                except TimeoutError:
                    break
                except OSError:
                    break
                records.append((time.time_ns(), data))
            if not records:
                continue
            path.write_bytes(_pcap_bytes(records))
            frames = read_pcap(path, agent.config.receiver_id).frames
            agent.submit(frames)
            total += len(frames)
    return total


def _pcap_bytes(records: Sequence[tuple[int, bytes]]) -> bytes:
    out = bytearray(_PCAP_HEADER)
    for t_ns, data in records:
        out += struct.pack(
            "<IIII", t_ns // 1_000_000_000, t_ns % 1_000_000_000, len(data), len(data)
        )
        out += data
    return bytes(out)
