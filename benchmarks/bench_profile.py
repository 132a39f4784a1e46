"""Where the time of a warm packet goes in the compiled scorer (docs/performance.md).

Scores the benchmark's 200-packet trace of the standard scenario (seed 101,
σ = 1 dB) three times with :class:`~radiopose.likelihood.compiled.ShiftScorer`
and prints, per packet, the total and the time spent in the threshold pass,
the prefilter, the kernel calls (main pass, and the threshold pass when it
uses the per-chunk heaps; the parallel kernel when a core is spare, else the
serial ones) and the exact float64 rescoring; the remainder is
Python bookkeeping. The timers wrap the calls, so they add a few µs each.
Usage: ``python -m benchmarks profile [--seed 101] [--packets 200] [--repeat 3]``.

It wraps the scorer's private passes (monkeypatching them with timers), so it
lives beside the benchmarks, not among the scripts.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import replace

import radiopose.likelihood.compiled as compiled
from radiopose.likelihood import candidate_space
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate


def profile(seed: int = 101, n_packets: int = 200, repeat: int = 3) -> None:
    """Print, per repeat, the warm per-packet time and its parts (ms/packet)."""
    sim = simulate(replace(ScenarioConfig(), duration_s=1.0, noise_db=1.0), seed=seed)
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    heard = [space.heard(p) for p in group_packets(sim.packets)][:n_packets]
    sc = compiled.ShiftScorer(space)
    sc.score_heard(heard[0], 100)  # compile / load, and a hint for the next packet
    spent: dict[str, float] = {}

    def timed(name: str, fn: Callable) -> Callable:
        def wrapper(*args: object, **kwargs: object) -> object:
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            spent[name] = spent.get(name, 0.0) + time.perf_counter() - t0
            return out

        return wrapper

    sc._threshold = timed("threshold pass", sc._threshold)
    sc._kernel = timed("kernel calls", sc._kernel)
    # the module's functions wrapped for the run only (a caller in the same
    # process, e.g. the test suite, gets them back)
    # (with no core spare the serial kernels run in place of ``sc._kernel``)
    names = ("_prefilter", "exact_mse_db2", "_shift_topk_shared", "_shift_topk_serial")
    saved = {n: getattr(compiled, n) for n in names}
    compiled._prefilter = timed("prefilter", compiled._prefilter)
    compiled.exact_mse_db2 = timed("exact rescoring", compiled.exact_mse_db2)
    compiled._shift_topk_shared = timed("kernel calls", compiled._shift_topk_shared)
    compiled._shift_topk_serial = timed("kernel calls", compiled._shift_topk_serial)
    try:
        for _ in range(repeat):
            spent.clear()
            t0 = time.perf_counter()
            for h in heard:
                sc.score_heard(h, 100)
            total = time.perf_counter() - t0
            parts = ", ".join(f"{k} {1e3 * v / len(heard):.3f}" for k, v in spent.items())
            print(f"warm packet {1e3 * total / len(heard):.3f} ms: {parts} (ms/packet)")
    finally:
        for n, fn in saved.items():
            setattr(compiled, n, fn)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--packets", type=int, default=200, help="packets of the trace to score")
    ap.add_argument("--repeat", type=int, default=3, help="passes over the trace")
    args = ap.parse_args(argv)
    profile(args.seed, args.packets, args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
