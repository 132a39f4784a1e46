"""Fixtures and helpers of the live-server tests (imported by ``test_server_*.py``).

* ``tiny`` — a tiny simulated site (6 m, 0.25 m grid, 3 receivers, 3 s of
  packets every 20 ms) with one pcap per receiver (clock offsets ±0.3 s);
* ``db_url`` — a fresh empty database, once SQLite and once PostgreSQL (a
  throwaway cluster started from Debian's binaries; skipped with the reason
  when they are absent);
* ``server`` — the app on uvicorn in a thread on an ephemeral loopback port,
  with the site imported and tokens of every role.
"""

from __future__ import annotations

import contextlib
import glob
import itertools
import os
import shutil
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import httpx
import numpy as np
import pytest

from radiopose.capture.records import FrameRecords, read_pcap
from radiopose.capture.writer import write_receiver_pcaps
from radiopose.server.app import create_app, import_site_dir
from radiopose.server.auth import create_token
from radiopose.server.db import Database
from radiopose.server.live import LiveConfig
from radiopose.simulate import ScenarioConfig, Simulation, simulate

RECEIVERS = ("rx1", "rx2", "rx3")


@dataclass(frozen=True)
class Tiny:
    root: Path
    site_dir: Path
    pcaps: dict[str, Path]
    frames: dict[str, FrameRecords]
    transmitter: str


@pytest.fixture(scope="session")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Tiny:
    root = tmp_path_factory.mktemp("tiny")
    cfg = ScenarioConfig(
        size_m=6.0,
        step_m=0.25,
        n_receivers=3,
        duration_s=3.0,
        interval_ms=20.0,
        azimuth_step_deg=2.0,
        noise_db=0.5,
        min_receiver_spacing_m=3.0,
    )
    sim = simulate(cfg, seed=3)
    sim.write(root)
    pc = write_receiver_pcaps(
        sim.packets,
        root / "pcaps",
        rng=np.random.default_rng(3),
        clock_offset_s={"rx2": 0.3, "rx3": -0.3},
        jitter_s=2e-6,
        epoch_s=1000.0,
    )
    frames = {r: read_pcap(p, r).frames for r, p in pc.paths.items()}
    _warm_kernels(sim)
    return Tiny(root, root / "site", dict(pc.paths), frames, str(sim.packets.transmitter[0]))


def _warm_kernels(sim: Simulation) -> None:
    """Compile (or load from numba's cache) the live methods' kernels in this
    process before a server test starts: its server thread shares them, and a
    browser test waits 30 s for the first estimate, which numba's first
    compile on a cold cache beside another busy worker can take (a dashboard
    test timed out so, run alone after the caches were cleared)."""
    from radiopose.tracker import locate

    pk = sim.packets
    keep = pk.timestamp_s <= 1.0  # a second of packets
    columns = ("packet_id", "timestamp_s", "transmitter", "receiver_id", "rss_dbm")
    head = replace(pk, **{c: getattr(pk, c)[keep] for c in columns})
    for method in ("full", "filter"):  # the live server's default and the filter
        locate(sim.site, head, method)


