"""``radiopose simulate`` and ``radiopose demo``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app

ROTATIONS = ("linear", "periodic", "fast")


@app.command()
def simulate(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")],
    seed: Annotated[int, typer.Option(help="Random seed; same seed → byte-identical files.")] = 0,
    noise_db: Annotated[
        float, typer.Option("--noise-db", help="σ of Gaussian noise on packet RSS, dB.")
    ] = 1.0,
    receivers: Annotated[int, typer.Option(help="Number of receivers (paper: 3–6).")] = 4,
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
) -> None:
    """Simulate a scenario: writes DIR/site/, DIR/packets.csv and DIR/truth.csv."""
    from dataclasses import replace

    from radiopose.errors import InputError
    from radiopose.simulate import MotionConfig, ScenarioConfig
    from radiopose.simulate import simulate as run

    if rotation not in ROTATIONS:
        raise InputError(f"--rotation must be one of {', '.join(ROTATIONS)}, got {rotation!r}")
    if not 0 < speed_mps[0] <= speed_mps[1]:
        raise InputError(f"--speed-mps needs 0 < MIN <= MAX, got {speed_mps[0]} {speed_mps[1]}")
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
        motion=replace(MotionConfig(), rotation=rotation, speed_mps=speed_mps),  # type: ignore[arg-type]
    )
    sim = run(cfg, seed=seed)
    for p in sim.write(out):
        print(p)
    n_pk = len(sim.truth)
    print(f"{n_pk} packets, {len(sim.packets)} receptions at {receivers} receivers", flush=True)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output directory (created).")] = Path(
        "radiopose-demo"
    ),
    seed: Annotated[int, typer.Option(help="Random seed of the simulated scenario.")] = 7,
    noise_db: Annotated[
        float, typer.Option("--noise-db", help="σ of Gaussian noise on packet RSS, dB.")
    ] = 1.0,
    duration_s: Annotated[
        float, typer.Option("--duration-s", help="Length of the simulated trace, seconds.")
    ] = 1.0,
    live: Annotated[
        bool,
        typer.Option(
            "--live",
            help="Run the live system instead: a server and one replaying receiver agent per "
            "receiver (a 60 s trace unless --duration-s is longer than 1); Ctrl-C stops.",
        ),
    ] = False,
    port: Annotated[int, typer.Option(help="--live: the server's port on 127.0.0.1.")] = 8000,
) -> None:
    """Simulate the paper's standard scenario, localise it, and write figures and a table."""
    if live:
        from radiopose.server.demo import run_live_demo

        run_live_demo(
            out,
            seed=seed,
            noise_db=noise_db,
            duration_s=duration_s if duration_s > 1.0 else 60.0,
            port=port,
            echo=print,
        )
        return
    from radiopose.demo import run_demo

    run_demo(out, seed=seed, noise_db=noise_db, duration_s=duration_s, echo=print)
