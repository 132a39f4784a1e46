"""``radiopose simulate`` and ``radiopose demo``."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from radiopose.cli import app

if TYPE_CHECKING:
    from radiopose.errors import InputError

ROTATIONS = ("linear", "periodic", "fast")
# Defaults of the options that only apply with --pcap (one place: the signature
# and the "given without --pcap" check both read them).
_PCAP_DEFAULTS = {
    "--clock-offset-ms": 1000.0,
    "--clock-drift-ppm": 20.0,
    "--jitter-us": 20.0,
    "--duplicates": 0.0,
}


_SCENARIO_FLAGS = {
    "survey_noise_db": "--survey-noise-db",
    "noise_db": "--noise-db",
    "size_m": "--size-m",
    "step_m": "--step-m",
    "n_receivers": "--receivers",
    "interval_ms": "--interval-ms",
    "duration_s": "--duration-s",
    "azimuth_step_deg": "--azimuth-step-deg",
    "loss_fraction": "--loss",
    "speed_mps": "--speed-mps",
}
"""``radiopose simulate``'s option for each ScenarioConfig / HandheldConfig field it
sets (their range errors name the option; ``demo`` shares the names it has)."""

_MOTION_FLAGS = {
    "speed_mps": "--speed-mps",
    "linear_rate_deg_s": "--rotation-rate-dps",
    "fast_rate_deg_s": "--rotation-rate-dps",
}
"""The same for the MotionConfig fields the options set (``--rotation-rate-dps``
sets the rate of the ``--rotation`` chosen)."""

_PCAP_FLAGS = {
    "clock_offset_max_s": ("--clock-offset-ms", 1e3),
    "drift_max_ppm": ("--clock-drift-ppm", 1.0),
    "jitter_s": ("--jitter-us", 1e6),
    "duplicate_fraction": ("--duplicates", 1.0),
}
"""``simulate --pcap``'s option for each CaptureConfig field, and the option's units
per the field's (milliseconds and microseconds for seconds)."""


def _named_options(exc: InputError) -> InputError:
    """``exc`` with each ``[3-D ]scenario setting FIELD =`` of :data:`_SCENARIO_FLAGS`
    (and ``motion setting FIELD =`` of :data:`_MOTION_FLAGS`) named as its option:
    ``--noise-db -1.0 is out of range (allowed: [0, 30])``."""
    from radiopose.errors import InputError

    reason = exc.reason
    for field_name, flag in _SCENARIO_FLAGS.items():
        for setting in ("3-D scenario setting", "scenario setting"):  # the longer first
            reason = reason.replace(f"{setting} {field_name} =", flag)
    for field_name, flag in _MOTION_FLAGS.items():
        reason = reason.replace(f"motion setting {field_name} =", flag)
    return InputError(reason, path=exc.path, line=exc.line, column=exc.column)


@contextlib.contextmanager
def _options_named() -> Iterator[None]:
    """A scenario range error raised inside the block names the option
    (:func:`_named_options`), for ``simulate`` and the demos."""
    from radiopose.errors import InputError

    try:
        yield
    except InputError as exc:
        raise _named_options(exc) from None


_REAL_DEMO_IGNORES = {
    "live": "--live",
    "seed": "--seed",
    "noise_db": "--noise-db",
    "duration_s": "--duration-s",
    "interval_ms": "--interval-ms",
    "method": "--method",
    "port": "--port",
    "pose": "--pose",
}
"""``radiopose demo``'s options (parameter name -> option) that ``--real`` does not
use: the real-data demo replays the shipped tracks with their own settings."""


def _given(ctx: typer.Context, options: dict[str, str]) -> list[str]:
    """The options of ``options`` (parameter name -> option) given on the command
    line, whatever their value (a value equal to the default is still given). The
    source is compared by name: typer vendors its own click."""
    given = ("COMMANDLINE", "ENVIRONMENT")
    return [
        flag
        for name, flag in options.items()
        if getattr(ctx.get_parameter_source(name), "name", None) in given
    ]


MIN_RECEIVERS = 3
"""Fewest receivers ``radiopose simulate`` accepts: ``TrackerConfig.min_receivers``'s
default (not imported: it loads the method registry). Every method skips a packet
heard by fewer, so a scenario with fewer gives no estimate at all (the library's
:class:`ScenarioConfig` takes 1 for experiments that lower ``min_receivers``)."""


