"""``radiopose serve``, ``token create``, ``receiver`` and ``db export``."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app
from radiopose.errors import InputError

DEFAULT_DB = "radiopose.db"

token_app = typer.Typer(help="Bearer tokens of the live server.", no_args_is_help=True)
db_app = typer.Typer(help="The live server's database.", no_args_is_help=True)
app.add_typer(token_app, name="token")
app.add_typer(db_app, name="db")


def _url(db: str) -> str:
    """A SQLAlchemy URL; a plain path means a SQLite file."""
    return db if "://" in db else f"sqlite:///{db}"


def _database(db: str):
    try:
        from radiopose.server.db import Database
    except ModuleNotFoundError as exc:
        raise InputError(
            f"the live server needs {exc.name}, which is missing: reinstall radiopose "
            "from its clone (pip install -e .)"
        ) from None
    return Database(_url(db))


def _sqlite_file(db: str) -> Path | None:
    """The file of a SQLite ``--db`` (a plain path or a ``sqlite:///`` URL), else
    ``None`` (another database, an in-memory one, or a URL SQLAlchemy cannot
    parse: opening it gives the error)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        url = make_url(_url(db))
    except (ArgumentError, ValueError):
        return None
    if url.get_backend_name() != "sqlite" or url.database in (None, "", ":memory:"):
        return None
    return Path(url.database)


def _existing_database(db: str):
    """The server database ``db`` for a command that only reads it: a SQLite file
    that does not exist is a one-line error (opening it would create an empty one)."""
    path = _sqlite_file(db)
    if path is not None and not path.is_file():
        raise InputError(f"--db {db}: no such database file (this command reads a server's)")
    return _database(db)


def _partition(value: str) -> tuple[int, int]:
    try:
        k, n = (int(v) for v in value.split("/"))
    except ValueError:
        raise InputError(f"--partition must be K/N, e.g. 0/2, got {value!r}") from None
    if not (n >= 1 and 0 <= k < n):
        raise InputError(f"--partition {value}: need 0 <= K < N")
    return k, n


@app.command(short_help="The central server: API, live tracking, dashboard.")
def serve(
    site: Annotated[Path, typer.Argument(help="Site directory, imported into the database.")],
    db: Annotated[
        str, typer.Option(help="SQLAlchemy URL or SQLite file (default ./radiopose.db).")
    ] = DEFAULT_DB,
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port.")] = 8000,
    method: Annotated[
        str | None,
        typer.Option(
            help="Tracker method: full, location, orientation, top, lms, filter or a "
            "plugin's (docs/methods.md) (default: SITE/tracker.toml's live_method, else "
            "full at a 2-D site and filter at a 3-D one)."
        ),
    ] = None,
    live_lag_s: Annotated[
        float,
        typer.Option(
            "--live-lag-s",
            help="Fixed lag of the filter's smoother, s (0: causal; at most 0.25).",
        ),
    ] = 0.25,
    partition: Annotated[
        str, typer.Option(help="K/N: track the K-th of N transmitter partitions.")
    ] = "0/1",
    ssl_certfile: Annotated[
        Path | None, typer.Option("--ssl-certfile", help="TLS certificate (PEM).")
    ] = None,
    ssl_keyfile: Annotated[
        Path | None, typer.Option("--ssl-keyfile", help="TLS private key (PEM).")
    ] = None,
    calibration_s: Annotated[
        float, typer.Option("--calibration-s", help="Clock calibration window, seconds.")
    ] = 3.0,
    idle_flush_s: Annotated[
        float, typer.Option("--idle-flush-s", help="Close open packets after this pause, s.")
    ] = 5.0,
    no_pipeline: Annotated[
        bool, typer.Option("--no-pipeline", help="API only: leave localisation to others.")
    ] = False,
    log_level: Annotated[str, typer.Option("--log-level", help="Log level.")] = "info",
) -> None:
    """The central server: API, live localisation and dashboard (Ctrl-C stops)."""

    from radiopose.server.app import create_app, import_site_dir
    from radiopose.server.jsonlog import configure_logging
    from radiopose.server.live import MAX_LIVE_LAG_S, LiveConfig
    from radiopose.server.sitestore import build_site
    from radiopose.tracker import METHODS, TrackerConfig, default_live_method
    from radiopose.tracker_settings import (
        apply_tracker_settings,
        load_site_live_method,
        load_site_settings,
    )

    if method is not None and method not in METHODS:
        raise InputError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    # the method: --method, else the site's tracker.toml live_method, else (None) the
    # default at the site the pipeline runs, which follows the stored site's admin edits
    method = method or load_site_live_method(site)
    tracker = None
    settings, settings_path = load_site_settings(site)
    if settings_path is not None:  # the site's priors for the filter ([filter], [filter.pose3d])
        tracker = apply_tracker_settings(TrackerConfig(), settings, batch=False)
    if not 0 <= live_lag_s <= MAX_LIVE_LAG_S:
        raise InputError(f"--live-lag-s must lie in [0, {MAX_LIVE_LAG_S}], got {live_lag_s!r}")
    k, n = _partition(partition)
    if (ssl_certfile is None) != (ssl_keyfile is None):
        raise InputError("--ssl-certfile and --ssl-keyfile go together")
    if ssl_certfile is not None and ssl_keyfile is not None:
        _check_tls(ssl_certfile, ssl_keyfile)
    if not (calibration_s > 0 and idle_flush_s > 0):
        raise InputError("--calibration-s and --idle-flush-s must be > 0")
    if not 0 < port < 65536:
        raise InputError(f"--port must be 1-65535, got {port}")
    import uvicorn

    configure_logging(log_level)
    database = _database(db)
    database.check_writable()  # a read-only file: one line now, not at the first report
    status = import_site_dir(database, site)
    scheme = "https" if ssl_certfile else "http"
    print(
        f"site {site}: {status} (version {database.site_version()}); database {database.url}",
        flush=True,
    )
    shown = method or default_live_method(build_site(database.site_rows()))
    print(
        f"live method {shown}"
        + ("" if method else " (the default at this site)")
        + (f" (lag {live_lag_s:g} s)" if METHODS[shown].lagged else "")
        + ("" if settings_path is None else f", tracker settings from {settings_path}"),
        flush=True,
    )
    print(f"serving on {scheme}://{host}:{port}/ (API docs: /docs)", flush=True)
    live = LiveConfig(
        method=method,
        tracker=tracker,
        live_lag_s=live_lag_s,
        partition=k,
        partitions=n,
        calibration_s=calibration_s,
        idle_flush_s=idle_flush_s,
    )
    application = create_app(database, live, run_pipeline=not no_pipeline, pipeline_mode="process")
    try:
        uvicorn.run(
            application,
            host=host,
            port=port,
            log_config=None,
            access_log=False,
            timeout_graceful_shutdown=3,
            ssl_certfile=None if ssl_certfile is None else str(ssl_certfile),
            ssl_keyfile=None if ssl_keyfile is None else str(ssl_keyfile),
        )
    finally:
        database.close()


def _check_tls(certfile: Path, keyfile: Path) -> None:
    """Load the certificate and key as uvicorn will, before anything starts: a
    missing, unreadable or malformed file is one line naming the option and the
    file (ssl's own messages name neither: "[SSL] PEM lib (_ssl.c:3905)")."""
    import ssl

    from radiopose.errors import InputError

    for option, path in (("--ssl-certfile", certfile), ("--ssl-keyfile", keyfile)):
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            raise InputError(f"{option} {path}: {exc.strerror or exc}") from None
    try:
        # (a password callback: an encrypted key is refused here, not prompted for twice)
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(
            str(certfile), str(keyfile), password=lambda: b""
        )
    except ssl.SSLError as exc:
        raise InputError(
            f"--ssl-certfile {certfile} / --ssl-keyfile {keyfile}: not a PEM certificate "
            f"and its private key ({exc.reason or exc})"
        ) from None


@token_app.command("create")
def token_create(
    db: Annotated[str, typer.Option(help="SQLAlchemy URL or SQLite file of the server.")],
    role: Annotated[str, typer.Option(help="admin, receiver or viewer.")],
    receiver: Annotated[
        str | None, typer.Option(help="The receiver a receiver token may post as.")
    ] = None,
) -> None:
    """Print a new bearer token on stdout (stored hashed)."""
    from radiopose.server.auth import check_role, create_token

    check_role(role, receiver)
    path = _sqlite_file(db)
    new = path is not None and not path.exists()
    database = _database(db)
    try:
        print(create_token(database, role, receiver))
    finally:
        database.close()
    if new:  # a token for a server yet to start there, or a mistyped --db
        print(
            f"radiopose: note: {path} did not exist; created a new database for this token",
            file=sys.stderr,
        )


@app.command(short_help="Ship one receiver's frame reports to the server.")
def receiver(
    server: Annotated[str, typer.Option(help="Server URL, e.g. http://127.0.0.1:8000.")],
    token: Annotated[str, typer.Option(help="This receiver's bearer token.")],
    id: Annotated[str, typer.Option("--id", help="Receiver id (as in receivers.csv).")],
    replay: Annotated[
        Path | None, typer.Option(help="Send this capture (pcap, pcapng or CSV), then exit.")
    ] = None,
    speed: Annotated[float, typer.Option(help="Replay speed, times real time.")] = 1.0,
    interface: Annotated[
        str | None, typer.Option(help="Capture live from this monitor-mode interface.")
    ] = None,
    spool: Annotated[
        Path | None,
        typer.Option(
            help="Directory for batches the server has not acknowledged; default: a "
            "per-user data directory, $XDG_DATA_HOME/radiopose/spool "
            "(~/.local/share/radiopose/spool when XDG_DATA_HOME is unset).",
            show_default=False,
        ),
    ] = None,
    batch_ms: Annotated[float, typer.Option("--batch-ms", help="Batching period, ms.")] = 100.0,
    quiet: Annotated[bool, typer.Option("-q", "--quiet", help="No summary line.")] = False,
) -> None:
    """Ship one receiver's frame reports to the central server."""
    import threading

    if (replay is None) == (interface is None):
        raise InputError("give exactly one of --replay CAPTURE or --interface IFACE")
    if not server.startswith(("http://", "https://")):
        raise InputError(f"--server must be an http:// or https:// URL, got {server!r}")
    from radiopose.ids import receiver_id_problem

    if (problem := receiver_id_problem(id)) is not None:
        raise InputError(f"--id: {problem}")
    if not 1.0 <= batch_ms <= 10_000.0:
        raise InputError(f"--batch-ms must be 1-10000, got {batch_ms}")
    if replay is not None and not speed > 0:
        raise InputError(f"--speed must be > 0, got {speed}")
    if replay is not None and speed * batch_ms / 1000.0 > 1.0:
        typer.echo(
            f"radiopose: warning: --speed {speed:g} puts {speed * batch_ms / 1000.0:g} s of "
            "capture in each batch; receivers replayed side by side then drift apart by "
            "seconds of capture, and the server drops the frames of one more than 5 s "
            f"(max_lag_s) behind the leading one as late: --speed {1000.0 / batch_ms:g} or "
            "less keeps them",
            err=True,
        )
    try:
        from radiopose.receiver import (
            AgentConfig,
            ReceiverAgent,
            capture_interface,
            default_spool_dir,
            replay_frames,
            run_replay,
        )

        frames = replay_frames(replay, id) if replay is not None else None
        agent = ReceiverAgent(
            AgentConfig(
                server,
                token,
                id,
                spool_dir=default_spool_dir() if spool is None else spool,
                batch_interval_s=batch_ms / 1000.0,
            )
        )
    except ModuleNotFoundError as exc:
        raise InputError(
            f"the receiver needs httpx ({exc.name} is missing): reinstall radiopose"
        ) from None
    stop = threading.Event()
    try:
        if not agent.refresh_transmitters():
            print(
                f"radiopose: {server} unreachable; spooling to {agent.spool.dir} until it answers",
                file=sys.stderr,
            )
        if frames is not None:
            run_replay(agent, frames, speed=speed, stop=stop)
        else:
            capture_interface(agent, interface or "", stop=stop)
        agent.drain()
    except KeyboardInterrupt:
        stop.set()
        agent.close()
        left = agent.pending()
        print(
            f"radiopose: interrupted; {left} batches kept in {agent.spool.dir} "
            "(sent on the next run)",
            file=sys.stderr,
        )
        raise typer.Exit(130) from None
    agent.close()
    st = agent.stats
    if not quiet:
        print(
            f"receiver {id}: {st.frames_in} frames, {st.batches_acked} batches acknowledged "
            f"({st.duplicates} already stored, {st.resends} retries, {st.spooled} spooled, "
            f"{st.rejected} rejected, {st.frames_filtered} frames of unenrolled transmitters "
            "not sent)",
            file=sys.stderr,
        )
    if st.rejected:
        raise InputError(
            f"{st.rejected} batches were rejected by the server (the last: "
            f"{st.last_rejection}); kept in {agent.spool.dir / 'rejected'}"
        )


@db_app.command("export")
def db_export(
    db: Annotated[str, typer.Option(help="SQLAlchemy URL or SQLite file of the server.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory.")],
) -> None:
    """Export the run: site/, frames.csv, packets.csv, estimates.csv (replayable)."""
    from radiopose.server.export import export_run

    database = _existing_database(db)
    try:
        for p in export_run(database, out):
            print(p)
    finally:
        database.close()
