"""``radiopose demo --pose 3d``: the 3-D filter on a simulated hand-held walk.

Simulates the 3-D hand-held scenario (``radiopose simulate --pose 3d``: 20 m ×
20 m, 6 receivers at mixed heights, some on the ceiling, σ = 1 dB; a phone
held in the hand, walking with turns, pitched 20–70°, rolling, at 0.8–1.6 m;
docs/simulation.md) for :data:`DEMO3D_DURATION_S` seconds, a packet every
:data:`DEMO3D_INTERVAL_MS` ms. It writes the scenario files, runs ``filter``
three times — offline (batch ``locate``: the smoother and the 3-D
refinement), live (the live server's filter: a fixed lag of
:data:`DEMO3D_LIVE_LAG_S`, no refinement; run here in batch) and causal (each
packet's estimate at once) — writes the three estimates files, prints the
per-axis error table (``errors.md``) and draws each track against the truth
(``pose3d_offline.png``, ``pose3d_live.png``, ``pose3d_causal.png``: the top
view with the stated uncertainty, height, azimuth, pitch and roll over time,
the position and rotation-angle errors).

The paper's five methods are not run: at a 3-D site they would need the full
candidate table (positions × heights × azimuths × pitches × rolls), which
takes minutes and gigabytes to build (docs/pose3d.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from radiopose.errors import InputError
from radiopose.evaluate.pose3d import AxisErrors
from radiopose.evaluate.scoring import error_stats
from radiopose.units import FloatArray

DEMO3D_DURATION_S = 10.0
"""Length of the 3-D demo's walk, seconds."""
DEMO3D_INTERVAL_MS = 20.0
"""Time between the 3-D demo's packets, milliseconds (the scenario's own: 5 ms)."""
DEMO3D_LIVE_LAG_S = 0.25
"""The ``live`` run's smoothing lag, seconds: the live server's default and largest
(``radiopose.server.live.LiveConfig.live_lag_s``)."""


def run_demo3d(
    out_dir: str | Path,
    *,
    seed: int = 7,
    noise_db: float = 1.0,
    duration_s: float = DEMO3D_DURATION_S,
    interval_ms: float = DEMO3D_INTERVAL_MS,
    echo: Callable[[str], None] = print,
    progress: Callable[[int, int], None] | None = None,
) -> list[Path]:
    """Run the 3-D demo into ``out_dir``; return the paths written.

    Parameters
    ----------
    out_dir
        Output directory (its entries replaced only when the demo succeeds).
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
        Called as ``progress(done, total)`` after each packet of the offline
        filter's forward pass (its refinement follows).

    Raises
    ------
    InputError
        A scenario setting out of range (one line naming it).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from radiopose.estimates import write_estimates_csv
    from radiopose.evaluate.pose3d import axis_errors
    from radiopose.evaluate.scoring import match_truth
    from radiopose.plots import pose3d_figure
    from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
    from radiopose.tables import staged_directory, staged_echo
    from radiopose.tracker import TrackerConfig, locate

    t0 = time.perf_counter()
    cfg = replace(
        HandheldConfig(), noise_db=noise_db, duration_s=duration_s, interval_ms=interval_ms
    )
    try:
        cfg.validate()
    except InputError as exc:
        raise InputError(f"demo --pose 3d: {exc}") from None
    sim = simulate_handheld(cfg, seed=seed)
    out = Path(out_dir)
    rx = sim.site.receiver_positions_m()
    with staged_directory(out) as stage:
        say = staged_echo(echo, stage, out)

        written = sim.write(stage / "scenario")
        n_pk = len(sim.truth)
        heights = ", ".join(f"{z:.1f}" for z in rx[:, 2])
        say(
            f"simulated a {duration_s:g} s hand-held walk: {n_pk} packets, one every "
            f"{interval_ms:g} ms, at {len(rx)} receivers at heights {heights} m "
            f"(seed {seed}, σ = {noise_db:g} dB)"
        )
        base = TrackerConfig()
        runs = {
            "offline": (base, "the smoother and the 3-D refinement"),
            "live": (
                replace(
                    base,
                    smoothing_lag_s=DEMO3D_LIVE_LAG_S,
                    pose3d=replace(base.pose3d, refine=False),
                ),
                f"the live server's filter: a lag of {DEMO3D_LIVE_LAG_S:g} s, no refinement",
            ),
            "causal": (
                replace(base, smoothing_lag_s=None),
                "each packet's estimate at once, no lag",
            ),
        }
        rows = []
        for name, (tcfg, what) in runs.items():
            say(f"localising with the filter, {name} ({what}) ...")
            t1 = time.perf_counter()
            result = locate(
                sim.site, sim.packets, "filter", tcfg, progress if name == "offline" else None
            )
            est = result.estimates
            path = stage / f"estimates_{name}.csv"
            write_estimates_csv(est, path)
            written.append(path)
            e = axis_errors(sim.truth, est)
            rows.append((name, e, time.perf_counter() - t1))
            idx = match_truth(sim.truth, est)
            ok = idx >= 0
            tr = sim.truth
            fig = pose3d_figure(
                tr.timestamp_s, tr.position_m, tr.orientation_deg, est.select(ok),
                (e.position_m, e.rotation_deg), n_packets=n_pk, receivers_m=rx,
                title=f"filter, {name}: {duration_s:g} s hand-held walk, seed {seed}, "
                f"σ = {noise_db:g} dB, {len(rx)} receivers",
            )  # fmt: skip
            png = stage / f"pose3d_{name}.png"
            fig.savefig(png, dpi=100)
            plt.close(fig)
            written.append(png)
        table = _error_table(rows)
        (stage / "errors.md").write_text(table + "\n", encoding="utf-8")
        written.append(stage / "errors.md")
        for line in table.splitlines():
            say(line)
        for p in written:
            say(f"wrote {p}")
    written = [out / p.relative_to(stage) for p in written]
    echo(f"demo finished in {time.perf_counter() - t0:.1f} s")
    return written


def _stats(x: FloatArray, decimals: int) -> str:
    """``mean / median / p95`` of errors (:func:`~radiopose.evaluate.scoring.error_stats`),
    or a dash for none."""
    s = error_stats(x)
    if s.n == 0:
        return "–"
    return " / ".join(f"{v:.{decimals}f}" for v in (s.mean, s.median, s.p95))


def _error_table(rows: list[tuple[str, AxisErrors, float]]) -> str:
    """The per-axis error table of ``(variant, errors, seconds)`` rows (Markdown)."""
    head = (
        "| filter | coverage | position mean / median / p95 (m) | rotation mean / median / p95 (°) "
        "| height (m) | azimuth (°) | pitch (°) | roll (°) | run time (s) |\n"
        "|:---|---:|---|---|---:|---:|---:|---:|---:|"
    )
    lines = [head]
    for name, e, secs in rows:
        m = e.means()
        lines.append(
            f"| {name} | {100 * e.coverage:.1f} % | {_stats(e.position_m, 2)} "
            f"| {_stats(e.rotation_deg, 1)} | {m['height_m']:.2f} | {m['azimuth_deg']:.1f} "
            f"| {m['pitch_deg']:.1f} | {m['roll_deg']:.1f} | {secs:.1f} |"
        )
    return "\n".join(lines)
