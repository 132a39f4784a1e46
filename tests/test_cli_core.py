"""CLI: help, simulate per contract, one-line errors, demo."""

import subprocess
import sys

import pytest

from radiopose.cli import main


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


COMMANDS = (
    "simulate",
    "demo",
    "enrol",
    "sync",
    "locate",
    "methods",
    "score",
    "serve",
    "receiver",
    "evaluate",
    "spoof",
    "pattern",
    "token",
    "db",
)


def test_help_lists_every_command(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    code, out, _ = run(["--help"], capsys)
    assert code == 0
    rows = [line.strip("│ ").split() for line in out.splitlines() if line.startswith("│ ")]
    listed = [r[0] for r in rows if r and r[0] in COMMANDS]
    assert sorted(listed) == sorted(COMMANDS)  # every command, each once
    # one line each: no continuation rows (rows that start with blank space)
    block = out.split("Commands")[1]
    cont = [ln for ln in block.splitlines() if ln.startswith("│" + " " * 10)]
    assert cont == []


def test_simulate_contract_call(tmp_path, capsys):
    code, out, err = run(
        [
            "simulate",
            "-o",
            str(tmp_path / "s"),
            "--seed",
            "4",
            "--noise-db",
            "0.5",
            "--receivers",
            "3",
            "--interval-ms",
            "20",
            "--duration-s",
            "0.2",
            "--size-m",
            "8",
            "--step-m",
            "0.5",
        ],
        capsys,
    )
    assert code == 0, err
    assert (tmp_path / "s" / "site" / "site.toml").is_file()
    lines = (tmp_path / "s" / "truth.csv").read_text().splitlines()
    assert len(lines) == 1 + 10
    assert "packets.csv" in out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--receivers", "0"], "--receivers 0 is out of range (allowed: 3 to 16;"),
        (["--receivers", "2"], "--receivers 2 is out of range (allowed: 3 to 16;"),
        (["--receivers", "2", "--pose", "3d"], "--receivers 2 is out of range (allowed: 3 to"),
        (["--receivers", "17"], "--receivers 17 is out of range (allowed: 3 to 16;"),
        (["--rotation", "spin"], "--rotation must be one of"),
        (["--noise-db", "-2"], "--noise-db -2.0 is out of range (allowed: [0, 30])"),
        (["--duration-s", "0.001"], "--duration-s 0.001 is shorter than one packet interval"),
        (["--duration-s", "inf"], "--duration-s inf must be a finite number"),
        (["--size-m", "1.5"], "--size-m 1.5 leaves no room to walk"),
        (["--speed-mps", "1", "nan"], "--speed-mps needs"),
        (["--pcap", "--duplicates", "2"], "--duplicates 2 is out of range (allowed: [0, 1])"),
        (["--pcap", "--jitter-us", "-1"], "--jitter-us -1 is out of range (allowed: [0, 1000])"),
        (["--rotation-rate-dps", "100", "50"], "--rotation-rate-dps (100.0, 50.0) needs"),
        (["--azimuth-step-deg", "7"], "--azimuth-step-deg 7.0 does not divide 360"),
        (["--size-m", "10", "--step-m", "0.3"], "--step-m 0.3 does not divide size_m = 10.0"),
        (["--step-m", "0.0001"], "more than 25,000,000 grid points"),
        (["--seed", "-1"], "--seed must be a non-negative integer"),
        (["--size-m", "1e308"], "--size-m 1e+308 is out of range"),
        (["--azimuth-step-deg", "0.0001"], "3.6e+06 azimuths"),
        (["--duplicates", "0.5"], "--duplicates applies only with --pcap"),
        (["--rotation", "periodic", "--rotation-rate-dps", "1", "2"], "applies to --rotation"),
        # the 3-D scenario's range errors name the option and the range, as 2-D's do
        (
            ["--pose", "3d", "--noise-db", "-1"],
            "--noise-db -1.0 is out of range (allowed: [0, 30])",
        ),
        (
            ["--pose", "3d", "--interval-ms", "0.001"],
            "--interval-ms 0.001 is out of range (allowed",
        ),
        (["--pose", "3d", "--duration-s", "4000"], "--duration-s 4000.0 is out of range (allowed"),
        (["--pose", "3d", "--loss", "1"], "--loss 1.0 is out of range (allowed: [0, 1))"),
        (["--pose", "3d", "--speed-mps", "1", "200"], "0 <= low <= high <= 100"),
    ],
)
def test_simulate_errors_one_line(tmp_path, capsys, args, needle):
    code, _, err = run(["simulate", "-o", str(tmp_path / "x"), *args], capsys)
    assert code == 2
    assert needle in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "scenario setting" not in err  # an option, not an internal field
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("receivers", "reason"),
    [
        ("2", "every method skips a packet heard by fewer than 3 receivers)"),
        ("17", "a scenario has at most 16)"),
    ],
)
def test_simulate_receivers_range_gives_the_reason_of_the_bound_crossed(
    tmp_path, capsys, receivers, reason
):
    """`--receivers 17` was refused because 'every method skips a packet heard by fewer
    than 3 receivers': that reason is the floor's; the ceiling is the scenario's maximum."""
    code, _, err = run(["simulate", "-o", str(tmp_path / "x"), "--receivers", receivers], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.rstrip().endswith(
        f"--receivers {receivers} is out of range (allowed: 3 to 16; {reason}"
    )
    other = "fewer than" if receivers == "17" else "at most 16"
    assert other not in err


def test_simulate_receivers_floor_is_the_trackers():
    """`radiopose simulate --receivers 2` wrote a scenario on which every method
    gave 0 % coverage: each skips a packet heard by fewer than
    TrackerConfig.min_receivers. The CLI's floor is that default."""
    from radiopose.cli.core import MIN_RECEIVERS
    from radiopose.tracker import TrackerConfig

    assert MIN_RECEIVERS == TrackerConfig().min_receivers == 3


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["simulate", "--receivers", "x"],
         "radiopose simulate: --receivers: 'x' is not a valid integer"),
        (["simulate", "--noise-db", "x"],
         "radiopose simulate: --noise-db: 'x' is not a valid number"),
        (["simulate", "--speed-mps", "1", "y"],
         "radiopose simulate: --speed-mps: 'y' is not a valid number"),
        (["simulate", "--seed", "1.5"], "radiopose simulate: --seed: '1.5' is not a valid integer"),
        (["pattern", "import", "p.msi", "--format", "zz"],
         "radiopose pattern import: --format: 'zz' is not one of 'msi', 'basta', 'mitll'"),
        # click's own one-line messages are left as they are (named "radiopose", not
        # sys.argv[0]: "python -m pytest simulate: …" in process)
        (["simulate", "--bogus"], "radiopose simulate: No such option: --bogus"),
    ],
)  # fmt: skip
def test_a_bad_value_is_one_line_naming_the_option(tmp_path, capsys, args, line):
    """A value typer cannot convert reads ``COMMAND: --OPTION: what is wrong``, not
    ``Invalid value for '--receivers': Input should be a valid integer, unable to
    parse string as an integer`` (nor ``Value error, …``), the wording of typer's
    pydantic coercion."""
    code, out, err = run([*args, "-o", str(tmp_path / "x")], capsys)
    assert code == 2 and out == ""
    assert err.startswith(line) and err.count("\n") == 1
    assert "Invalid value" not in err and "Value error" not in err and "Input should" not in err
    assert not (tmp_path / "x").exists()