@app.command(short_help="Simulate a scenario: site/, packets.csv, truth.csv.")
def simulate(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")],
    seed: Annotated[int, typer.Option(help="Random seed; same seed → byte-identical files.")] = 0,
    noise_db: Annotated[
        float, typer.Option("--noise-db", help="σ of Gaussian noise on packet RSS, dB.")
    ] = 1.0,
    receivers: Annotated[int, typer.Option(help="Number of receivers, 3 to 16 (paper: 3–6).")] = 4,
    interval_ms: Annotated[
        float, typer.Option("--interval-ms", help="Time between packets, milliseconds.")
    ] = 5.0,
    duration_s: Annotated[
        float, typer.Option("--duration-s", help="Length of the trace, seconds.")
    ] = 2.0,
    rotation: Annotated[
        str, typer.Option(help="Rotation: linear, periodic (human-like) or fast (beyond model).")
    ] = "linear",
    speed_mps: Annotated[
        tuple[float, float],
        typer.Option("--speed-mps", help="Speed range drawn uniformly, metres/second (MIN MAX)."),
    ] = (0.5, 1.5),
    rotation_rate_dps: Annotated[
        tuple[float, float] | None,
        typer.Option(
            "--rotation-rate-dps",
            help="Rotation rate range drawn uniformly (random sign), degrees/second (MIN MAX); "
            "for --rotation linear (default 10 90) or fast (default 450 900).",
        ),
    ] = None,
    loss: Annotated[
        float, typer.Option(help="Fraction of packets each receiver misses, 0–1.")
    ] = 0.0,
    size_m: Annotated[float, typer.Option("--size-m", help="Side of the square area, m.")] = 20.0,
    step_m: Annotated[float, typer.Option("--step-m", help="Candidate grid step, m.")] = 0.1,
    azimuth_step_deg: Annotated[
        float, typer.Option("--azimuth-step-deg", help="Candidate azimuth step, degrees.")
    ] = 1.0,
    survey_noise_db: Annotated[
        float, typer.Option("--survey-noise-db", help="σ of noise on survey RSS, dB.")
    ] = 0.0,
    pose: Annotated[
        str,
        typer.Option(
            "--pose",
            help="2d (the paper's scenario) or 3d (a hand-held phone: height, pitch and roll "
            "vary; receivers at mixed heights; docs/pose3d.md).",
        ),
    ] = "2d",
    pcap: Annotated[
        bool,
        typer.Option(
            "--pcap",
            help="Also write DIR/captures/: one radiotap pcap per receiver, as sniffers would "
            "record the packets (RSS in whole dBm, also in packets.csv); `radiopose sync "
            "DIR/captures/*.pcap` recovers packets.csv.",
        ),
    ] = False,
    clock_offset_ms: Annotated[
        float,
        typer.Option(
            "--clock-offset-ms",
            help="--pcap: receiver clocks run U(0, this) milliseconds ahead of the first.",
        ),
    ] = _PCAP_DEFAULTS["--clock-offset-ms"],
    clock_drift_ppm: Annotated[
        float,
        typer.Option(
            "--clock-drift-ppm", help="--pcap: receiver clock drift drawn from U(±this), ppm."
        ),
    ] = _PCAP_DEFAULTS["--clock-drift-ppm"],
    jitter_us: Annotated[
        float,
        typer.Option(
            "--jitter-us",
            help="--pcap: scale of the half-normal timestamp latency, microseconds.",
        ),
    ] = _PCAP_DEFAULTS["--jitter-us"],
    duplicates: Annotated[
        float,
        typer.Option(
            "--duplicates",
            help="--pcap: fraction of frames a receiver records twice, 0–1 (sync drops "
            "them as ambiguous; see captures/pcap_truth.csv).",
        ),
    ] = _PCAP_DEFAULTS["--duplicates"],
) -> None:
    """Simulate a scenario: writes DIR/site/, DIR/packets.csv and DIR/truth.csv."""
    from dataclasses import replace

    from radiopose.errors import InputError
    from radiopose.simulate import MotionConfig, ScenarioConfig
    from radiopose.simulate import simulate as run
    from radiopose.simulate.scenario import MAX_RECEIVERS

    if not 0 <= seed < 2**63:
        raise InputError(f"--seed must be a non-negative integer below 2**63, got {seed}")
    if rotation not in ROTATIONS:
        raise InputError(f"--rotation must be one of {', '.join(ROTATIONS)}, got {rotation!r}")
    if not 0 < speed_mps[0] <= speed_mps[1]:
        raise InputError(f"--speed-mps needs 0 < MIN <= MAX, got {speed_mps[0]} {speed_mps[1]}")
    motion = replace(MotionConfig(), rotation=rotation, speed_mps=speed_mps)  # type: ignore[arg-type]
    if rotation_rate_dps is not None:
        if rotation == "periodic":
            raise InputError("--rotation-rate-dps applies to --rotation linear or fast")
        rate = "linear_rate_deg_s" if rotation == "linear" else "fast_rate_deg_s"
        rate_change: dict[str, Any] = {rate: tuple(rotation_rate_dps)}
        motion = replace(motion, **rate_change)
    if not MIN_RECEIVERS <= receivers <= MAX_RECEIVERS:
        why = (
            f"every method skips a packet heard by fewer than {MIN_RECEIVERS} receivers"
            if receivers < MIN_RECEIVERS
            else f"a scenario has at most {MAX_RECEIVERS}"
        )
        raise InputError(
            f"--receivers {receivers} is out of range (allowed: {MIN_RECEIVERS} to "
            f"{MAX_RECEIVERS}; {why})"
        )
    with _options_named():  # name the option, not the scenario's field
        cfg = ScenarioConfig(
            size_m=size_m,
            step_m=step_m,
            n_receivers=receivers,
            noise_db=noise_db,
            survey_noise_db=survey_noise_db,
            interval_ms=interval_ms,
            duration_s=duration_s,
            azimuth_step_deg=azimuth_step_deg,
            loss_fraction=loss,
            motion=motion,
        )
        if pose == "2d":
            cfg.validate()
        elif pose == "3d":  # the hand-held scenario takes the shared settings only
            from radiopose.simulate.handheld import HandheldConfig

            HandheldConfig.from_scenario(cfg).validate()
    capture_cfg = None
    if not pcap:
        values = (clock_offset_ms, clock_drift_ppm, jitter_us, duplicates)
        for (name, default), value in zip(_PCAP_DEFAULTS.items(), values, strict=True):
            if value != default:
                raise InputError(f"{name} applies only with --pcap")
        if (out / "captures").exists():  # an earlier run's, which the new packets would not match
            raise InputError(
                "holds the captures of an earlier run, which would not match the new "
                "packets: remove it, or pass --pcap to replace it",
                path=out / "captures",
            )
    else:
        from radiopose.capture.writer import CaptureConfig

        capture_cfg = CaptureConfig(
            clock_offset_max_s=clock_offset_ms / 1e3,
            drift_max_ppm=clock_drift_ppm,
            jitter_s=jitter_us / 1e6,
            duplicate_fraction=duplicates,
        )
        bad = capture_cfg.out_of_range()
        if bad is not None:  # named as the option, in its units
            field_name, value, lo, hi = bad
            flag, k = _PCAP_FLAGS[field_name]
            raise InputError(
                f"{flag} {value * k:g} is out of range (allowed: [{lo * k:g}, {hi * k:g}])"
            )
    if pose not in ("2d", "3d"):
        raise InputError(f"--pose must be 2d or 3d, got {pose!r}")
    if pose == "3d":  # pose3d: the hand-held scenario takes the shared settings only
        from radiopose.simulate.handheld import HandheldConfig, simulate_handheld

        only_2d = {
            "--rotation": rotation != "linear",
            "--rotation-rate-dps": rotation_rate_dps is not None,
            "--size-m": size_m != 20.0,
            "--step-m": step_m != 0.1,
            "--azimuth-step-deg": azimuth_step_deg != 1.0,
            "--survey-noise-db": survey_noise_db != 0.0,
        }
        for name, given in only_2d.items():
            if given:
                raise InputError(f"{name} applies only with --pose 2d")
        sim = simulate_handheld(HandheldConfig.from_scenario(cfg), seed=seed)
    else:
        sim = run(cfg, seed=seed)
    if capture_cfg is not None:
        from radiopose.capture.writer import whole_dbm

        sim = replace(sim, packets=whole_dbm(sim.packets))
    from radiopose.tables import staged_directory

    written: list[Path] = []
    with staged_directory(out) as stage:  # all files or none
        written += sim.write(stage)
        if capture_cfg is not None:
            from radiopose.capture.writer import CLOCKS_FILE, TRUTH_FILE, simulate_captures

            caps = simulate_captures(
                sim.packets,
                [r.receiver_id for r in sim.site.receivers],
                stage / "captures",
                seed=seed,
                config=capture_cfg,
            )
            written += [*caps.paths.values(), stage / "captures" / CLOCKS_FILE]
            if duplicates > 0:
                written.append(stage / "captures" / TRUTH_FILE)
            else:
                (stage / "captures" / TRUTH_FILE).unlink()  # equal to packets.csv
    for p in written:
        print(out / p.relative_to(stage))
    n_pk = len(sim.truth)
    print(f"{n_pk} packets, {len(sim.packets)} receptions at {receivers} receivers", flush=True)


