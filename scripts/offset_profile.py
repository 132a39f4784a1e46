"""Does the coarse-grid offset profile identify the device's offset? (issue 15, round 8)

docs/filter.md, "Accuracy round 8". For each seed the standard scenario is
simulated (matched power, and with ``--loud`` 6 dB above the enrolled power),
and :func:`radiopose.filtering.offset_profile.offset_profile` is computed over
the whole file at each coarse-grid setting given: its argmax (pose marginal
and pose profile) against the true offset (0 or +6 dB), and the margin of the
argmax over the enrolled power (``ℓ(b*) − ℓ(0)``, nats). σ is the simulated
one (the filter's estimate offline); the CPU time is the profile's alone
(the table built once per run, then timed separately).

Usage (tuning seeds only)::

    python scripts/offset_profile.py --seeds 7300-7349 --sigmas 0.5 3 [--loud]
        [--grids 1:15 0.5:10] [--windows 0.1] [--grid-sigmas 1]
    python scripts/offset_profile.py --quick
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from typing import cast

import numpy as np

from radiopose.filtering import FilterModel
from radiopose.filtering.offset_profile import CoarseTable, offset_profile
from radiopose.likelihood import Scorer, candidate_space
from radiopose.packets import group_packets
from radiopose.scripting import positive_float, positive_int, run_script, usage_errors
from radiopose.simulate import ScenarioConfig, seed_range, simulate


class _NoScorer:
    """A stand-in for the site's scorer: the profile never searches the fine grid."""


def _grid(text: str) -> tuple[float, float]:
    """``STEP_M:STEP_DEG``, both finite and > 0 (the parser's usage error otherwise)."""
    a, colon, b = text.partition(":")
    if not colon:
        raise argparse.ArgumentTypeError(f"{text!r} is not STEP_M:STEP_DEG")
    try:
        return positive_float(a), positive_float(b)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not STEP_M:STEP_DEG: {exc}") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=seed_range, default=range(7300, 7301), help="FIRST-LAST (tuning seeds only)"
    )
    ap.add_argument("--sigmas", type=positive_float, nargs="+", default=[3.0])
    ap.add_argument("--loud", action="store_true", help="also the device 6 dB above its power")
    ap.add_argument("--grids", type=_grid, nargs="+", default=[(1.0, 15.0)], help="STEP_M:STEP_DEG")
    ap.add_argument(
        "--windows", type=positive_float, nargs="+", default=[0.1], help="window lengths, s"
    )
    ap.add_argument("--grid-sigmas", type=positive_float, nargs="+", default=[0.5], help="σ_g, dB")
    ap.add_argument("--stride", type=positive_int, default=1, help="every n-th window only")
    ap.add_argument("--quick", action="store_true", help="a small site: checks that it runs")
    args = ap.parse_args(argv)
    base = ScenarioConfig.smoke() if args.quick else ScenarioConfig()
    with usage_errors(ap):  # σ within the scenario's range, before the runs
        for sigma in args.sigmas:
            replace(base, noise_db=sigma).validate()
    seeds = [5] if args.quick else args.seeds
    offsets = np.arange(-12.0, 12.01, 0.5)
    devices = [0.0, 6.0] if args.loud else [0.0]
    rows: dict[tuple[object, ...], list[tuple[float, float, float, float, float]]] = {}
    for sigma in args.sigmas:
        for seed in seeds:
            sim = simulate(replace(base, noise_db=sigma), seed)
            tx = sim.site.devices[0].transmitter
            space = candidate_space(sim.site, tx)
            # the profile reads the model's maps only: no scorer needed (cheaper)
            model = FilterModel.build(sim.site, space, cast("Scorer", _NoScorer()))
            obs = group_packets(sim.packets)
            base_records = [(o.timestamp_s, space.heard(o), o.packet_id) for o in obs]
            tables = {g: CoarseTable.build(model, *g) for g in args.grids}
            for dev in devices:
                recs = [
                    (t, type(h)(h.receiver_index, h.rss_dbm + dev), k) for t, h, k in base_records
                ]
                for g, table in tables.items():
                    for w in args.windows:
                        for gs in args.grid_sigmas:
                            c0 = time.process_time()
                            prof = offset_profile(
                                table, recs, sigma, offsets, w, gs, stride=args.stride
                            )
                            cpu = time.process_time() - c0
                            i0 = int(np.argmin(np.abs(offsets)))
                            bm, bp = prof.best_db("marginal"), prof.best_db("profile")
                            mm = float(prof.marginal.max() - prof.marginal[i0])
                            line = (
                                f"σ {sigma:g} seed {seed} device {dev:+.0f} grid {g[0]:g} m/"
                                f"{g[1]:g}° window {w:g} s σg {gs:g}: marginal argmax "
                                f"{bm:+.1f} (margin {mm:.1f} nats), profile argmax {bp:+.1f}, "
                                f"{prof.n_windows} windows, {cpu * 1e3:.0f} ms"
                            )
                            print(line, flush=True)
                            rows.setdefault((sigma, dev, g, w, gs), []).append(
                                (bm, bp, mm, cpu, dev)
                            )
    print()
    print(
        "| σ (dB) | device | grid | window (s) | σ_g (dB) | runs | marginal: within 1.5 dB "
        "| mean abs err (dB) | worst | profile: within 1.5 dB | CPU ms/run |"
    )
    print("|---:|---:|:---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for (sigma, dev, g, w, gs), vals in rows.items():
        a = np.array([v[:4] for v in vals])
        em, ep = np.abs(a[:, 0] - dev), np.abs(a[:, 1] - dev)
        print(
            f"| {sigma:g} | {dev:+.0f} | {g[0]:g} m × {g[1]:g}° | {w:g} | {gs:g} | {len(vals)} | "
            f"{int((em <= 1.5).sum())} | {em.mean():.2f} | {em.max():.1f} | "
            f"{int((ep <= 1.5).sum())} | {1e3 * a[:, 3].mean():.0f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
