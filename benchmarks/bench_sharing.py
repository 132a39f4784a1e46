"""Devices of one phone model in one tracker, and the live method at a 3-D site.

Two measurements behind session 29's changes (docs/performance.md, "Many
devices in the live pipeline"; docs/methods.md, "The live default"), each in
a fresh process of its own (the parent only starts them):

1. **Per-device cost.** A streaming :class:`~radiopose.tracker.Tracker`
   (``filter``, lag 0.25 s) at a site with ``N`` devices enrolled with one
   pattern and power: each device's first ``--packets`` packets, then the
   process's peak resident memory (``ru_maxrss``). At the standard 2-D site
   (the paper's grid) and at the simulated 3-D site (``radiopose simulate
   --pose 3d``, seed 5, 5° azimuths), where each further device's first
   packets are also timed (the 3-D model is built on the first one).
2. **Methods at the 3-D site.** Packets per second of ``full`` and of
   ``filter`` (lag 0.25 s) streaming the 3-D site's first 60 packets after 10
   warm-up packets; the ratio is to ``full`` in the same run.

Usage::

    python -m benchmarks sharing [--devices 1 20 100] [--packets 5] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from typing import Any

from benchmarks.common import emit, machine, table

_CHILD = r"""
import dataclasses, json, resource, sys, time
from radiopose.packets import group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import Tracker, TrackerConfig

kind, n, packets = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if kind == "2d":
    sim = simulate(ScenarioConfig(duration_s=0.2, noise_db=1.0), seed=202)
else:
    sim = simulate(ScenarioConfig(pose="3d", noise_db=1.0, azimuth_step_deg=5.0), seed=5)
d0 = sim.site.devices[0]
devs = tuple(dataclasses.replace(d0, transmitter=f"02:00:00:00:{i // 256:02x}:{i % 256:02x}")
             for i in range(n))
site = dataclasses.replace(sim.site, devices=devs)
obs = group_packets(sim.packets)
out = {}
if kind == "3d-methods":
    for m in ("full", "filter"):
        tr = Tracker(site, m, TrackerConfig(), lag_s=0.25 if m == "filter" else None)
        for o in obs[:10]:
            tr.update(dataclasses.replace(o, transmitter=devs[0].transmitter))
        t = time.perf_counter()
        for o in obs[10:70]:
            tr.update(dataclasses.replace(o, transmitter=devs[0].transmitter))
        out[m] = 60 / (time.perf_counter() - t)
else:
    tr = Tracker(site, "filter", TrackerConfig(), lag_s=0.25)
    starts = []
    for i, d in enumerate(devs):
        t = time.perf_counter()
        for o in obs[:packets]:
            tr.update(dataclasses.replace(o, transmitter=d.transmitter,
                                          packet_id=f"{i}-{o.packet_id}"))
        starts.append(time.perf_counter() - t)
    out = {"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
           "first_device_s": starts[0],
           "later_device_s": sum(starts[1:]) / max(len(starts) - 1, 1)}
print(json.dumps(out))
"""


def _child(*args: object) -> dict[str, Any]:
    res = subprocess.run(
        [sys.executable, "-c", _CHILD, *map(str, args)], capture_output=True, text=True, check=True
    )
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    from radiopose.scripting import check_output, positive_int

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=positive_int, nargs="+", default=[1, 20, 100])
    ap.add_argument("--packets", type=positive_int, default=5, help="packets per device")
    ap.add_argument("--markdown", default=None, help="also write the report here")
    a = ap.parse_args(argv)
    if a.markdown is not None:
        check_output(ap, "--markdown", files=[a.markdown])
    rows = []
    for kind in ("2d", "3d"):
        for n in a.devices:
            r = _child(kind, n, a.packets)
            rows.append({"site": kind, "devices": n, **r})
            print(f"{kind} {n}: {r}", file=sys.stderr, flush=True)
    rates = _child("3d-methods", 1, 0)
    methods = [
        {"method": m, "packets_per_s": v, "ratio_vs_full": v / rates["full"]}
        for m, v in rates.items()
    ]
    lines = [f"Machine: `{machine()}`", "", "### 1. Per-device cost (`filter`, lag 0.25 s)", ""]
    lines += table(rows, {"peak_rss_mb": ".0f", "first_device_s": ".2f", "later_device_s": ".3f"})
    lines += ["### 2. Methods streaming at the 3-D site (60 packets after 10)", ""]
    lines += table(methods, {"packets_per_s": ".1f", "ratio_vs_full": ".3f"})
    return emit(lines, a.markdown)


if __name__ == "__main__":
    from radiopose.scripting import run_script

    raise SystemExit(run_script(main))
