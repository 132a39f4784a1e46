"""How much of the grid the compiled kernel's bounds skip (docs/performance.md).

For a few packets of the standard scenario, takes the final pruning threshold
(the 164-th best MSE: ``k = 100`` plus the kernel's oversampling of 64) and
evaluates the kernel's two lower bounds in numpy: the whole-row bound per
position (the prefilter) and the per-block bound over blocks of 24 azimuths.
Prints the fraction of positions and of blocks that survive. The kernel starts
from a looser threshold and tightens it as it goes, so it visits somewhat more.
Usage: ``python -m benchmarks prune [--sigma-db 1.0] [--packets 5] [--seed 101]``.

It restates the kernel's bounds in numpy, so it lives beside the benchmarks,
not among the scripts.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from radiopose.likelihood import candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate


def prune_statistics(sigma_db: float = 1.0, n_packets: int = 5, seed: int = 101) -> None:
    """Print, per packet, the fractions of positions and blocks the bounds keep."""
    sim = simulate(replace(ScenarioConfig(), duration_s=0.2, noise_db=sigma_db), seed=seed)
    space = candidate_space(sim.site, sim.site.devices[0].transmitter)
    sc = ShiftScorer(space)
    kk = 100 + sc.oversample
    for obs in group_packets(sim.packets)[:n_packets]:
        heard = space.heard(obs)
        r = heard.receiver_index
        w = (heard.rss_dbm - sc.centre_db[r]).astype(np.float32)
        cut = sc.score_heard(heard, kk).mse_db2[-1] * r.size
        e = w[:, None] - sc.base[r]  # (h, n_pos)
        t = sc.row0[r]
        x0 = np.maximum(sc.row_min[t] - e, 0) + np.maximum(e - sc.row_max[t], 0)
        positions = (x0**2).sum(axis=0) <= cut
        blo, bhi, _, _ = sc.bounds
        k = sc.off[r]
        x = np.maximum(blo[t, k] - e[..., None], 0) + np.maximum(e[..., None] - bhi[t, k], 0)
        blocks = ((x**2).sum(axis=0) <= cut) & positions[:, None]
        print(
            f"packet {obs.packet_id}: positions surviving the row bound "
            f"{100 * positions.mean():.1f} %, blocks surviving {100 * blocks.mean():.3f} %"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigma-db", type=float, default=1.0, help="RSS noise σ, dB")
    ap.add_argument("--packets", type=int, default=5, help="packets to examine")
    ap.add_argument("--seed", type=int, default=101)
    args = ap.parse_args(argv)
    prune_statistics(args.sigma_db, args.packets, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
