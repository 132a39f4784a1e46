"""Accuracy of ``filter`` causal vs a live fixed lag vs offline → ``docs/filter.md``, "Live lag".

Standard scenario (``ScenarioConfig()``: 20 × 20 m, 0.1 m / 1° grid, 4
receivers, a packet every 5 ms, 2 s traces), held-out seeds (default
1000–1004; the filter was tuned on 7000–7011). Variants:

* ``causal`` — lag 0 (each packet's estimate at once);
* ``live, lag 0.1 s`` and ``live, lag 0.25 s`` — the live server's fixed-lag
  smoother (``LiveConfig.live_lag_s``): batch ``locate`` with ``smoothing_lag_s``
  equal to the lag and the offline-only passes off (``offline_offset_selection``,
  ``offline_reverse_pass``, ``offline_refine``), which is exactly what the
  streaming tracker with that lag gives (``tests/test_server_live_lag.py``); the
  live server never runs those passes over the whole file, only over a track's
  first half second (the live re-solve, ``FilterConfig.live_resolve_times_s``,
  the default since session 25; ``--set "live_resolve_times_s=()"`` gives the
  rows before it; ``tests/test_live_resolve.py``);
* ``offline, lag 1 s`` — batch ``locate``'s default (with the offline passes);
* ``textbook`` — issue 15's anchor, not ``filter``: a plain textbook particle
  filter told the scenario's σ and the device's power
  (:mod:`radiopose.evaluate.textbook_pf`), causal. Not in the default rows.
* ``re-solved at every emission`` — what the live re-solve could give at most
  with this machinery (session 26): every 0.1 s the offline passes
  (:class:`radiopose.tracker.resolve.Solver`) over all the packets up to
  that time, each packet's estimate taken from the first such re-solve at
  least 0.25 s after it (the live lag; so each packet sees 0.25–0.35 s of what
  follows, 0.30 s on average: slightly more than the live filter). Not a live
  method (about 20 re-solves of up to the whole trace per run); not in the
  default rows.

Before 2026-11-27 (session 10) the live rows left the offline passes on, so
since they became the default (docs/filter.md, "Round 6 as the default") those
rows measured batch ``locate`` with a short lag, not the live server.

Errors are pooled over runs (mean / median / p95), with the mean of the
per-run mean orientation errors and the worst run.

Usage::

    python scripts/live_lag_accuracy.py [--seeds 5] [--first-seed 1000] [--sigmas 0.5 3]
        [--variants causal "live, lag 0.25 s"] [--set FIELD=VALUE ...]
        [--duration-s 2] [--settle-s S] [--bins-s W] [--quick]

``--set`` overrides :class:`~radiopose.filtering.FilterConfig` fields in every
variant (e.g. ``--set jump_probability=0.01``); ``--variants`` picks the rows.
``--duration-s`` sets the traces' length (the standard scenario's 2 s by
default); ``--settle-s S`` adds the same errors over the packets from ``S``
seconds after each trace's first packet on (acquisition left out), beside the
whole-trace columns; ``--bins-s W`` adds a table of the orientation error in
time bins of width ``W`` (each run's mean in the bin, then the mean over runs).
"""

from __future__ import annotations

import argparse
import itertools
import shlex
import sys
import time
from dataclasses import dataclass, replace

import numpy as np

from radiopose.evaluate.demo import build_scorer, run_methods
from radiopose.evaluate.textbook_pf import registered_textbook
from radiopose.filtering import FilterConfig, FilterEstimate
from radiopose.filtering.config import overrides_or_exit
from radiopose.geometry import orientation_error_deg
from radiopose.likelihood import Scorer
from radiopose.packets import group_packets
from radiopose.scripting import (
    finite_float,
    non_negative_int,
    positive_float,
    positive_int,
    run_script,
    usage_errors,
)
from radiopose.simulate import ScenarioConfig, Simulation, simulate
from radiopose.tracker import Tracker, TrackerConfig
from radiopose.tracker.resolve import Solver

VARIANTS: dict[str, tuple[float | None, bool]] = {
    "causal": (None, False),
    "live, lag 0.1 s": (0.1, False),
    "live, lag 0.25 s": (0.25, False),
    "offline, lag 1 s": (1.0, True),
}
"""Variant → (the smoother's lag, seconds (``None``: causal); whether batch
``locate``'s offline-only passes run)."""

ANCHOR = "textbook"
"""The anchor's row (``--variants textbook``): :mod:`radiopose.evaluate.textbook_pf`."""

BOUND = "re-solved at every emission"
"""The bound's row (module docstring; :func:`prefix_bound`)."""

BOUND_STEP_S = 0.1
"""The bound's re-solve interval, seconds."""

