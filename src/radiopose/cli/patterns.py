"""``radiopose enrol`` and ``radiopose pattern import|plot``: parsing and printing only.

The work lives in :mod:`radiopose.patterns` (enrolment, importers, plots).
Every output is computed in full before anything is written, and each file is
written atomically, so a failure leaves no partial output.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app
from radiopose.errors import InputError
from radiopose.patterns.enrol import EnrolConfig, enrol_csv
from radiopose.patterns.importers import read_basta_json, read_mitll, read_msi
from radiopose.patterns.pattern import Pattern, read_pattern_csv, write_pattern_csv
from radiopose.tables import atomic_writer

pattern_app = typer.Typer(
    name="pattern",
    help="Radiation patterns: import industry files and real measurements, plot.",
    short_help="Radiation patterns: import files and measurements, plot.",
    no_args_is_help=True,
)
app.add_typer(pattern_app, name="pattern")


# Options shared by ``enrol`` and ``pattern import`` (typer copies each use).
_PatternOutput = Annotated[
    Path, typer.Option("-o", "--output", help="Pattern CSV to write.", show_default=False)
]
_PlotOption = Annotated[
    Path | None,
    typer.Option("--plot", help="Also write a PNG polar plot here.", show_default=False),
]
_NameOption = Annotated[
    str | None, typer.Option("--name", help="Pattern name (default: output file stem).")
]


class ImportFormat(StrEnum):
    """Formats accepted by ``radiopose pattern import``."""

    msi = "msi"
    basta = "basta"
    mitll = "mitll"


class MsiMode(StrEnum):
    """What to build from an MSI file's two cuts."""

    horizontal = "horizontal"
    sphere = "sphere"


def _write_outputs(pattern: Pattern, output: Path, plot: Path | None) -> None:
    png = None
    if plot is not None:
        from radiopose.patterns.plot import pattern_png  # matplotlib only when asked

        png = pattern_png(pattern)
    if output.exists() and output.is_dir():
        raise InputError("is a directory, expected a CSV file path", path=output)
    write_pattern_csv(pattern, output)
    if png is not None and plot is not None:
        with atomic_writer(plot, "wb") as fh:
            fh.write(png)


def _summary(pattern: Pattern, output: Path) -> None:
    lo, hi = pattern.range_dbi
    shape = "slice" if pattern.is_slice else f"{pattern.polar_deg.size} polar rows"
    typer.echo(
        f"{output}: {pattern.azimuth_deg.size} azimuths × {shape}, "
        f"directivity {lo:.2f} … {hi:.2f} dBi"
    )


@app.command("enrol")
def enrol_command(
    measurements: Annotated[
        Path,
        typer.Argument(
            help="Enrolment CSV: motor_azimuth_deg, motor_elevation_deg, rss_dbm.",
            show_default=False,
        ),
    ],
    output: _PatternOutput,
    smooth_deg: Annotated[
        float,
        typer.Option(
            "--smooth-deg", help="Half-width of the circular smoothing window, degrees (0 = off)."
        ),
    ] = 5.0,
    step_deg: Annotated[
        float, typer.Option("--step-deg", help="Output azimuth grid step, degrees (divides 360).")
    ] = 1.0,
    polar_step_deg: Annotated[
        float | None,
        typer.Option(
            "--polar-step-deg",
            help="Output polar step for a full sphere, degrees (default: measured spacing).",
            show_default=False,
        ),
    ] = None,
    plot: _PlotOption = None,
    name: _NameOption = None,
) -> None:
    """Enrol a radiation pattern from positioner RSS measurements."""
    config = EnrolConfig(
        smooth_deg=smooth_deg, azimuth_step_deg=step_deg, polar_step_deg=polar_step_deg
    )
    pattern = enrol_csv(measurements, config, name=name or output.stem)
    _write_outputs(pattern, output, plot)
    _summary(pattern, output)


@pattern_app.command("import")
def import_command(
    source: Annotated[
        Path,
        typer.Argument(
            help="Pattern file (.msi, BASTA .json) or, for mitll, a directory of captures.",
            show_default=False,
        ),
    ],
    output: _PatternOutput,
    fmt: Annotated[
        ImportFormat, typer.Option("--format", help="Input format.", show_default=False)
    ],
    msi_mode: Annotated[
        MsiMode,
        typer.Option("--msi-mode", help="msi: horizontal cut as a slice, or a full sphere."),
    ] = MsiMode.horizontal,
    normalise: Annotated[
        bool,
        typer.Option(
            "--normalise/--keep-gain",
            help="msi/basta: rescale to mean intensity 0 dBi instead of the file's gain (dBi).",
        ),
    ] = False,
    smooth_deg: Annotated[
        float, typer.Option("--smooth-deg", help="mitll: smoothing half-width, degrees.")
    ] = 5.0,
    step_deg: Annotated[
        float, typer.Option("--step-deg", help="mitll: output azimuth step, degrees.")
    ] = 1.0,
    mac: Annotated[
        str | None,
        typer.Option(
            "--mac",
            help="mitll: advertiser address(es) to keep, comma-separated (default: the most "
            "frequent per file).",
        ),
    ] = None,
    plot: _PlotOption = None,
    name: _NameOption = None,
) -> None:
    """Import a pattern from an industry file or real measurements into the contract CSV."""
    pname = name or output.stem
    if fmt is ImportFormat.msi:
        pattern = read_msi(source, mode=msi_mode.value, normalise=normalise, name=pname)
    elif fmt is ImportFormat.basta:
        pattern = read_basta_json(source, normalise=normalise, name=pname)
    else:
        config = EnrolConfig(smooth_deg=smooth_deg, azimuth_step_deg=step_deg)
        pattern = read_mitll(source, config, mac=mac, name=pname)
    _write_outputs(pattern, output, plot)
    _summary(pattern, output)


@pattern_app.command("plot")
def plot_command(
    pattern_csv: Annotated[Path, typer.Argument(help="Pattern CSV to plot.", show_default=False)],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="PNG file to write.", show_default=False)
    ],
) -> None:
    """Plot a pattern: the 90° polar cut (plus a heat map for a full sphere) as PNG."""
    from radiopose.patterns.plot import pattern_png

    pattern = read_pattern_csv(pattern_csv)
    png = pattern_png(pattern)
    with atomic_writer(output, "wb") as fh:
        fh.write(png)
    typer.echo(f"{output}: polar plot of {pattern.name}")
