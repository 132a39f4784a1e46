"""``radiopose demo``: the whole system on built-in simulated data.

Simulates the paper's standard site (20 m × 20 m, 4 receivers, σ = 1 dB) with
a walk long enough to see: 30 s between random waypoints with rounded turns,
the device facing the way it walks with a small sway (:func:`demo_scenario`).
It writes the scenario files, draws the scene, the patterns and a receiver's
survey map, runs the paper's five methods and the Bayesian tracker ``filter``
on the trace, prints the error table (with coverage) and the ``filter``'s
calibration, and saves the MSE map of one packet, the trajectories, the
orientation error over time and the ``filter``'s track with its uncertainty
beside ``full``'s sparse estimates (``filter_track.png``).

Packets come every 20 ms, not the paper's 5 ms: the same 30 s at 5 ms are
6,000 packets, four times as many to localise with six methods (run times in
docs/simulation.md, "The demo's walk"); ``--interval-ms 5`` runs them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, cast

from radiopose.simulate import MotionConfig, ScenarioConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DEMO_DURATION_S = 30.0
"""Length of the demo's walk, seconds."""
DEMO_INTERVAL_MS = 20.0
"""Time between the demo's packets, milliseconds (the paper: 5 ms)."""


def demo_scenario(
    *,
    noise_db: float = 1.0,
    duration_s: float = DEMO_DURATION_S,
    interval_ms: float = DEMO_INTERVAL_MS,
) -> ScenarioConfig:
    """The demo's scenario: the paper's standard site and noise, a walk with turns.

    The device walks between random waypoints (legs of at least 4 m, turns of
    at most 120°, corners rounded over about 2 m) at one speed of 0.5–1.5 m/s,
    its top pointing the way it walks with a sway of 5–15°
    (:class:`~radiopose.simulate.MotionConfig` ``path="walk"``,
    ``rotation="heading"``).
    """
    return ScenarioConfig(
        noise_db=noise_db,
        duration_s=duration_s,
        interval_ms=interval_ms,
        motion=MotionConfig(path="walk", rotation="heading"),
    )


def run_demo(
    out_dir: str | Path,
    *,
    seed: int = 7,
    noise_db: float = 1.0,
    duration_s: float = DEMO_DURATION_S,
    interval_ms: float = DEMO_INTERVAL_MS,
    echo: Callable[[str], None] = print,
    progress: Callable[[str, int, int], None] | None = None,
) -> list[Path]:
    """Run the demo into ``out_dir``; return the paths written.

    Parameters
    ----------
    out_dir
        Output directory (replaced as a whole when the demo succeeds).
    seed
        Seed of the simulated scenario.
    noise_db
        σ of the packet RSS noise, dB.
    duration_s
        Length of the walk, seconds.
    interval_ms
        Time between packets, milliseconds.
    echo
        Receives every printed line.
    progress
        Called as ``progress(method, done, total)`` over each method's packets
        (a progress bar: ``radiopose demo`` on a terminal).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radiopose.plot_site import plot_scene, plot_survey_map
    from radiopose.simulate import simulate

    t0 = time.perf_counter()
    out = Path(out_dir)
    cfg = demo_scenario(noise_db=noise_db, duration_s=duration_s, interval_ms=interval_ms)
    sim = simulate(cfg, seed=seed)
    from radiopose.tables import staged_directory, staged_echo

    # Everything is written to a staging directory beside OUT and moved into
    # OUT only when the whole demo succeeded: a failure leaves no partial output.
    with staged_directory(out) as stage:
        say = staged_echo(echo, stage, out)

        written = sim.write(stage / "scenario")
        say(
            f"simulated a {duration_s:g} s walk with turns: {len(sim.truth)} packets, one every "
            f"{interval_ms:g} ms (the paper: 5 ms; --interval-ms 5 for four times the "
            f"packets), at {len(sim.site.receivers)} receivers (seed {seed}, σ = {noise_db:g} dB)"
        )

        ax = plot_scene(sim.site, sim.truth.position_m[:, :2], sim.truth.orientation_deg[:, 0])
        written.append(_save(ax.figure, stage / "scene.png"))
        plt.close(cast("Figure", ax.figure))

        ax = plot_survey_map(sim.site, sim.site.receivers[0].receiver_id)
        written.append(_save(ax.figure, stage / "survey_map_rx1.png"))
        plt.close(cast("Figure", ax.figure))

        written.append(_pattern_figure(sim, stage / "patterns.png"))

        from radiopose.evaluate.demo import run_demo_pipeline

        say(
            "localising with the paper's five methods (full, location, orientation, top, lms) "
            "and the Bayesian tracker (filter) ..."
        )
        for p in written:
            say(f"wrote {p}")
        run_demo_pipeline(sim, stage, echo=say, progress=progress)  # prints its table, files
    written = [out / p.relative_to(stage) for p in written]
    echo(f"demo finished in {time.perf_counter() - t0:.1f} s")
    return written


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    return path


def _pattern_figure(sim, path: Path) -> Path:
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