LIVE_FILTER = replace(
    FilterConfig(),
    offline_offset_selection=False,
    offline_reverse_pass=False,
    offline_refine=False,
)
"""The filter as the live server runs it: no pass that needs the whole file."""


@dataclass(frozen=True)
class BoundRun:
    """The bound's errors, shaped as the fields of a ``MethodRun`` the table reads."""

    estimates: list[FilterEstimate]
    position_error_m: np.ndarray
    orientation_error_deg: np.ndarray
    truth_index: np.ndarray
    n_packets: int


def prefix_bound(sim: Simulation, scorer: Scorer, fcfg: FilterConfig, lag_s: float) -> BoundRun:
    """:data:`BOUND`: each packet's estimate from the offline passes over every
    packet up to its emission (module docstring), re-solved every
    :data:`BOUND_STEP_S`; the packets left at the end of the trace from the last
    re-solve (over the whole trace), as the live server's flush."""
    tx = sim.site.devices[0].transmitter
    device = Tracker(
        sim.site, "filter", TrackerConfig(filter=fcfg), {tx: scorer}, lag_s=lag_s
    ).device(tx)
    records = [(float(o.timestamp_s), device.space.heard(o), o.packet_id)
               for o in group_packets(sim.packets)]  # fmt: skip
    times = np.array([r[0] for r in records])
    chosen: dict[object, FilterEstimate] = {}
    solver = Solver(device)  # the prefixes grow: each packet is stepped once
    eps_s = 1e-9  # packet times are multiples of the interval: no rounding at a boundary
    for k in itertools.count():
        emit_s = times[0] + lag_s + k * BOUND_STEP_S
        solved = solver.solve(records[: int(np.searchsorted(times, emit_s + eps_s))])
        last = emit_s + eps_s >= times[-1]
        for key, est in solved.items():
            t_s = key[1]  # type: ignore[index]
            if key not in chosen and (last or t_s <= emit_s - lag_s + eps_s):
                chosen[key] = est
        if last:
            break
    row = {float(t): i for i, t in enumerate(sim.truth.timestamp_s)}
    keys = sorted(chosen, key=lambda k: k[1])  # type: ignore[index]
    idx = np.array([row[float(k[1])] for k in keys], dtype=int)  # type: ignore[index]
    pos = np.array([chosen[k].position_m for k in keys])
    ori = np.array([chosen[k].orientation_deg for k in keys])
    return BoundRun(
        [chosen[k] for k in keys],
        np.linalg.norm(pos - sim.truth.position_m[idx], axis=1),
        orientation_error_deg(ori, sim.truth.orientation_deg[idx]),
        idx,
        len(records),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=positive_int, default=5, help="number of seeds")
    ap.add_argument("--first-seed", type=non_negative_int, default=1000)
    ap.add_argument("--sigmas", type=positive_float, nargs="+", default=[0.5, 3.0])
    ap.add_argument(
        "--variants", nargs="+", default=list(VARIANTS), choices=[*VARIANTS, ANCHOR, BOUND],
        help="which rows (default: the filter's four; 'textbook' adds issue 15's anchor, "
        f"{BOUND!r} the live re-solve's bound)",
    )  # fmt: skip
    ap.add_argument(
        "--set", nargs="*", default=[], metavar="FIELD=VALUE",
        help="FilterConfig overrides for every variant",
    )  # fmt: skip
    ap.add_argument(
        "--duration-s", type=finite_float, default=None,
        help="trace length, seconds (default: the scenario's 2 s)",
    )  # fmt: skip
    ap.add_argument(
        "--interval-ms", type=finite_float, default=None,
        help="time between packets, ms (default: the scenario's 5; a phone sends every 100)",
    )  # fmt: skip
    ap.add_argument(
        "--settle-s", type=finite_float, default=None,
        help="also report the errors from this many seconds into each trace on",
    )  # fmt: skip
    ap.add_argument(
        "--bins-s", type=finite_float, default=None,
        help="also a table of the orientation error (mean of runs) in time bins of this width",
    )  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    args = ap.parse_args(argv)
    overrides = overrides_or_exit(ap, args.set)
    variants = {v: VARIANTS.get(v, (None, False)) for v in args.variants}
    base = ScenarioConfig.smoke() if args.quick else ScenarioConfig()
    if args.duration_s is not None:
        if not args.duration_s > 0:
            ap.error(f"--duration-s must be > 0, got {args.duration_s}")
        base = replace(base, duration_s=args.duration_s)
    if args.interval_ms is not None:
        base = replace(base, interval_ms=args.interval_ms)
    settle = args.settle_s
    if settle is not None and not 0 <= settle < base.duration_s:
        ap.error(f"--settle-s must be in [0, {base.duration_s:g}), got {settle}")
    width = args.bins_s
    if width is not None and not 0 < width <= base.duration_s:
        ap.error(f"--bins-s must be in (0, {base.duration_s:g}], got {width}")
    with usage_errors(ap):  # σ and duration within the scenario's ranges, before the runs
        for sigma in args.sigmas:
            replace(base, noise_db=sigma).validate()
    with usage_errors(ap, "--set"):  # the overrides with each variant's own settings
        for lag_s, offline in variants.values():
            fcfg = FilterConfig() if offline else LIVE_FILTER
            TrackerConfig(smoothing_lag_s=lag_s, filter=replace(fcfg, **overrides))
    edges = [] if width is None else list(np.arange(0.0, base.duration_s - 1e-9, width))
    bin_lines = [
        "| σ (dB) | variant | " + " | ".join(f"{a:g}–{a + width:g} s" for a in edges) + " |",
        "|---:|:---|" + "---:|" * len(edges),
    ] if width is not None else []  # fmt: skip
    after = "" if settle is None else f" after {settle:g} s: pos mean | ori mean of runs | worst |"
    lines = [
        "| σ (dB) | variant | coverage | pos mean (m) | pos median | pos p95 | ori mean (°) "
        "| ori median | ori p95 | ori mean of runs | worst run |" + after,
        "|---:|:---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        + ("" if settle is None else "---:|---:|---:|"),
    ]
    t_start = time.perf_counter()
    for sigma in args.sigmas:
        per: dict[str, list] = {v: [] for v in variants}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            sim = simulate(replace(base, noise_db=sigma), seed)
            scorer = build_scorer(sim, "numba")
            for name, (lag_s, offline) in variants.items():
                fcfg = FilterConfig() if offline else LIVE_FILTER
                cfg = TrackerConfig(smoothing_lag_s=lag_s, filter=replace(fcfg, **overrides))
                if name == BOUND:
                    live = replace(LIVE_FILTER, **overrides)
                    run = prefix_bound(sim, scorer, live, VARIANTS["live, lag 0.25 s"][0])
                elif name == ANCHOR:  # told this scenario's σ (and the power, as every run is)
                    with registered_textbook(sigma) as anchor:
                        run = run_methods(sim, (anchor.name,), cfg, scorer)[anchor.name]
                else:
                    run = run_methods(sim, ("filter",), cfg, scorer)["filter"]
                t_s = sim.truth.timestamp_s
                per[name].append((run, t_s[run.truth_index] - t_s[0]))
                print(
                    f"σ {sigma:g} seed {seed} {name}: pos {run.position_error_m.mean():.3f} m, "
                    f"ori {run.orientation_error_deg.mean():.2f}°",
                    file=sys.stderr,
                    flush=True,
                )
        for name, timed in per.items():
            runs = [r for r, _ in timed]
            pe = np.concatenate([r.position_error_m for r in runs])
            oe = np.concatenate([r.orientation_error_deg for r in runs])
            cov = sum(len(r.estimates) for r in runs) / sum(r.n_packets for r in runs)
            per_run = [r.orientation_error_deg.mean() for r in runs]
            row = (
                f"| {sigma:g} | {name} | {100 * cov:.1f} % | {pe.mean():.3f} | "
                f"{np.median(pe):.3f} | {np.percentile(pe, 95):.3f} | {oe.mean():.2f} | "
                f"{np.median(oe):.2f} | {np.percentile(oe, 95):.2f} | {np.mean(per_run):.2f} | "
                f"{np.max(per_run):.1f} |"
            )
            if settle is not None:
                late = [(r, t >= settle) for r, t in timed]
                pe_late = np.concatenate([r.position_error_m[k] for r, k in late])
                late_runs = [r.orientation_error_deg[k].mean() for r, k in late]
                row += f" {pe_late.mean():.3f} | {np.mean(late_runs):.2f} | {max(late_runs):.1f} |"
            lines.append(row)
            if width is not None:  # each run's mean in the bin, then the mean over runs
                cells = []
                for a in edges:
                    in_bin = [r.orientation_error_deg[(t >= a) & (t < a + width)] for r, t in timed]
                    means = [float(v.mean()) for v in in_bin if v.size]
                    cells.append(f"{np.mean(means):.1f}" if means else "—")
                bin_lines.append(f"| {sigma:g} | {name} | " + " | ".join(cells) + " |")
    if bin_lines:
        title = "Orientation error (°) by time since each trace's first packet (mean of runs):"
        lines += ["", title]
        lines += ["", *bin_lines]
    lines.append("")
    command = shlex.join(
        ["python", "scripts/live_lag_accuracy.py", *(sys.argv[1:] if argv is None else argv)]
    )
    lines.append(
        f"Seeds {args.first_seed}–{args.first_seed + args.seeds - 1}, "
        f"{time.perf_counter() - t_start:.0f} s (`{command}`)."
    )
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
