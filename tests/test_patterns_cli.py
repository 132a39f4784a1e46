"""``radiopose enrol`` and ``radiopose pattern import|plot``: outputs, one-line errors."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from radiopose.cli import main
from radiopose.patterns import smartphone_like
from radiopose.patterns.enrol import (
    Measurements,
    simulate_positioner_measurements,
    write_measurements_csv,
)
from radiopose.patterns.pattern import read_pattern_csv

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MSI_NAME = "python_antenna_pattern_simulated_05T.msi"


@pytest.fixture
def measurements_csv(tmp_path: Path) -> Path:
    rng = np.random.default_rng(7)
    true = smartphone_like(rng)
    m = simulate_positioner_measurements(true, rng, azimuth_step_deg=5.0, samples_per_direction=3)
    path = tmp_path / "meas.csv"
    write_measurements_csv(m, path)
    return path


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def _assert_one_line_failure(code: int, err: str, *fragments: str) -> None:
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("radiopose: ")
    for f in fragments:
        assert f in lines[0]


def test_enrol_writes_pattern_and_plot(measurements_csv, tmp_path, capsys):
    out, png = tmp_path / "out" / "phone.csv", tmp_path / "phone.png"
    code, stdout, err = _run(
        [
            "enrol",
            str(measurements_csv),
            "-o",
            str(out),
            "--smooth-deg",
            "3",
            "--step-deg",
            "2",
            "--plot",
            str(png),
        ],
        capsys,
    )
    assert code == 0, err
    p = read_pattern_csv(out)
    assert p.name == "phone" and p.is_slice and p.azimuth_deg.size == 180
    assert png.read_bytes().startswith(PNG_MAGIC)
    assert "dBi" in stdout


@pytest.mark.parametrize(
    ("content", "fragments"),
    [
        ("motor_azimuth_deg,rss_dbm\n0,-50\n", ("meas.csv:1", "motor_elevation_deg")),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,x\n", ("meas.csv:2", "rss_dbm")),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,nan\n", ("meas.csv:2",)),
        ("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,200,-50\n", ("motor_elevation_deg",)),
    ],
)
def test_enrol_bad_input_one_line_no_output(tmp_path, capsys, content, fragments):
    src = tmp_path / "meas.csv"
    src.write_text(content)
    out, png = tmp_path / "o" / "p.csv", tmp_path / "p.png"
    code, _, err = _run(["enrol", str(src), "-o", str(out), "--plot", str(png)], capsys)
    _assert_one_line_failure(code, err, *fragments)
    assert not out.exists() and not png.exists()
    assert not list(tmp_path.rglob("*.tmp"))


def test_enrol_bad_options_and_missing_file(measurements_csv, tmp_path, capsys):
    out = tmp_path / "p.csv"
    code, _, err = _run(["enrol", str(measurements_csv), "-o", str(out), "--step-deg", "7"], capsys)
    _assert_one_line_failure(code, err, "azimuth step 7")
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--smooth-deg", "-1"], capsys
    )
    _assert_one_line_failure(code, err, "smoothing half-width")
    code, _, err = _run(["enrol", str(tmp_path / "none.csv"), "-o", str(out)], capsys)
    _assert_one_line_failure(code, err, "file not found")
    assert not out.exists()


def test_enrol_existing_output_is_untouched_on_failure(tmp_path, capsys):
    src = tmp_path / "meas.csv"
    src.write_text("motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-50\n5,90,bad\n")
    out = tmp_path / "p.csv"
    out.write_text("previous\n")
    code, _, err = _run(["enrol", str(src), "-o", str(out)], capsys)
    _assert_one_line_failure(code, err, "meas.csv:3")
    assert out.read_text() == "previous\n"


def test_enrol_refuses_a_quarter_circle_and_hints_at_radians(tmp_path, capsys):
    out = tmp_path / "p.csv"
    for name, step, fragment in (
        ("m_q.csv", 1.0, "measurements leave motor azimuths 90–360° (a 270° gap) unmeasured"),
        ("m_radians.csv", 0.01, "radians? motor_azimuth_deg is in degrees"),
    ):
        src = tmp_path / name
        top = 90.0 if step == 1.0 else 6.28
        az = np.arange(0.0, top + step / 2, step)
        write_measurements_csv(
            Measurements(az, np.full(az.size, 90.0), np.full(az.size, -50.0)), src
        )
        code, _, err = _run(["enrol", str(src), "-o", str(out)], capsys)
        assert code == 2
        _assert_one_line_failure(code, err, f"{src}, column 'motor_azimuth_deg': ", fragment)
        assert not out.exists()


def _files(root: Path) -> set[Path]:
    return set(root.rglob("*"))


@pytest.mark.parametrize("bad_plot", ["dir", "under_file", "same_as_output"])
def test_enrol_plot_failure_writes_nothing(measurements_csv, tmp_path, capsys, bad_plot):
    (tmp_path / "plots").mkdir()
    (tmp_path / "a_file").write_text("x")
    out = tmp_path / "new" / "deeper" / "p.csv"
    plot = {
        "dir": tmp_path / "plots",
        "under_file": tmp_path / "a_file" / "sub" / "p.png",
        "same_as_output": out,
    }[bad_plot]
    before = _files(tmp_path)
    code, stdout, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(plot)], capsys
    )
    _assert_one_line_failure(code, err, str(plot))
    assert stdout == ""
    assert _files(tmp_path) == before  # no CSV, no PNG, no temporary file, no new directory


def test_pattern_import_plot_failure_writes_nothing(shared_data, tmp_path, capsys):
    msi = shared_data / "antenna-files" / MSI_NAME
    out = tmp_path / "bs.csv"
    out.write_text("previous\n")
    (tmp_path / "BADDIR").mkdir()
    before = _files(tmp_path)
    argv = ["pattern", "import", str(msi), "-o", str(out), "--format", "msi"]
    code, _, err = _run([*argv, "--plot", str(tmp_path / "BADDIR")], capsys)
    _assert_one_line_failure(code, err, "BADDIR", "is a directory")
    assert _files(tmp_path) == before and out.read_text() == "previous\n"


def test_csv_failure_after_the_figure_is_staged_removes_it(measurements_csv, tmp_path, capsys):
    (tmp_path / "a_file").write_text("x")
    plot = tmp_path / "figs" / "p.png"
    before = _files(tmp_path)
    bad_out = tmp_path / "a_file" / "p.csv"  # parent is a file: the CSV cannot be written
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(bad_out), "--plot", str(plot)], capsys
    )
    _assert_one_line_failure(code, err, str(bad_out))
    assert _files(tmp_path) == before


def test_figure_rename_failure_removes_the_new_csv(measurements_csv, tmp_path, capsys, monkeypatch):
    import radiopose.cli.patterns as cli_patterns

    out, plot = tmp_path / "p.csv", tmp_path / "p.png"
    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst) == plot:
            raise OSError(errno.EIO, "simulated failure", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(cli_patterns.os, "replace", failing_replace)
    before = _files(tmp_path)
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(plot)], capsys
    )
    _assert_one_line_failure(code, err, "simulated failure")
    assert _files(tmp_path) == before


def test_enrol_with_plot_into_new_directories(measurements_csv, tmp_path, capsys):
    out, plot = tmp_path / "a" / "b" / "p.csv", tmp_path / "c" / "d" / "p.png"
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(plot)], capsys
    )
    assert code == 0, err
    assert read_pattern_csv(out).name == "p"
    assert plot.read_bytes().startswith(PNG_MAGIC)
    assert not list(tmp_path.rglob("*.tmp"))
    mode = plot.stat().st_mode & 0o777
    assert mode == out.stat().st_mode & 0o777  # the figure gets the usual file mode


def test_pattern_import_msi_and_basta(shared_data, tmp_path, capsys):
    files = shared_data / "antenna-files"
    msi = next(files.glob("*.msi"))
    out = tmp_path / "bs.csv"
    code, _, err = _run(["pattern", "import", str(msi), "-o", str(out), "--format", "msi"], capsys)
    assert code == 0, err
    assert read_pattern_csv(out).range_dbi[1] == pytest.approx(19.09)
    basta = next(files.glob("*.json"))
    out2, png = tmp_path / "aa.csv", tmp_path / "aa.png"
    code, _, err = _run(
        [
            "pattern",
            "import",
            str(basta),
            "-o",
            str(out2),
            "--format",
            "basta",
            "--normalise",
            "--plot",
            str(png),
        ],
        capsys,
    )
    assert code == 0, err
    p = read_pattern_csv(out2)
    assert p.polar_deg.size == 181 and p.range_dbi[1] == pytest.approx(15.15, abs=0.01)
    assert png.read_bytes().startswith(PNG_MAGIC)


def test_pattern_import_mitll_and_plot(shared_data, tmp_path, capsys):
    src = shared_data / "phone-patterns-mitll" / "iPhone-11-2"
    out = tmp_path / "iphone-11.csv"
    code, _, err = _run(
        ["pattern", "import", str(src), "-o", str(out), "--format", "mitll"], capsys
    )
    assert code == 0, err
    assert read_pattern_csv(out).range_dbi == pytest.approx((-4.74, 4.88), abs=0.01)
    png = tmp_path / "plot" / "iphone.png"
    code, _, err = _run(["pattern", "plot", str(out), "-o", str(png)], capsys)
    assert code == 0, err
    assert png.read_bytes().startswith(PNG_MAGIC)


def test_pattern_import_bad_file_one_line(tmp_path, capsys):
    src = tmp_path / "x.msi"
    src.write_text("NAME x\nHORIZONTAL 1\n0 0\nVERTICAL 1\n0 0\n")
    out = tmp_path / "x.csv"
    code, _, err = _run(["pattern", "import", str(src), "-o", str(out), "--format", "msi"], capsys)
    _assert_one_line_failure(code, err, "x.msi", "GAIN")
    assert not out.exists()
    bad = tmp_path / "p.csv"
    bad.write_text("azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n0,90,2\n")
    code, _, err = _run(["pattern", "plot", str(bad), "-o", str(tmp_path / "p.png")], capsys)
    _assert_one_line_failure(code, err, "p.csv:3", "duplicate grid point")
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize(
    ("fmt", "options", "stray"),
    [
        ("mitll", ["--msi-mode", "sphere"], "--msi-mode"),
        ("mitll", ["--keep-gain"], "--normalise/--keep-gain"),
        ("msi", ["--mac", "aa:bb:cc:dd:ee:ff", "--step-deg", "2"], "--step-deg, --mac"),
        ("basta", ["--msi-mode", "horizontal"], "--msi-mode"),
    ],
)
def test_pattern_import_refuses_options_of_another_format(tmp_path, capsys, fmt, options, stray):
    """An option the chosen format does not read is refused before any work,
    not ignored (helper-63: --msi-mode with --format mitll did nothing)."""
    out = tmp_path / "x.csv"
    code, _, err = _run(
        ["pattern", "import", str(tmp_path / "absent"), "-o", str(out), "--format", fmt, *options],
        capsys,
    )
    _assert_one_line_failure(code, err, stray, f"does not apply to --format {fmt}")
    assert not out.exists()


def test_console_script_exit_status(tmp_path):
    src = tmp_path / "m.csv"
    src.write_text("motor_azimuth_deg,motor_elevation_deg\n0,90\n")
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from radiopose.cli import main; sys.exit(main())",
            "enrol",
            str(src),
            "-o",
            str(tmp_path / "o.csv"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "column 'rss_dbm'" in r.stderr
    assert not (tmp_path / "o.csv").exists()


def test_plot_functions_take_and_return_axes():
    import matplotlib.pyplot as plt

    from radiopose.patterns import dipole
    from radiopose.patterns.plot import pattern_png, plot_polar, plot_sphere

    phone = smartphone_like(np.random.default_rng(3))
    ax = plot_polar(phone)
    assert ax.name == "polar" and len(ax.lines) == 1
    again = plot_polar(phone.renamed("other"), ax=ax, linestyle="--")
    assert again is ax and len(ax.lines) == 2
    line = ax.lines[0].get_ydata()
    np.testing.assert_allclose(line[:-1], phone.directivity_dbi[:, 0])
    assert line[-1] == line[0]  # closed curve
    sphere = dipole(azimuth_step_deg=5.0, polar_step_deg=5.0)
    hm = plot_sphere(sphere)
    assert hm.get_xlabel().startswith("pattern azimuth")
    with pytest.raises(ValueError, match="polar Axes"):
        plot_polar(phone, ax=hm)
    plt.close("all")
    assert pattern_png(sphere).startswith(PNG_MAGIC)


@pytest.mark.parametrize(
    ("args", "option", "what"),
    [
        (["--polar-step-deg", "1e-7"], "--polar-step-deg", "polar step 1e-07 deg is finer"),
        (["--step-deg", "1e-9"], "--step-deg", "azimuth step 1e-09 deg is finer"),
        (["--smooth-deg", "-1"], "--smooth-deg", "smoothing half-width"),
    ],
)
def test_enrol_grid_limit_names_the_option(measurements_csv, tmp_path, capsys, args, option, what):
    out = tmp_path / "p.csv"
    code, _, err = _run(["enrol", str(measurements_csv), "-o", str(out), *args], capsys)
    assert code == 2
    _assert_one_line_failure(code, err, f"radiopose: column '{option}': {what}")
    assert not out.exists()


def test_enrol_inferred_polar_step_names_the_row(tmp_path, capsys):
    src = tmp_path / "m.csv"
    src.write_text(
        "motor_azimuth_deg,motor_elevation_deg,rss_dbm\n0,90,-40\n90,90,-41\n180,90.001,-42\n"
    )
    out = tmp_path / "p.csv"
    code, _, err = _run(["enrol", str(src), "-o", str(out)], capsys)
    assert code == 2
    _assert_one_line_failure(
        code,
        err,
        f"{src}:4, column 'motor_elevation_deg': elevations 90 and 90.001 deg imply a polar "
        "step of 0.001 deg, finer than the 0.1 deg limit",
    )
    assert not out.exists()


def test_pattern_import_mitll_step_limit_names_the_option(shared_data, tmp_path, capsys):
    src = shared_data / "phone-patterns-mitll" / "iPhone-11-2"
    out = tmp_path / "p.csv"
    code, _, err = _run(
        ["pattern", "import", str(src), "-o", str(out), "--format", "mitll", "--step-deg", "1e-9"],
        capsys,
    )
    assert code == 2
    _assert_one_line_failure(code, err, "column '--step-deg': azimuth step 1e-09 deg is finer")
    assert not out.exists()


def test_a_figure_not_named_png_is_refused_before_any_work(measurements_csv, tmp_path, capsys):
    """``enrol --plot o.xyz`` wrote a PNG under that name, and ``pattern plot -o`` alike
    (session 27's walkthrough): a figure path must end in .png; nothing is written."""
    out = tmp_path / "p.csv"
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(tmp_path / "o.xyz")],
        capsys,
    )
    _assert_one_line_failure(code, err, "o.xyz", "--plot writes a PNG")
    assert not out.exists() and not (tmp_path / "o.xyz").exists()
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(tmp_path / "o.PNG")],
        capsys,
    )
    assert code == 0 and (tmp_path / "o.PNG").read_bytes()[:4] == b"\x89PNG"
    code, _, err = _run(["pattern", "plot", str(out), "-o", str(tmp_path / "x.pdf")], capsys)
    _assert_one_line_failure(code, err, "x.pdf", "-o writes a PNG")
    assert not (tmp_path / "x.pdf").exists()


