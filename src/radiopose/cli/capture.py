"""``radiopose sync``: receiver captures -> synchronised ``packets.csv``."""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Annotated, Any

import typer

from radiopose.cli import app

# Show a progress bar when the captures together are larger than this.
_PROGRESS_MIN_BYTES = 8 * 1024 * 1024


def _advance(bar: Any, task: Any, done: int) -> None:
    """Progress callback: ``done`` bytes of ``task`` read."""
    bar.update(task, completed=done)


def _receiver_map(pairs: list[str], captures: list[Path]) -> dict[Path, str]:
    from radiopose.errors import InputError
    from radiopose.ids import receiver_id_problem

    by_path = {p.resolve(): p for p in captures}
    out: dict[Path, str] = {}
    for item in pairs:
        rid, sep, file = item.partition("=")
        rid = rid.strip()
        if not sep or not rid or not file:
            raise InputError(f"--receiver expects ID=FILE, got {item!r}")
        if (problem := receiver_id_problem(rid)) is not None:
            raise InputError(f"--receiver {item!r}: {problem}")
        key = Path(file).resolve()
        if key not in by_path:
            raise InputError(f"--receiver {item!r}: unknown capture {file} (not among CAPTURE...)")
        if by_path[key] in out:
            raise InputError(
                f"--receiver {item!r}: {file} already named {out[by_path[key]]!r} by --receiver"
            )
        out[by_path[key]] = rid
    return out


@app.command(short_help="Match the receivers' captures into packets.csv.")
def sync(
    captures: Annotated[
        list[Path],
        typer.Argument(
            help="Receiver captures: pcap/pcapng (radiotap) files, one per receiver, or CSV "
            "(receiver_id, timestamp_s, frame_sha256, transmitter, rss_dbm).",
            show_default=False,
            metavar="CAPTURE",
        ),
    ],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="packets.csv to write (atomically).")
    ],
    tolerance_ms: Annotated[
        float,
        typer.Option(
            "--tolerance-ms", help="Matching tolerance after clock correction, milliseconds."
        ),
    ] = 5.0,
    receiver: Annotated[
        list[str] | None,
        typer.Option(
            "--receiver",
            metavar="ID=FILE",
            help="ID=FILE: receiver id of a pcap capture (default: the file name without "
            "extension). Repeatable.",
        ),
    ] = None,
    reference: Annotated[
        str | None,
        typer.Option(
            help="Reference receiver whose clock the others are mapped to (default: the "
            "first capture's receiver that kept any frame)."
        ),
    ] = None,
    max_drift_ppm: Annotated[
        float,
        typer.Option("--max-drift-ppm", help="Largest receiver clock drift considered, ppm."),
    ] = 500.0,
    quiet: Annotated[bool, typer.Option("-q", "--quiet", help="Do not print the summary.")] = False,
) -> None:
    """Match the frames of several receivers into packets (packets.csv).

    Frames are matched by the SHA-256 of their 802.11 bytes. Each receiver's
    clock offset and drift against the reference receiver are estimated from
    unambiguous matches first; then frames whose corrected times agree within
    the tolerance form a packet, unless a receiver has the frame twice.
    """
    from radiopose.capture.records import read_capture
    from radiopose.capture.sync import SyncConfig, synchronise
    from radiopose.errors import InputError, unreadable
    from radiopose.packets import write_packets_csv

    if not (tolerance_ms > 0 and tolerance_ms < 60_000):
        raise InputError(f"--tolerance-ms must be in (0, 60000), got {tolerance_ms}")
    if not max_drift_ppm >= 0:
        raise InputError(f"--max-drift-ppm must be >= 0, got {max_drift_ppm}")
    if len({p.resolve() for p in captures}) != len(captures):
        raise InputError("the same capture is given twice")
    if output.resolve() in {p.resolve() for p in captures}:
        raise InputError("-o would overwrite one of the captures", path=output)
    names = _receiver_map(receiver or [], captures)
    sizes = {}
    for p in captures:
        try:
            sizes[p] = os.stat(p).st_size
        except OSError as exc:
            raise unreadable(p, exc) from None

    caps = []
    if sum(sizes.values()) >= _PROGRESS_MIN_BYTES:
        from rich.console import Console
        from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            DownloadColumn(),
            console=Console(stderr=True),
            transient=True,
        ) as bar:
            for p in captures:
                task = bar.add_task(f"reading {p.name}", total=sizes[p])
                caps.append(
                    read_capture(
                        p,
                        names.get(p),
                        progress=functools.partial(_advance, bar, task),
                    )
                )
                bar.update(task, completed=sizes[p])
    else:
        caps = [read_capture(p, names.get(p)) for p in captures]

    if not any(c.stats for c in caps):  # (only CSV captures name no receiver without rows)
        from radiopose.errors import InputError

        shown = ", ".join(str(p) for p in captures[:3]) + (" …" if len(captures) > 3 else "")
        raise InputError(f"no frames of any receiver in {shown} (CSV captures with a header only?)")
    cfg = SyncConfig(
        tolerance_s=tolerance_ms / 1e3, reference=reference, max_drift_ppm=max_drift_ppm
    )
    packets, report = synchronise(caps, cfg)
    write_packets_csv(packets, output)
    if not quiet:
        for line in report.lines():
            typer.echo(line)
        typer.echo(f"wrote {output} ({len(packets)} rows)")
