"""``radiopose import``: public datasets in the interchange format (``docs/real-data.md``)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app

import_app = typer.Typer(
    help="Import a public dataset into a site and tracks (interchange format).",
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
)
app.add_typer(import_app, name="import", short_help="Import a public dataset (tetam).")


@import_app.command(short_help="The BLE tracking dataset: OUT/site/ and OUT/tracks/<name>/.")
def tetam(
    dataset: Annotated[
        Path,
        typer.Argument(
            help="The dataset directory (cnf/, hst/, trk/ as in ../shared/data/ble-tetam)."
        ),
    ],
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")],
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No summary.")] = False,
) -> None:
    """Write OUT/site/ (survey from the histograms), and for every trk/*_all_sensors.mbd,
    OUT/tracks/<name>/packets.csv, truth.csv and heldout-site/ (the site with the other
    tracks' readings added to the survey: localise a track with it, never with its own data).
    All or nothing: on an error nothing is written."""
    from radiopose.realdata.build import import_tetam, shipped_import_settings

    summary = import_tetam(dataset, out, shipped_import_settings())
    if not quiet:
        for line in summary.lines():
            print(line, file=sys.stderr)
    print(f"wrote {out}/site and {len(summary.packets)} tracks in {out}/tracks", file=sys.stderr)
