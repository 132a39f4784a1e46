"""``radiopose demo``: the whole system on built-in simulated data.

Simulates the paper's standard scenario (20 m × 20 m, 4 receivers, packets every
5 ms, straight walk with linear rotation), writes the scenario files, draws the
scene, the patterns and a receiver's survey map, then runs the paper's five
methods on the trace, prints the error table (with coverage) and saves the
MSE map of one packet, the trajectories and the orientation error over time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path


def run_demo(
    out_dir: str | Path,
    *,
    seed: int = 7,
    noise_db: float = 1.0,
    duration_s: float = 1.0,
    echo: Callable[[str], None] = print,
) -> list[Path]:
    """Run the demo into ``out_dir``; return the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radiopose.plot_site import plot_scene, plot_survey_map
    from radiopose.simulate import ScenarioConfig, simulate

    t0 = time.perf_counter()
    out = Path(out_dir)
    sim = simulate(ScenarioConfig(noise_db=noise_db, duration_s=duration_s), seed=seed)
    from radiopose.tables import staged_directory

    # Everything is written to a staging directory beside OUT and moved into
    # OUT only when the whole demo succeeded: a failure leaves no partial output.
    with staged_directory(out) as stage:

        def say(line: str, stage: Path = stage) -> None:
            echo(line.replace(str(stage), str(out)))

        written = sim.write(stage / "scenario")
        say(
            f"simulated {len(sim.truth)} packets (seed {seed}, σ = {noise_db:g} dB) "
            f"at {len(sim.site.receivers)} receivers"
        )

        ax = plot_scene(sim.site, sim.truth.position_m[:, :2], sim.truth.orientation_deg[:, 0])
        written.append(_save(ax.figure, stage / "scene.png"))
        plt.close(ax.figure)

        ax = plot_survey_map(sim.site, sim.site.receivers[0].receiver_id)
        written.append(_save(ax.figure, stage / "survey_map_rx1.png"))
        plt.close(ax.figure)

        written.append(_pattern_figure(sim, stage / "patterns.png"))

        from radiopose.evaluate.demo import run_demo_pipeline

        say("localising with all five methods (full, location, orientation, top, lms) ...")
        for p in written:
            say(f"wrote {p}")
        run_demo_pipeline(sim, stage, echo=say)  # prints its table and what it wrote
    written = [out / p.relative_to(stage) for p in written]
    echo(f"demo finished in {time.perf_counter() - t0:.1f} s")
    return written


def _save(fig, path: Path) -> Path:  # type: ignore[no-untyped-def]
    fig.savefig(path, dpi=110)
    return path


def _pattern_figure(sim, path: Path) -> Path:  # type: ignore[no-untyped-def]
    import matplotlib.pyplot as plt

    from radiopose.patterns.plot import plot_polar

    names = ["device", "survey-tx", *[r.pattern for r in sim.site.receivers]]
    fig, axes = plt.subplots(
        2,
        (len(names) + 1) // 2,
        subplot_kw={"projection": "polar"},
        figsize=(3.2 * ((len(names) + 1) // 2), 6.6),
        layout="constrained",
    )
    for ax, name in zip(axes.ravel(), names, strict=False):
        plot_polar(sim.site.patterns[name], ax=ax)
        ax.set_title(name)
    for ax in axes.ravel()[len(names) :]:
        ax.set_visible(False)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
