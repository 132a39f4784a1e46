"""``radiopose enrol`` and ``radiopose pattern import|plot``: parsing and printing only.

The work lives in :mod:`radiopose.patterns` (enrolment, importers, plots).
Every output is computed in full before anything is written, and each file is
written atomically, so a failure leaves no partial output (a device or pipe given
as ``--plot`` cannot be staged: it is written directly, last).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app
from radiopose.errors import InputError
from radiopose.patterns.enrol import EnrolConfig, enrol_csv
from radiopose.patterns.importers import read_basta_json, read_mitll, read_msi
from radiopose.patterns.pattern import Pattern, read_pattern_csv, write_pattern_csv
from radiopose.tables import atomic_writer, check_outputs_not_inputs

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


def _new_parents(path: Path) -> list[Path]:
    """Create the missing parent directories of ``path``; return them, outermost first."""
    missing: list[Path] = []
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    created: list[Path] = []
    try:
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
    except OSError as exc:
        _remove_dirs(created)
        reason = (
            "a parent is not a directory"
            if isinstance(exc, (FileExistsError, NotADirectoryError))
            else exc.strerror
        )
        raise InputError(f"cannot create the file: {reason}", path=path) from None
    if not path.parent.is_dir():
        raise InputError("cannot create the file: a parent is not a directory", path=path)
    return created


def _remove_dirs(created: list[Path]) -> None:
    for d in reversed(created):
        with contextlib.suppress(OSError):
            d.rmdir()


def _check_target(path: Path, what: str) -> None:
    if path.is_dir():
        raise InputError(f"is a directory, expected a {what} file path", path=path)


def _check_png_name(path: Path, option: str) -> None:
    """A figure path must end in ``.png`` (the figure is always a PNG): ``--plot o.xyz``
    wrote a PNG under that name. An existing device or pipe (``/dev/null``) is accepted
    under any name and written directly (see :func:`_write_outputs`)."""
    if path.suffix.lower() != ".png" and not (path.is_char_device() or path.is_fifo()):
        raise InputError(f"{option} writes a PNG: give a file name ending in .png", path=path)


def _check_plot(plot: Path | None) -> None:
    """Before the input is read: a ``--plot`` path is not a directory and names a PNG."""
    if plot is not None:
        _check_target(plot, "PNG")
        _check_png_name(plot, "--plot")


def _write_outputs(pattern: Pattern, output: Path, plot: Path | None) -> None:
    """Write the pattern CSV and, if asked, its PNG: both or neither.

    The figure is rendered and written to a temporary file beside its target
    first, then the CSV is written atomically, then the figure is renamed into
    place. On any failure the temporary file, a CSV this call created and any
    directories it created are removed (a CSV that existed before is replaced
    only when everything else has already succeeded).

    A figure target that exists and is not a regular file (a device, a FIFO) is
    not staged: renaming over it would replace the node with a file. It is
    written directly, through :func:`radiopose.tables.atomic_writer`, after the
    CSV, so a reader of the pipe gets nothing when the CSV fails. If that last
    write fails, a CSV this call created is removed; one that existed before
    has already been replaced.
    """
    _check_target(output, "CSV")
    if plot is not None and plot.resolve() == output.resolve():  # the rest: _check_plot
        raise InputError("--plot is the same file as -o", path=plot)
    png = None
    if plot is not None:
        from radiopose.patterns.plot import pattern_png  # matplotlib only when asked

        png = pattern_png(pattern)
    direct = plot is not None and plot.exists() and not plot.is_file()
    created: list[Path] = []
    tmp: Path | None = None
    csv_is_new = not output.exists()
    csv_written = False
    try:
        if png is not None and plot is not None and not direct:
            created += _new_parents(plot)
            try:
                fd, name = tempfile.mkstemp(prefix=f".{plot.name}.", suffix=".tmp", dir=plot.parent)
            except OSError as exc:
                raise InputError(f"cannot write ({exc.strerror})", path=plot) from None
            tmp = Path(name)
            with os.fdopen(fd, "wb") as fh:
                fh.write(png)
        created += _new_parents(output)
        write_pattern_csv(pattern, output)
        csv_written = True
        if tmp is not None and plot is not None:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600
            os.replace(tmp, plot)
            tmp = None
        elif png is not None and plot is not None:  # a device or pipe: written in place
            try:
                with atomic_writer(plot, "wb") as fh:
                    fh.write(png)
            except OSError as exc:
                raise InputError(f"cannot write ({exc.strerror})", path=plot) from None
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        if csv_written and csv_is_new:
            with contextlib.suppress(OSError):
                output.unlink()
        _remove_dirs(created)
        raise


def _enrol_config(**options: float | None) -> EnrolConfig:
    """An :class:`EnrolConfig` whose errors name the command-line option, not the attribute."""
    try:
        return EnrolConfig(**options)  # type: ignore[arg-type]
    except InputError as exc:
        option = _CONFIG_OPTIONS.get(exc.column or "")
        if option is None or exc.path is not None:
            raise
        raise InputError(exc.reason, column=option) from None


_CONFIG_OPTIONS = {
    "smooth_deg": "--smooth-deg",
    "azimuth_step_deg": "--step-deg",
    "polar_step_deg": "--polar-step-deg",
}


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
        float,
        typer.Option("--step-deg", help="Output azimuth grid step, degrees (divides 360, >= 0.1)."),
    ] = 1.0,
    polar_step_deg: Annotated[
        float | None,
        typer.Option(
            "--polar-step-deg",
            help="Output polar step for a full sphere, degrees (divides 180, >= 0.1; "
            "default: measured spacing).",
            show_default=False,
        ),
    ] = None,
    plot: _PlotOption = None,
    name: _NameOption = None,
) -> None:
    """Enrol a radiation pattern from positioner RSS measurements."""
    config = _enrol_config(
        smooth_deg=smooth_deg, azimuth_step_deg=step_deg, polar_step_deg=polar_step_deg
    )
    check_outputs_not_inputs([output, plot], [measurements])
    _check_plot(plot)
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
        MsiMode | None,
        typer.Option(
            "--msi-mode",
            help="msi: horizontal cut as a slice, or a full sphere.",
            show_default="horizontal",
        ),
    ] = None,
    normalise: Annotated[
        bool | None,
        typer.Option(
            "--normalise/--keep-gain",
            help="msi/basta: rescale to mean intensity 0 dBi instead of the file's gain (dBi).",
            show_default="--keep-gain",
        ),
    ] = None,
    smooth_deg: Annotated[
        float | None,
        typer.Option(
            "--smooth-deg", help="mitll: smoothing half-width, degrees.", show_default="5"
        ),
    ] = None,
    step_deg: Annotated[
        float | None,
        typer.Option("--step-deg", help="mitll: output azimuth step, degrees.", show_default="1"),
    ] = None,
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
    given = {
        "--msi-mode": msi_mode is not None,
        "--normalise/--keep-gain": normalise is not None,
        "--smooth-deg": smooth_deg is not None,
        "--step-deg": step_deg is not None,
        "--mac": mac is not None,
    }
    applies = {
        ImportFormat.msi: ("--msi-mode", "--normalise/--keep-gain"),
        ImportFormat.basta: ("--normalise/--keep-gain",),
        ImportFormat.mitll: ("--smooth-deg", "--step-deg", "--mac"),
    }[fmt]
    stray = [option for option, on in given.items() if on and option not in applies]
    if stray:  # an option the format does not read would be ignored without a word
        raise InputError(f"{', '.join(stray)} does not apply to --format {fmt.value}")
    check_outputs_not_inputs([output, plot], [source])
    _check_plot(plot)
    pname = name or output.stem
    if fmt is ImportFormat.msi:
        sphere = msi_mode is MsiMode.sphere
        pattern = read_msi(
            source, mode="sphere" if sphere else "horizontal", normalise=bool(normalise), name=pname
        )
    elif fmt is ImportFormat.basta:
        pattern = read_basta_json(source, normalise=bool(normalise), name=pname)
    else:
        config = _enrol_config(
            smooth_deg=5.0 if smooth_deg is None else smooth_deg,
            azimuth_step_deg=1.0 if step_deg is None else step_deg,
        )
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

    check_outputs_not_inputs([output], [pattern_csv])
    _check_png_name(output, "-o")
    pattern = read_pattern_csv(pattern_csv)
    png = pattern_png(pattern)
    with atomic_writer(output, "wb") as fh:
        fh.write(png)
    typer.echo(f"{output}: polar plot of {pattern.name}")