def test_console_script_no_traceback(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "radiopose", "simulate", "-o", str(tmp_path), "--receivers", "99"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.startswith("radiopose: ") and "Traceback" not in r.stderr


def test_simulate_refuses_unwritable_outputs_before_writing(tmp_path, capsys):
    out = tmp_path / "s"
    (out / "packets.csv").mkdir(parents=True)  # a directory where a file goes
    code, _, err = run(["simulate", "-o", str(out)], capsys)
    assert code == 2 and "packets.csv: is a directory" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == ["packets.csv"]  # nothing else written
    out2 = tmp_path / "s2"
    out2.mkdir()
    (out2 / "captures").write_text("not a directory")
    code, _, err = run(["simulate", "-o", str(out2), "--pcap"], capsys)
    assert code == 2 and "captures: is a file, expected a directory" in err
    assert sorted(p.name for p in out2.iterdir()) == ["captures"]
    # a bad entry deep inside an output directory: the run's site/ replaces it whole
    out3 = tmp_path / "s3"
    (out3 / "site").mkdir(parents=True)
    (out3 / "site" / "patterns").write_text("a file where a directory goes")
    code, _, err = run(["simulate", "-o", str(out3), "--duration-s", "0.1"], capsys)
    assert code == 0, err
    assert (out3 / "site" / "patterns").is_dir() and (out3 / "packets.csv").is_file()
    assert not list(tmp_path.glob(".s*staging"))  # no staging directory left


def test_demo_bad_setting_leaves_no_directory(tmp_path, capsys):
    code, _, err = run(["demo", "-o", str(tmp_path / "d"), "--duration-s", "0.001"], capsys)
    assert code == 2 and err.count("\n") == 1
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(("rotation", "lo", "hi"), [("linear", 100, 120), ("fast", 700, 720)])
def test_simulate_rotation_rate_option(tmp_path, capsys, rotation, lo, hi):
    import numpy as np

    from radiopose.packets import read_truth_csv

    out = tmp_path / "s"
    args = ["simulate", "-o", str(out), "--duration-s", "0.5", "--rotation", rotation]
    code, _, err = run([*args, "--rotation-rate-dps", str(lo), str(hi)], capsys)
    assert code == 0, err
    t = read_truth_csv(out / "truth.csv")
    rate = np.degrees(np.diff(np.unwrap(np.radians(t.orientation_deg[:, 0]))))
    rate_dps = np.abs(rate / np.diff(t.timestamp_s))
    assert np.all((rate_dps > lo - 0.01) & (rate_dps < hi + 0.01))


def test_unexpected_errors_are_one_line(tmp_path, capsys, monkeypatch):
    import radiopose.simulate

    def boom(*args, **kwargs):
        raise RuntimeError("kaboom\nsecond line")

    monkeypatch.setattr(radiopose.simulate, "simulate", boom)
    monkeypatch.delenv("RADIOPOSE_TRACEBACK", raising=False)
    code, _, err = run(["simulate", "-o", str(tmp_path / "s")], capsys)
    assert code == 3
    assert err == (
        "radiopose: internal error, RuntimeError: kaboom second line "
        "(please report it; RADIOPOSE_TRACEBACK=1 shows where)\n"
    )
    monkeypatch.setenv("RADIOPOSE_TRACEBACK", "1")
    with pytest.raises(RuntimeError, match="kaboom"):
        main(["simulate", "-o", str(tmp_path / "s")])


def test_demo_failure_leaves_no_partial_output(tmp_path, capsys):
    out = tmp_path / "d"
    (out / "mse_map.png").mkdir(parents=True)  # the demo's last figure cannot be written
    code, _, err = run(["demo", "-o", str(out), "--duration-s", "0.5"], capsys)
    assert code == 2 and "mse_map.png: is a directory" in err
    assert [p.name for p in out.iterdir()] == ["mse_map.png"]
    assert not list(tmp_path.glob(".d.*"))


def test_packet_progress_shown_and_not(capsys):
    from radiopose.cli import packet_progress

    with packet_progress("locate", False) as (progress, say):
        assert progress is None
        say("plain")
    assert capsys.readouterr().out == "plain\n"
    with packet_progress("locate", True) as (progress, say):
        assert progress is not None
        progress(3, 10)
        say("[b]not markup[/b]")
    assert "[b]not markup[/b]" in capsys.readouterr().out


def test_method_progress_names_the_method_it_is_on(capsys):
    """The demo's bar over several methods in turn (``radiopose demo`` on a
    terminal): the callback ``run_methods`` takes, and a print beside the bar."""
    from radiopose.cli import method_progress

    with method_progress("localising", False) as (progress, say):
        assert progress is None
    with method_progress("localising", True) as (progress, say):
        assert progress is not None
        progress("full", 3, 10)
        say("[b]not markup[/b]")
    assert "[b]not markup[/b]" in capsys.readouterr().out


def test_outputs_never_overwrite_inputs(tmp_path, capsys):
    """``-o`` naming an input (the packets, a file of the site, the pattern to
    plot) is a one-line error before any work, and the input is intact."""
    code, _, _ = run(["simulate", "-o", str(tmp_path / "s"), "--duration-s", "0.2"], capsys)
    assert code == 0
    site, packets = tmp_path / "s" / "site", tmp_path / "s" / "packets.csv"
    before = packets.read_bytes()
    pattern = next((site / "patterns").glob("*.csv"))
    for args in (
        ["locate", str(site), str(packets), "-o", str(packets), "--method", "location"],
        ["locate", str(site), str(packets), "-o", str(pattern), "--method", "location"],
        ["pattern", "plot", str(pattern), "-o", str(pattern)],
    ):
        code, _, err = run(args, capsys)
        assert code == 2 and "would overwrite" in err and err.count("\n") == 1, err
    assert packets.read_bytes() == before and pattern.read_text().startswith("azimuth_deg")
    # an output directory is refused before the work, not after it
    code, _, err = run(["locate", str(site), str(packets), "-o", str(tmp_path)], capsys)
    assert code == 2 and "is a directory" in err and "wrote" not in err


def test_simulate_never_leaves_stale_captures(tmp_path, capsys):
    out = tmp_path / "s"
    code, _, _ = run(["simulate", "-o", str(out), "--duration-s", "0.2", "--pcap"], capsys)
    assert code == 0
    before = {p.name: p.read_bytes() for p in (out / "captures").iterdir()}
    code, _, err = run(["simulate", "-o", str(out), "--seed", "5", "--duration-s", "0.2"], capsys)
    assert code == 2 and "earlier run" in err and err.count("\n") == 1
    assert {p.name: p.read_bytes() for p in (out / "captures").iterdir()} == before
    code, _, _ = run(
        ["simulate", "-o", str(out), "--seed", "5", "--duration-s", "0.2", "--pcap"], capsys
    )
    assert code == 0 and {p.name: p.read_bytes() for p in (out / "captures").iterdir()} != before