@app.command(short_help="Simulate a walk, localise it with every method, plot.")
def demo(
    ctx: typer.Context,
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")] = Path(
        "radiopose-demo"
    ),
    seed: Annotated[int, typer.Option(help="Random seed of the simulated scenario.")] = 7,
    noise_db: Annotated[
        float, typer.Option("--noise-db", help="σ of Gaussian noise on packet RSS, dB.")
    ] = 1.0,
    duration_s: Annotated[
        float | None,
        typer.Option(
            "--duration-s",
            help="Length of the simulated walk, seconds (default 30; --live: 60).",
        ),
    ] = None,
    interval_ms: Annotated[
        float | None,
        typer.Option(
            "--interval-ms",
            help="Time between packets, ms (default 20; the paper's 5 gives 4x the packets; "
            "--live: 100).",
        ),
    ] = None,
    live: Annotated[
        bool,
        typer.Option(
            "--live",
            help="Run the live system instead: a server and one replaying receiver agent per "
            "receiver (a 60 s walk, a packet every 100 ms) and the dashboard drawing the "
            "track of --method; Ctrl-C stops.",
        ),
    ] = False,
    method: Annotated[
        str,
        typer.Option(help="--live: the server's tracker method (the dashboard draws its track)."),
    ] = "filter",
    port: Annotated[int, typer.Option(help="--live: the server's port on 127.0.0.1.")] = 8000,
    real: Annotated[
        bool,
        typer.Option(
            "--real",
            help="Real data instead: the shipped BLE tracking site (CC0) imported, every track "
            "localised and drawn against its camera truth (docs/real-data.md).",
        ),
    ] = False,
    pose: Annotated[
        str,
        typer.Option(
            "--pose",
            help="3d: a hand-held phone (height, pitch, roll) at 6 receivers at mixed heights, "
            "tracked by the filter offline, live and causal (a 10 s walk, a packet every 20 ms; "
            "with --live: a 10 m site, the server's 3-D filter; docs/pose3d.md).",
        ),
    ] = "2d",
) -> None:
    """Simulate a 30 s walk on the paper's standard site, localise it with the paper's five
    methods and the filter, and write a table and figures."""
    from radiopose.errors import InputError

    if not 0 <= seed < 2**63:
        raise InputError(f"--seed must be a non-negative integer below 2**63, got {seed}")
    if pose not in ("2d", "3d"):
        raise InputError(f"--pose must be 2d or 3d, got {pose!r}")
    if not live and not real and _given(ctx, {"port": "--port"}):
        raise InputError("--port applies to --live (the offline demo starts no server)")
    if pose == "3d" and not live and not real:  # (--real refuses --pose with its others)
        if method != "filter":
            raise InputError("--method applies to --live (the 3-D demo runs the filter)")
        from radiopose.cli import packet_progress
        from radiopose.demo3d import DEMO3D_DURATION_S, DEMO3D_INTERVAL_MS, run_demo3d

        with (
            _options_named(),
            packet_progress("filter, offline", sys.stderr.isatty()) as (progress, say),
        ):
            run_demo3d(
                out,
                seed=seed,
                noise_db=noise_db,
                duration_s=DEMO3D_DURATION_S if duration_s is None else duration_s,
                interval_ms=DEMO3D_INTERVAL_MS if interval_ms is None else interval_ms,
                echo=say,
                progress=progress,
            )
        return
    if real:
        ignored = _given(ctx, _REAL_DEMO_IGNORES)
        if ignored:
            verb = "does" if len(ignored) == 1 else "do"
            raise InputError(
                f"{', '.join(ignored)} {verb} not apply to --real (the real-data demo replays "
                "the shipped BLE tracks with their own settings; it takes only -o)"
            )
        from radiopose.realdata.demo import run_real_demo

        run_real_demo(out, echo=print)
        return
    if live:
        from radiopose.server.demo import run_live_demo
        from radiopose.tracker import METHODS

        if method not in METHODS:
            raise InputError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
        if pose == "3d" and method != "filter":
            raise InputError(
                "--pose 3d --live runs the filter (the paper's methods search every candidate "
                "per packet at a 3-D site: far too slow live; docs/methods.md)"
            )
        run_live_demo(
            out,
            seed=seed,
            noise_db=noise_db,
            duration_s=60.0 if duration_s is None else duration_s,
            interval_ms=100.0 if interval_ms is None else interval_ms,
            method=method,
            port=port,
            echo=print,
            pose=pose,
        )
        return
    if method != "filter":
        raise InputError("--method applies to --live (the offline demo runs every method)")
    from radiopose.cli import method_progress
    from radiopose.demo import DEMO_DURATION_S, DEMO_INTERVAL_MS, run_demo

    with _options_named(), method_progress("localising", sys.stderr.isatty()) as (progress, say):
        run_demo(
            out,
            seed=seed,
            noise_db=noise_db,
            duration_s=DEMO_DURATION_S if duration_s is None else duration_s,
            interval_ms=DEMO_INTERVAL_MS if interval_ms is None else interval_ms,
            echo=say,
            progress=progress,
        )
