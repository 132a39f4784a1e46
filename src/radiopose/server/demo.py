"""``radiopose demo --live``: a server and one replaying receiver agent per receiver.

Simulates a small site (10 m × 10 m, 4 receivers, a packet every 100 ms) with
the device walking between random waypoints (rounded turns, facing the way it
walks) — or, with ``--pose 3d``, the hand-held phone of ``radiopose simulate
--pose 3d`` on a 10 m site with 6 receivers at mixed heights (height, pitch
and roll vary; the server runs the 3-D ``filter``) — writes one pcap per
receiver (each with its own clock offset and
drift), creates a fresh SQLite database with tokens, starts ``radiopose serve
--method METHOD`` (default ``filter``: the dashboard draws its track with the
stated uncertainty) and one ``radiopose receiver --replay`` per receiver as
child processes, prints the dashboard URL (with a viewer token) and an admin
token, and waits for Ctrl-C, which stops every child cleanly.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path


def serve_command(site_dir: Path, db_url: str, port: int, method: str | None = None) -> list[str]:
    """Command line of ``radiopose serve`` as the demo (and the server benchmark) runs it:
    ``site_dir`` on ``port``, 2 s clock calibration, 3 s idle flush, and the tracker
    ``method`` (``None``: the server's default)."""
    return [
        sys.executable,
        "-m",
        "radiopose",
        "serve",
        str(site_dir),
        "--db",
        db_url,
        "--port",
        str(port),
        "--calibration-s",
        "2",
        "--idle-flush-s",
        "3",
        *([] if method is None else ["--method", method]),
    ]


def replay_command(
    base_url: str,
    token: str,
    receiver_id: str,
    pcap: Path,
    speed: float,
    spool: Path,
    *,
    quiet: bool = False,
) -> list[str]:
    """Command line of one ``radiopose receiver --replay`` agent: replays ``pcap`` at
    ``speed`` × real time to the server at ``base_url``, spooling under ``spool``."""
    return [
        sys.executable,
        "-m",
        "radiopose",
        "receiver",
        "--server",
        base_url,
        "--token",
        token,
        "--id",
        receiver_id,
        "--replay",
        str(pcap),
        "--speed",
        str(speed),
        "--spool",
        str(spool),
        *(["-q"] if quiet else []),
    ]


def run_live_demo(
    out_dir: str | Path,
    *,
    seed: int = 7,
    noise_db: float = 1.0,
    duration_s: float = 60.0,
    interval_ms: float = 100.0,
    method: str = "filter",
    speed: float = 1.0,
    port: int = 8000,
    echo: Callable[[str], None] = print,
    stop_after_s: float | None = None,
    pose: str = "2d",
) -> dict[str, str]:
    """Run the live demo until Ctrl-C (or ``stop_after_s``); return URL and tokens.

    ``method`` is the server's tracker method; ``duration_s`` and ``interval_ms``
    the simulated walk's length and packet interval; ``pose`` ``"2d"`` (the
    paper's kind of site) or ``"3d"`` (a hand-held phone at a 3-D site).
    """
    import httpx
    import numpy as np

    from radiopose.capture.writer import write_receiver_pcaps
    from radiopose.errors import InputError
    from radiopose.server.auth import create_token
    from radiopose.server.db import Database
    from radiopose.simulate import MotionConfig, ScenarioConfig, simulate

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if pose == "3d":
        from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

        cfg3 = HandheldConfig(
            size_m=10.0,
            n_receivers=6,
            duration_s=duration_s,
            interval_ms=interval_ms,
            noise_db=noise_db,
            min_receiver_spacing_m=3.0,
        )
        cfg3.validate()
        sim = simulate_handheld(cfg3, seed=seed)
    elif pose == "2d":
        cfg = ScenarioConfig(
            size_m=10.0,
            step_m=0.25,
            n_receivers=4,
            duration_s=duration_s,
            interval_ms=interval_ms,
            azimuth_step_deg=3.0,
            noise_db=noise_db,
            min_receiver_spacing_m=4.0,
            motion=MotionConfig(path="walk", rotation="heading"),
        )
        sim = simulate(cfg, seed=seed)
    else:
        raise InputError(f"pose must be 2d or 3d, got {pose!r}")
    sim.write(out / "scenario")
    ids = [r.receiver_id for r in sim.site.receivers]
    rng = np.random.default_rng(seed)
    pcaps = write_receiver_pcaps(
        sim.packets,
        out / "pcaps",
        rng=rng,
        clock_offset_s={r: float(rng.uniform(-0.5, 0.5)) for r in ids[1:]},
        drift_ppm={r: float(rng.uniform(-10, 10)) for r in ids[1:]},
        jitter_s=5e-6,
        epoch_s=1_000.0,
    )
    db_path = out / "live.db"
    for p in out.glob("live.db*"):
        p.unlink()
    db_url = f"sqlite:///{db_path}"
    db = Database(db_url)
    tokens = {"admin": create_token(db, "admin"), "viewer": create_token(db, "viewer")}
    for r in ids:
        tokens[r] = create_token(db, "receiver", r)
    db.close()

    base = f"http://127.0.0.1:{port}"
    children: list[subprocess.Popen[bytes]] = []
    log = open(out / "server.log", "wb")  # noqa: SIM115
    try:
        server = subprocess.Popen(
            serve_command(out / "scenario" / "site", db_url, port, method),
            stdout=subprocess.DEVNULL,
            stderr=log,
        )
        children.append(server)
        end = time.monotonic() + 60
        while True:
            if server.poll() is not None:
                log.flush()
                raise InputError(_stopped(out / "server.log", port))
            try:
                if (
                    httpx.get(
                        base + "/health",
                        timeout=1.0,
                        headers={"Authorization": f"Bearer {tokens['viewer']}"},
                    ).status_code
                    == 200
                ):
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > end:
                raise InputError("the server did not start within 60 s")
            time.sleep(0.2)
        echo(f"dashboard: {base}/#token={tokens['viewer']}")
        echo(f"admin token: {tokens['admin']}")
        echo(f"API docs: {base}/docs · database {db_path} · server log {out / 'server.log'}")
        for r in ids:
            children.append(
                subprocess.Popen(
                    replay_command(
                        base, tokens[r], r, pcaps.paths[r], speed, out / "spool", quiet=True
                    ),
                )
            )
        walk = "hand-held 3-D walk" if pose == "3d" else "walk"
        echo(
            f"{len(ids)} receiver agents replaying a {duration_s:g} s {walk} (a packet every "
            f"{interval_ms:g} ms) at {speed:g}x; the server tracks it with {method!r}; "
            "Ctrl-C stops"
        )
        t0 = time.monotonic()
        while stop_after_s is None or time.monotonic() - t0 < stop_after_s:
            time.sleep(0.2)
    except KeyboardInterrupt:
        echo("stopping…")
    finally:
        for child in reversed(children):
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        for child in children:
            try:
                child.wait(15)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        log.close()
    echo("stopped")
    return {"url": f"{base}/", **tokens}


def _stopped(log_path: Path, port: int) -> str:
    """Why the demo's server stopped, one line: the last line of its log that
    says (the ``radiopose: …`` line of a refused start, e.g. an unknown method),
    else the port guess."""
    try:
        lines = log_path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        lines = []
    said = [ln.strip() for ln in lines if ln.startswith("radiopose: ")]
    if said:
        return f"the server stopped: {said[-1].removeprefix('radiopose: ')} (see {log_path})"
    bound = any("address already in use" in ln.lower() for ln in lines)
    hint = f"port {port} is taken; try --port" if bound else f"is port {port} free? try --port"
    return f"the server stopped (see {log_path}); {hint}"
