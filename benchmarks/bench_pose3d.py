"""The 3-D filter (``filter`` at a 3-D site): packets/s, as a ratio against the 2-D filter.

``python -m benchmarks pose3d [--packets N] [--repeat R] [--markdown FILE]``.

Warm, in process: the 3-D hand-held scenario (``radiopose simulate --pose 3d``:
20 m × 20 m, 6 receivers at mixed heights, σ = 1 dB, a packet every 5 ms) and
the paper's 2-D standard scenario (4 receivers), ``N`` packets each (default
2,000). numba's kernels compiled and each site prepared (the 3-D filter's
height model and coarse acquisition table; the 2-D filter's scorer and model)
before timing; then the streaming causal ``Tracker.update`` of ``filter`` over
each trace, alternating, ``R`` repeats, median. Ratio: 3-D over 2-D in rate
terms (> 1: the 3-D filter is faster). A third row runs the 3-D filter with
the receivers' own gain in its height model (``survey_receiver_gain``, an
option) on the same trace. The first packet (the track's coarse
acquisition) is timed apart, and the 3-D model's build time is reported.

Every number is measured in this run on this machine; only the ratio compares
across runs (the project's machine is shared and noisy). CPU-time rates
(``process_time``) sit beside wall-clock ones.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from benchmarks.bench_filter import TX, standard_trace
from benchmarks.common import emit, machine, table
from radiopose.likelihood import candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets
from radiopose.simulate.handheld import HandheldConfig, simulate_handheld
from radiopose.tracker import Tracker, TrackerConfig


def trace_3d(n_packets: int, seed: int = 302):  # type: ignore[no-untyped-def]
    """The 3-D hand-held scenario with ``n_packets`` packets (σ = 1 dB, 6 receivers)."""
    return simulate_handheld(replace(HandheldConfig(), duration_s=n_packets * 0.005), seed=seed)


GAIN = "3-D filter, receiver gain"
"""The row of the 3-D filter with ``Pose3dConfig.survey_receiver_gain`` (an option,
off by default; docs/pose3d.md, "The receiver's gain in the height model")."""


def section_warm(n_packets: int, repeat: int) -> tuple[list[dict], dict]:
    cfg = TrackerConfig(kernel="numba")
    gain_cfg = replace(cfg, pose3d=replace(cfg.pose3d, survey_receiver_gain=True))
    trace = trace_3d(n_packets)
    sims = {"2-D filter (standard)": standard_trace(n_packets), "3-D filter": trace, GAIN: trace}
    configs = {name: gain_cfg if name == GAIN else cfg for name in sims}
    scorer2d = ShiftScorer(candidate_space(sims["2-D filter (standard)"].site, TX))
    scorers = {"2-D filter (standard)": {TX: scorer2d}, "3-D filter": None, GAIN: None}
    # warm-up: compile (or load) every kernel of each on a short trace
    short3d = trace_3d(100, 303)
    for name, sim in (
        ("2-D filter (standard)", standard_trace(100, 203)),
        ("3-D filter", short3d),
        (GAIN, short3d),
    ):
        tr = Tracker(
            sim.site, "filter", configs[name],
            scorers=scorers[name] if name.startswith("2") else None,
        )  # fmt: skip
        for o in group_packets(sim.packets):
            tr.update(o)
    extra: dict = {}

    def stream(name: str) -> tuple[float, float]:
        sim = sims[name]
        obs = group_packets(sim.packets)
        t0 = time.perf_counter()
        tracker = Tracker(sim.site, "filter", configs[name], scorers=scorers[name])
        tracker.device(TX)  # site preparation outside the timing
        t1 = time.perf_counter()
        tracker.update(obs[0])  # the track's acquisition
        t2 = time.perf_counter()
        extra.setdefault(name, []).append((t1 - t0, t2 - t1))
        t0, c0 = time.perf_counter(), time.process_time()
        for o in obs[1:]:
            tracker.update(o)
        n = len(obs) - 1
        return n / (time.perf_counter() - t0), n / (time.process_time() - c0)

    rates: dict[str, list[tuple[float, float]]] = {}
    for _ in range(repeat):
        for name in sims:
            rates.setdefault(name, []).append(stream(name))
    base = np.median(rates["2-D filter (standard)"], axis=0)
    rows = []
    for name in sims:
        r = np.asarray(rates[name])
        med = np.median(r, axis=0)
        prep, first = np.median(np.asarray(extra[name]), axis=0)
        rows.append(
            {
                "method": name,
                "receivers": len(sims[name].site.receivers),
                "packets": n_packets,
                "packets_per_s": float(med[0]),
                "range": f"{r[:, 0].min():.0f}-{r[:, 0].max():.0f}",
                "ratio_vs_2d": float(med[0] / base[0]),
                "packets_per_cpu_s": float(med[1]),
                "cpu_ratio_vs_2d": float(med[1] / base[1]),
                "prepare_s": float(prep),
                "first_packet_s": float(first),
            }
        )
    return rows, extra


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--packets", type=int, default=2000, help="packets in each trace")
    ap.add_argument("--repeat", type=int, default=3, help="repeats per measurement (median)")
    ap.add_argument("--markdown", help="also write the table to this Markdown file")
    args = ap.parse_args(argv)
    rows, _ = section_warm(args.packets, args.repeat)
    lines = [f"Machine: `{machine()}`", ""]
    lines += [f"### Warm, in process, streaming causal filter ({args.packets} packets)", ""]
    fmt = {
        "packets_per_s": ".0f", "ratio_vs_2d": ".2f", "packets_per_cpu_s": ".0f",
        "cpu_ratio_vs_2d": ".2f", "prepare_s": ".2f", "first_packet_s": ".3f",
    }  # fmt: skip
    lines += table(rows, fmt)
    return emit(lines, args.markdown)


if __name__ == "__main__":
    sys.exit(main())