# ----------------------------------------------------------------------------- databases
def _pg_bin() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(found[-1]).parent if found else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def pg_server() -> Iterator[str]:
    """A throwaway PostgreSQL cluster on loopback; yields its base URL."""
    bindir = _pg_bin()
    if bindir is None:
        pytest.skip("PostgreSQL server binaries not found (apt-get install postgresql)")
    shm = Path("/dev/shm")  # a tmpfs: creating and removing clusters is quick there
    tmp = Path(tempfile.mkdtemp(prefix="radiopose-pg-", dir=shm if shm.is_dir() else None))
    data = tmp / "data"
    run_as: list[str] = []
    if os.geteuid() == 0:  # initdb refuses root: run the cluster as 'postgres'
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL")
        run_as = ["runuser", "-u", "postgres", "--"]
        shutil.chown(tmp, "postgres")
        tmp.chmod(0o700)
    port = _free_port()
    env = {**os.environ, "LC_ALL": "C.UTF-8"}
    try:
        subprocess.run(
            [
                *run_as,
                str(bindir / "initdb"),
                "-D",
                str(data),
                "-A",
                "trust",
                "-U",
                "postgres",
                "-E",
                "UTF8",
            ],
            check=True,
            capture_output=True,
            env=env,
        )
        subprocess.run(
            [
                *run_as,
                str(bindir / "pg_ctl"),
                "-D",
                str(data),
                "-l",
                str(tmp / "log"),
                "-w",
                "-o",
                f"-F -k {tmp} -h 127.0.0.1 -p {port}",
                "start",
            ],
            check=True,
            capture_output=True,
            env=env,
        )
    except subprocess.CalledProcessError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        pytest.skip(f"could not start PostgreSQL: {exc.stderr.decode(errors='replace')[-200:]}")
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}"
    finally:
        subprocess.run(
            [*run_as, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
        )
        shutil.rmtree(tmp, ignore_errors=True)


_db_counter = itertools.count()


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A fresh, empty database URL: SQLite file or a new PostgreSQL database."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'server.db'}"
    base = request.getfixturevalue("pg_server")
    name = f"t{os.getpid()}_{next(_db_counter)}"
    import psycopg

    with psycopg.connect(base.replace("+psycopg", "") + "/postgres", autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{name}"')
    return f"{base}/{name}"


# ----------------------------------------------------------------------------- server
@dataclass
class Running:
    url: str
    db: Database
    app: object
    tokens: dict[str, str] = field(default_factory=dict)
    clients: list[httpx.Client] = field(default_factory=list)

    def client(self, token: str | None, **headers: str) -> httpx.Client:
        """An HTTP client with ``token`` (closed with the server)."""
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        # a fresh connection per request: keep-alive to a server thread in this same
        # process costs ~40 ms per request here (not so across processes)
        headers.setdefault("Connection", "close")
        c = httpx.Client(base_url=self.url, headers=headers, timeout=30.0)
        self.clients.append(c)
        return c


@contextlib.contextmanager
def run_server(
    db: Database, live: LiveConfig | None = None, *, run_pipeline: bool = True, port: int = 0
) -> Iterator[Running]:
    """Serve ``db`` on a loopback port (default: ephemeral) in a thread."""
    import uvicorn

    app = create_app(db, live, run_pipeline=run_pipeline)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", port))
    port = sock.getsockname()[1]
    server = uvicorn.Server(
        uvicorn.Config(
            app, log_config=None, access_log=False, timeout_graceful_shutdown=1, lifespan="on"
        )
    )
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    end = time.monotonic() + 20
    while not server.started:
        if time.monotonic() > end or not thread.is_alive():
            raise RuntimeError("server did not start")
        time.sleep(0.02)
    running = Running(f"http://127.0.0.1:{port}", db, app)
    try:
        yield running
    finally:
        for c in running.clients:
            c.close()
        server.should_exit = True
        thread.join(15)
        sock.close()


def batch_rounds(trace: Tiny, per_batch: int = 40) -> Iterator[list[tuple[str, str, list]]]:
    """Every receiver's frames as ``(receiver, batch id, rows)`` batches, one round
    (the next batch of each receiver) at a time, so receivers interleave in time."""
    chunks = {r: list(range(0, len(trace.frames[r]), per_batch)) for r in trace.frames}
    for i in range(max(len(c) for c in chunks.values())):
        batches = []
        for r in sorted(trace.frames):
            if i < len(chunks[r]):
                f = trace.frames[r].take(slice(chunks[r][i], chunks[r][i] + per_batch))
                rows = list(zip(f.timestamp_ns.tolist(), f.frame_sha256, f.transmitter,
                                f.rss_dbm.tolist(), strict=True))  # fmt: skip
                batches.append((r, f"{r}-{i}", rows))
        yield batches


def store_frames(db: Database, trace: Tiny, per_batch: int = 40) -> int:
    """Store every receiver's frames as batches, receivers interleaved in time; how many."""
    n = 0
    for batches in batch_rounds(trace, per_batch):
        for r, batch_id, rows in batches:
            db.store_batch(r, batch_id, rows)
            n += 1
    return n


def fast_live(**kw: object) -> LiveConfig:
    """Live settings for short test traces.

    The idle flush (2 s; 5 s by default) is what closes a trace's last packets,
    so every test that waits for them pays it once; below about a second a CI
    machine's stall of the agents' threads (several suites at once) can pass
    for the end of the reports mid-calibration.
    """
    base = {"calibration_s": 1.0, "idle_flush_s": 2.0, "poll_s": 0.02, "checkpoint_s": 0.2}
    return LiveConfig(**{**base, **kw})


@pytest.fixture
def server(tiny: Tiny, db_url: str) -> Iterator[Running]:
    db = Database(db_url)
    import_site_dir(db, tiny.site_dir)
    tokens = {"admin": create_token(db, "admin"), "viewer": create_token(db, "viewer")}
    for r in RECEIVERS:
        tokens[r] = create_token(db, "receiver", r)
    with run_server(db, fast_live()) as running:
        running.tokens = tokens
        yield running
    db.close()


def frame_dicts(frames: FrameRecords) -> list[dict[str, object]]:
    return [
        {
            "timestamp_s": int(t) / 1e9,
            "frame_sha256": str(h),
            "transmitter": str(tx),
            "rss_dbm": float(r),
        }
        for t, h, tx, r in zip(
            frames.timestamp_ns,
            frames.frame_sha256,
            frames.transmitter,
            frames.rss_dbm,
            strict=True,
        )
    ]


def wait_for(predicate, timeout_s: float = 30.0, interval_s: float = 0.05, describe=None):
    """Poll until ``predicate()`` is truthy; return its value (fail on timeout).

    ``describe()``, if given, adds what was seen to the failure's message.
    """
    end = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > end:
            seen = "" if describe is None else f": {describe()}"
            raise AssertionError(f"timed out after {timeout_s} s waiting for {predicate}{seen}")
        time.sleep(interval_s)