def test_enrol_plot_to_a_device_writes_it_in_place(measurements_csv, tmp_path, capsys):
    """``--plot`` at a character device replaced the node with a regular file (the figure
    was staged and renamed over it): a device is written directly, the node stays."""
    dev, full = tmp_path / "x_nulldev", tmp_path / "x_fulldev"  # not held to .png
    try:
        os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # /dev/null's numbers
        os.mknod(full, stat.S_IFCHR | 0o666, os.makedev(1, 7))  # /dev/full's
    except OSError as exc:
        pytest.skip(f"cannot create a device node here: {exc}")
    out = tmp_path / "p.csv"
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(dev)], capsys
    )
    assert code == 0, err
    assert stat.S_ISCHR(os.lstat(dev).st_mode)
    assert read_pattern_csv(out).name == "p"
    assert not list(tmp_path.rglob("*.tmp"))
    out.unlink()  # a device that refuses the figure: one line, the new CSV removed
    code, _, err = _run(
        ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(full)], capsys
    )
    _assert_one_line_failure(code, err, f"{full}: cannot write (No space left on device)")
    assert stat.S_ISCHR(os.lstat(full).st_mode) and not out.exists()


def _read_fifo(fifo: Path, argv: list[str], capsys) -> tuple[int, str, bytes]:
    """Run ``argv`` while a thread reads ``fifo``; return the exit code, stderr and bytes read.

    The reader opens a hard link to the FIFO, so if the command never opens it (it
    replaced the name with a file), the reader is released with an empty write end.
    """
    alias = fifo.with_name(fifo.name + ".alias")
    os.link(fifo, alias)
    got: list[bytes] = []

    def reader() -> None:
        with open(alias, "rb") as fh:
            got.append(fh.read())

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    code, _, err = _run(argv, capsys)
    thread.join(timeout=10)
    if thread.is_alive():  # nobody wrote the pipe: give the reader an end of file
        os.close(os.open(alias, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(timeout=30)
    alias.unlink()
    return code, err, got[0] if got else b""


def test_enrol_plot_to_a_fifo_feeds_its_reader(measurements_csv, tmp_path, capsys):
    """``--plot`` at a FIFO replaced the pipe with a file and its reader got 0 bytes."""
    fifo = tmp_path / "figure.fifo"
    os.mkfifo(fifo)
    out = tmp_path / "p.csv"
    argv = ["enrol", str(measurements_csv), "-o", str(out), "--plot", str(fifo)]
    code, err, data = _read_fifo(fifo, argv, capsys)
    assert code == 0, err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert data.startswith(PNG_MAGIC)
    assert read_pattern_csv(out).name == "p"


def test_pattern_import_plot_to_a_fifo_feeds_its_reader(shared_data, tmp_path, capsys):
    fifo = tmp_path / "figure.fifo"
    os.mkfifo(fifo)
    msi, out = shared_data / "antenna-files" / MSI_NAME, tmp_path / "bs.csv"
    argv = ["pattern", "import", str(msi), "-o", str(out), "--format", "msi", "--plot", str(fifo)]
    code, err, data = _read_fifo(fifo, argv, capsys)
    assert code == 0, err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert data.startswith(PNG_MAGIC)
    assert out.is_file()


def test_a_figure_name_is_checked_before_the_source_is_read(tmp_path, capsys):
    """The .png check ran in _write_outputs, after the enrolment or import: with a bad
    --plot name and a malformed source, the source's error was reported and the whole
    enrolment ran first. The figure name is now checked before the source is read."""
    meas = tmp_path / "meas.csv"
    meas.write_text("motor_azimuth_deg,rss_dbm\n0,-50\n")  # no motor_elevation_deg
    msi = tmp_path / "x.msi"
    msi.write_text("NAME x\nHORIZONTAL 1\n0 0\nVERTICAL 1\n0 0\n")  # no GAIN
    out, fig = tmp_path / "p.csv", tmp_path / "o.xyz"
    for argv in (
        ["enrol", str(meas), "-o", str(out), "--plot", str(fig)],
        ["pattern", "import", str(msi), "-o", str(out), "--format", "msi", "--plot", str(fig)],
    ):
        code, _, err = _run(argv, capsys)
        _assert_one_line_failure(code, err, f"{fig}: --plot writes a PNG")
        assert "motor_elevation_deg" not in err and "GAIN" not in err
        assert not out.exists() and not fig.exists()
