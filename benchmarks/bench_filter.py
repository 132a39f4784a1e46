"""The Bayesian tracker (``filter``): packets/s and memory, as ratios against ``full``.

Sections (``python -m benchmarks filter [--packets N] [--repeat R] [--busy] [--parts]
[--markdown FILE]``):

1. **Warm, in process.** The paper's standard scenario (201 × 201 positions ×
   360 azimuths, 4 receivers, a packet every 5 ms), an ``N``-packet trace
   (default 2,000). numba's kernels compiled and the site prepared (scorer
   tables, :class:`~radiopose.filtering.FilterModel`) before timing; then the
   streaming ``Tracker.update`` (causal) and batch ``locate`` (fixed-lag
   smoother, the offline default) of ``filter`` and of ``full`` over the same
   trace, alternating, ``R`` repeats, median. Ratio: filter / full of the same
   mode.
2. **Whole process.** ``radiopose locate SITE PACKETS -o EST --method M`` in a
   fresh process on the same trace written to disk (wall time including
   interpreter start-up, imports, numba cache load, site preparation and CSV
   parsing), ``M`` = ``filter`` and ``full``, ``R`` repeats, median, after one
   untimed run of each (so numba's on-disk cache and the memo of the site's
   scipy-computed arrays, :mod:`radiopose.diskcache`, are filled: a second
   ``locate`` on a site); and the row ``filter, offline_workers = 1`` (the
   offline passes all in the one process, as before the eighth pass: the
   site's ``tracker.toml`` says so), and the row ``filter, refine_banded =
   false`` (the arbiter's sparse LU, round 6's solve; banded is the default),
   and ``filter, offline_coarse_track = false`` (without session 13's
   coarse-grid HMM candidate, the default since: what it costs a whole file).
   CPU: the process's and its forked children's. Peak memory: the largest
   ``ru_maxrss`` of the process and its children (read in a small launcher,
   since Linux carries a parent's ``ru_maxrss`` into its children); a forked
   child shares the parent's pages, so the two together use less than the sum.
3. **Where a fresh process spends its time**: imports of the command line,
   site load, packets CSV parsing, scorer tables, the filter's model, the
   first packet (the kernels' cache loads, the track's acquisition) and the
   next 49 packets, each timed (CPU) inside one process (second of two runs).
1b. **The live path** (``Tracker`` with the live server's 0.25 s lag, warm,
   the same trace, one track): ``filter`` with the live re-solve of the
   track's first half second (the default since session 25,
   docs/filter.md "The live re-solve") and without it
   (``live_resolve_times_s = ()``), alternating, ``R`` repeats, median; the
   ratio is with / without, and the slowest single ``update`` (ms) shows the
   re-solves' stall.
1c. **Beside a busy process** (``--busy``): streaming ``filter`` and ``full``
   (warm, the same trace) idle, then beside one other process that
   busy-loops on a core (started 1.5 s before), then the same with the
   compiled work's threads started regardless of the machine's load (the
   spare-core look forced to yes: what the load-average rule did before
   session 28); alternating, ``R`` repeats, median; the ratio is against
   the idle rate of the same method in this run.
4. **Where a warm packet spends its CPU time** (``--parts``): each part of
   ``filter`` (the fused kernel, the re-entry and its searches, σ, moments,
   smoother, the adapter) timed by a wrapper around its calls, batch and
   streaming, one run each.

Every number is measured in this run on this machine; only the ratios compare
across runs (the project's machine is shared and noisy). Beside wall-clock
rates the tables give CPU-time rates (``process_time``; the launcher's
children's user + system time), which another process's load disturbs far
less; all ratios are filter over full in rate terms (> 1: filter faster).
"""

from __future__ import annotations

import argparse
import contextlib
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import emit, machine, table
from radiopose.filtering import FilterConfig
from radiopose.likelihood import candidate_space
from radiopose.likelihood.compiled import ShiftScorer
from radiopose.packets import PacketObservation, group_packets, write_packets_csv
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.site import Site, write_site
from radiopose.tracker import Tracker, TrackerConfig, locate

TX = "02:00:00:00:00:01"
METHODS = ("filter", "full")


def standard_trace(n_packets: int, seed: int = 202):
    """The standard scenario with ``n_packets`` packets (σ = 1 dB)."""
    cfg = replace(ScenarioConfig(), duration_s=n_packets * 0.005, noise_db=1.0)
    return simulate(cfg, seed=seed)


def _stream_rates(
    site: Site, obs: list[PacketObservation], method: str, cfg: TrackerConfig, scorer: ShiftScorer
) -> tuple[float, float]:
    """Packets per wall second and per CPU second of a streaming ``Tracker`` of
    ``method`` over ``obs`` (the first packet, the site's preparation, untimed)."""
    tracker = Tracker(site, method, cfg, scorers={TX: scorer})
    tracker.update(obs[0])
    t0, c0 = time.perf_counter(), time.process_time()
    for o in obs[1:]:
        tracker.update(o)
    n = len(obs) - 1
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def section_warm(n_packets: int, repeat: int) -> list[dict]:
    sim = standard_trace(n_packets)
    space = candidate_space(sim.site, TX)
    scorer = ShiftScorer(space)
    obs = group_packets(sim.packets)
    cfg = TrackerConfig(kernel="numba")
    # warm-up: compile (or load) every kernel of both methods on a short trace
    warm = standard_trace(100, seed=203)
    for m in METHODS:
        locate(warm.site, warm.packets, m, cfg)

    def stream(method: str) -> tuple[float, float]:
        return _stream_rates(sim.site, obs, method, cfg, scorer)

    def batch(method: str) -> tuple[float, float]:
        t0, c0 = time.perf_counter(), time.process_time()
        locate(sim.site, sim.packets, method, cfg, scorers={TX: scorer})
        return len(obs) / (time.perf_counter() - t0), len(obs) / (time.process_time() - c0)

    rates: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for _ in range(repeat):
        for mode, fn in (("streaming Tracker.update", stream), ("batch locate", batch)):
            for m in METHODS:
                rates.setdefault((mode, m), []).append(fn(m))
    out = []
    for mode in ("streaming Tracker.update", "batch locate"):
        full = np.median(rates[(mode, "full")], axis=0)
        for m in METHODS:
            r = np.asarray(rates[(mode, m)])
            med = np.median(r, axis=0)
            out.append(
                {
                    "mode": mode,
                    "method": m,
                    "packets": len(obs),
                    "packets_per_s": float(med[0]),
                    "range": f"{r[:, 0].min():.0f}-{r[:, 0].max():.0f}",
                    "ratio_vs_full": float(med[0] / full[0]),
                    "packets_per_cpu_s": float(med[1]),
                    "cpu_ratio_vs_full": float(med[1] / full[1]),
                }
            )
    return out


def section_live(n_packets: int, repeat: int) -> list[dict]:
    """Section 1b: the live path with and without the live re-solve."""
    sim = standard_trace(n_packets)
    scorer = ShiftScorer(candidate_space(sim.site, TX))
    obs = group_packets(sim.packets)
    variants = {
        "filter, live re-solve (default)": FilterConfig(),
        "filter, live_resolve_times_s = ()": replace(FilterConfig(), live_resolve_times_s=()),
    }

    def run(fcfg: FilterConfig) -> tuple[float, float]:
        cfg = TrackerConfig(kernel="numba", filter=fcfg)
        tracker = Tracker(sim.site, "filter", cfg, scorers={TX: scorer}, lag_s=LIVE_LAG_S)
        tracker.update(obs[0])  # site preparation outside the timing
        slowest, t0 = 0.0, time.perf_counter()
        for o in obs[1:]:
            t1 = time.perf_counter()
            tracker.update(o)
            tracker.take_delayed()
            slowest = max(slowest, time.perf_counter() - t1)
        return (len(obs) - 1) / (time.perf_counter() - t0), slowest

    run(variants["filter, live re-solve (default)"])  # warm the offline passes' kernels
    rates: dict[str, list[tuple[float, float]]] = {label: [] for label in variants}
    for _ in range(repeat):
        for label, fcfg in variants.items():
            rates[label].append(run(fcfg))
    base = float(np.median([r[0] for r in rates["filter, live_resolve_times_s = ()"]]))
    return [
        {
            "mode": f"streaming Tracker, lag {LIVE_LAG_S:g} s",
            "variant": label,
            "packets": len(obs),
            "packets_per_s": float(np.median([r[0] for r in rs])),
            "range": f"{min(r[0] for r in rs):.0f}-{max(r[0] for r in rs):.0f}",
            "ratio_vs_without": float(np.median([r[0] for r in rs])) / base,
            "slowest_update_ms": 1e3 * float(np.median([r[1] for r in rs])),
        }
        for label, rs in rates.items()
    ]


@contextlib.contextmanager
def _busy_core() -> Iterator[None]:
    """One other process busy-looping on a core for the block (started 1.5 s
    before it, so that the spare-core look sees it), then killed."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(1.5)
        yield
    finally:
        proc.kill()
        proc.wait()


@contextlib.contextmanager
def _threads_regardless() -> Iterator[None]:
    """The compiled work on two threads whatever the machine runs: the
    spare-core look answers yes (as the 1-minute load average did, before
    session 28, for a load below the core count)."""
    import radiopose.filtering.particle as particle
    import radiopose.likelihood.compiled as compiled

    saved = compiled.spare_core, particle.spare_core
    compiled.spare_core = particle.spare_core = lambda: True
    try:
        yield
    finally:
        compiled.spare_core, particle.spare_core = saved


def section_busy(n_packets: int, repeat: int) -> list[dict]:
    """Section 1c: streaming ``filter`` and ``full`` idle, beside one busy
    process, and beside it with the threads started regardless."""
    sim = standard_trace(n_packets)
    scorer = ShiftScorer(candidate_space(sim.site, TX))
    obs = group_packets(sim.packets)
    cfg = TrackerConfig(kernel="numba")

    def stream(method: str) -> float:
        return _stream_rates(sim.site, obs, method, cfg, scorer)[0]

    for m in METHODS:  # warm
        stream(m)
    conditions = {
        "idle": contextlib.nullcontext,
        "beside a busy process": _busy_core,
        "beside a busy process, threads regardless": _busy_threads_regardless,
    }
    rates: dict[tuple[str, str], list[float]] = {}
    for _ in range(repeat):
        for label, ctx in conditions.items():
            with ctx():
                for m in METHODS:
                    rates.setdefault((label, m), []).append(stream(m))
    out = []
    for label in conditions:
        for m in METHODS:
            r = rates[(label, m)]
            out.append(
                {
                    "condition": label,
                    "method": m,
                    "packets": len(obs),
                    "packets_per_s": float(np.median(r)),
                    "range": f"{min(r):.0f}-{max(r):.0f}",
                    "ratio_vs_idle": float(np.median(r) / np.median(rates[("idle", m)])),
                }
            )
    return out


@contextlib.contextmanager
def _busy_threads_regardless() -> Iterator[None]:
    with _busy_core(), _threads_regardless():
        yield


LIVE_LAG_S = 0.25
"""The live server's default lag, seconds (``LiveConfig.live_lag_s``)."""


_LAUNCH = """
import resource, subprocess, sys, time
t0 = time.perf_counter()
rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
wall = time.perf_counter() - t0
if rc.returncode:
    sys.exit(rc.stderr.decode())
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(wall, ru.ru_maxrss, ru.ru_utime + ru.ru_stime)
"""


def _run_cli(args: list[str]) -> tuple[float, float, float]:
    """Wall seconds, peak RSS (MB) and CPU seconds of ``python -m radiopose ARGS``
    in a fresh process."""
    res = subprocess.run(
        [sys.executable, "-c", _LAUNCH, sys.executable, "-m", "radiopose", *args],
        capture_output=True,
        text=True,
        check=True,
    )
    wall, kb, cpu = res.stdout.split()
    return float(wall), int(kb) / 1024.0, float(cpu)


SERIAL_FILTER = "filter, offline_workers = 1"
"""Section 2's row of ``filter`` with every offline pass in the one process (the
site's ``tracker.toml`` says so; docs/performance.md, "Eighth pass")."""


COARSE_FILTER = "filter, offline_coarse_track = false"
"""Section 2's row of ``filter`` without session 13's coarse-grid HMM candidate (the
default since; the site's ``tracker.toml`` says so; docs/filter.md, "Coarse-grid
HMM"): what the HMM costs a whole file, measured in the same run."""


SPARSE_FILTER = "filter, refine_banded = false"
"""Section 2's row of ``filter`` with the arbiter's sparse LU (round 6's solve; the
banded one is the default since 2026-11-27; docs/performance.md, "Ninth pass")."""


def section_process(n_packets: int, repeat: int, tmp: Path) -> list[dict]:
    sim = standard_trace(n_packets)
    site_dir = tmp / "site"
    write_site(sim.site, site_dir)
    serial_dir = tmp / "site_serial"
    write_site(sim.site, serial_dir)
    (serial_dir / "tracker.toml").write_text("[filter]\noffline_workers = 1\n", encoding="utf-8")
    sparse_dir = tmp / "site_sparse"
    write_site(sim.site, sparse_dir)
    (sparse_dir / "tracker.toml").write_text("[filter]\nrefine_banded = false\n", encoding="utf-8")
    coarse_dir = tmp / "site_coarse"
    write_site(sim.site, coarse_dir)
    (coarse_dir / "tracker.toml").write_text(
        "[filter]\noffline_coarse_track = false\n", encoding="utf-8"
    )
    packets = tmp / "packets.csv"
    write_packets_csv(sim.packets, packets)
    n = len(group_packets(sim.packets))
    rows = {m: (m, site_dir) for m in METHODS} | {
        SERIAL_FILTER: ("filter", serial_dir),
        SPARSE_FILTER: ("filter", sparse_dir),
        COARSE_FILTER: ("filter", coarse_dir),
    }

    def args(label: str) -> list[str]:
        m, site = rows[label]
        out = tmp / f"est_{label.replace(' ', '_').replace(',', '')}.csv"
        return ["locate", str(site), str(packets), "-o", str(out), "--method", m, "--quiet"]

    for label in rows:  # fill numba's cache; not timed
        _run_cli(args(label))
    runs: dict[str, list[tuple[float, float, float]]] = {label: [] for label in rows}
    for _ in range(repeat):
        for label in rows:
            runs[label].append(_run_cli(args(label)))
    full_wall = float(np.median([r[0] for r in runs["full"]]))
    full_cpu = float(np.median([r[2] for r in runs["full"]]))
    out = []
    for label in rows:
        walls = [r[0] for r in runs[label]]
        wall = float(np.median(walls))
        cpu = float(np.median([r[2] for r in runs[label]]))
        out.append(
            {
                "method": label,
                "packets": n,
                "wall_s": wall,
                "range_s": f"{min(walls):.2f}-{max(walls):.2f}",
                "packets_per_s": n / wall,
                "ratio_vs_full": full_wall / wall,
                "cpu_s": cpu,
                "cpu_ratio_vs_full": full_cpu / cpu,
                "peak_rss_mb": max(r[1] for r in runs[label]),
            }
        )
    return out


_STAGES = """
import sys, time
clock = time.process_time
t0 = clock()
import radiopose.cli
radiopose.cli._register()
t1 = clock()
from radiopose.packets import group_packets, read_packets_csv
from radiopose.site import load_site
from radiopose.tracker import Tracker, TrackerConfig
t2 = clock()
site = load_site(sys.argv[1])
t3 = clock()
pk = read_packets_csv(sys.argv[2])
obs = group_packets(pk)
t4 = clock()
tr = Tracker(site, sys.argv[3], TrackerConfig())
tr.device(obs[0].transmitter)
t5 = clock()
tr.update(obs[0])
t6 = clock()
for o in obs[1:50]:
    tr.update(o)
t7 = clock()
print(t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t6 - t5, (t7 - t6) / 49)
"""


def section_stages(tmp: Path) -> list[dict]:
    """Stages of a fresh process, run twice per method (the second is reported)."""
    site_dir, packets = tmp / "site", tmp / "packets.csv"
    out = []
    for m in METHODS:
        for _ in range(2):
            t0 = time.perf_counter()
            res = subprocess.run(
                [sys.executable, "-c", _STAGES, str(site_dir), str(packets), m],
                capture_output=True,
                text=True,
                check=True,
            )
            wall = time.perf_counter() - t0
        cli, lib, load, parse, prep, first, later = (float(x) for x in res.stdout.split())
        out.append(
            {
                "method": m,
                "process_wall_s": wall,
                "cli_imports_s": cli,
                "library_imports_s": lib,
                "load_site_s": load,
                "read_packets_csv_s": parse,
                "prepare_device_s": prep,
                "first_packet_s": first,
                "next_packets_s_each": later,
            }
        )
    return out


# (owner module, attribute, label) of the calls whose CPU time section 4 reports
_PARTS = (
    ("radiopose.tracker.stream", "Tracker.update", "Tracker.update (everything)"),
    ("radiopose.tracker.filter", "FilterMethod.step", "adapter: FilterMethod.step"),
    ("radiopose.filtering.particle", "ParticleFilter.step", "ParticleFilter.step"),
    ("radiopose.filtering.kernels", "packet_update", "packet_update (fused kernel)"),
    ("radiopose.filtering.particle", "ParticleFilter._reenter", "re-entry (_reenter)"),
    ("radiopose.filtering.particle", "FilterModel.search", "re-entry: grid searches"),
    ("radiopose.filtering.particle", "profile_offset_db", "re-entry: offset profiling"),
    ("radiopose.filtering.kernels", "fixed_offset_loglik", "re-entry: window evidence"),
    ("radiopose.filtering.particle", "ParticleFilter._inject_lineage", "re-entry: genealogy"),
    ("radiopose.filtering.particle", "ParticleFilter._update_sigma", "sigma estimate"),
    ("radiopose.filtering.kernels", "posterior_moments", "posterior moments"),
    ("radiopose.filtering.particle", "_summary", "estimate objects (_summary)"),
    ("radiopose.filtering.kernels", "resample_in_place", "resampling"),
    ("radiopose.filtering.lineage", "Lineage.push", "smoother: push"),
    ("radiopose.filtering.lineage", "Lineage.remap", "smoother: remap at resampling"),
    ("radiopose.filtering.particle", "ParticleFilter._emit", "smoother: emit"),
)


def section_parts(n_packets: int) -> list[dict]:
    """CPU time per packet of each part of ``filter`` (``_PARTS``, nested: a row
    includes the rows below it that it calls), batch ``locate`` (1 s smoother)
    and streaming ``Tracker.update`` (causal), one run each, warm. Each call
    is wrapped by a ``process_time`` timer, which adds ≈ 1 µs per call."""
    import importlib

    sim = standard_trace(n_packets)
    space = candidate_space(sim.site, TX)
    scorer = ShiftScorer(space)
    obs = group_packets(sim.packets)
    cfg = TrackerConfig(kernel="numba")
    warm = standard_trace(100, seed=203)
    locate(warm.site, warm.packets, "filter", cfg)
    spent: dict[str, float] = {}
    calls: dict[str, int] = {}
    undo = []
    for module, attr, label in _PARTS:
        owner = importlib.import_module(module)
        *path, name = attr.split(".")
        for p in path:
            owner = getattr(owner, p)
        f = owner.__dict__.get(name) if isinstance(owner, type) else getattr(owner, name, None)
        if f is None:  # not in this version of the code (a baseline run)
            continue

        def timed(*a, _f=f, _label=label, **kw):  # type: ignore[no-untyped-def]
            t0 = time.process_time()
            try:
                return _f(*a, **kw)
            finally:
                spent[_label] = spent.get(_label, 0.0) + time.process_time() - t0
                calls[_label] = calls.get(_label, 0) + 1

        setattr(owner, name, timed)
        undo.append((owner, name, f))
    rows = []
    try:
        for mode in ("batch locate", "streaming Tracker.update"):
            spent.clear()
            calls.clear()
            c0 = time.process_time()
            if mode == "batch locate":
                locate(sim.site, sim.packets, "filter", cfg, scorers={TX: scorer})
            else:
                tracker = Tracker(sim.site, "filter", cfg, scorers={TX: scorer})
                for o in obs:
                    tracker.update(o)
            total = time.process_time() - c0
            rows.append(
                {
                    "mode": mode,
                    "part": "total",
                    "calls": len(obs),
                    "ms_per_packet": 1e3 * total / len(obs),
                }
            )
            rows += [
                {
                    "mode": mode,
                    "part": label,
                    "calls": calls[label],
                    "ms_per_packet": 1e3 * spent[label] / len(obs),
                }
                for _, _, label in _PARTS
                if label in spent
            ]
    finally:
        for owner, name, f in reversed(undo):
            setattr(owner, name, f)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--packets", type=int, default=2000, help="packets in the trace")
    ap.add_argument("--repeat", type=int, default=3, help="repeats per measurement (median)")
    ap.add_argument("--skip-process", action="store_true", help="only the in-process section")
    ap.add_argument(
        "--parts", action="store_true", help="also the CPU time of each part of filter (section 4)"
    )
    ap.add_argument(
        "--busy",
        action="store_true",
        help="also streaming beside one busy-looping process (section 1c)",
    )
    ap.add_argument("--markdown", help="also write the tables to this Markdown file")
    args = ap.parse_args(argv)
    lines = [f"Machine: `{machine()}`", ""]
    lines += [f"### 1. Warm, in process ({args.packets} packets, standard scenario)", ""]
    lines += table(
        section_warm(args.packets, args.repeat),
        {
            "packets_per_s": ".0f",
            "ratio_vs_full": ".2f",
            "packets_per_cpu_s": ".0f",
            "cpu_ratio_vs_full": ".2f",
        },
    )
    lines += [f"### 1b. The live path ({args.packets} packets, lag {LIVE_LAG_S:g} s)", ""]
    lines += table(
        section_live(args.packets, args.repeat),
        {"packets_per_s": ".0f", "ratio_vs_without": ".2f", "slowest_update_ms": ".0f"},
    )
    if args.busy:
        lines += [f"### 1c. Beside a busy process ({args.packets} packets, streaming)", ""]
        lines += table(
            section_busy(args.packets, args.repeat),
            {"packets_per_s": ".0f", "ratio_vs_idle": ".2f"},
        )
    if not args.skip_process:
        with tempfile.TemporaryDirectory() as tmp:
            rows = section_process(args.packets, args.repeat, Path(tmp))
            lines += ["### 2. Whole process: `radiopose locate --method M`", ""]
            lines += table(
                rows,
                {
                    "wall_s": ".2f",
                    "packets_per_s": ".0f",
                    "ratio_vs_full": ".2f",
                    "cpu_s": ".2f",
                    "cpu_ratio_vs_full": ".2f",
                    "peak_rss_mb": ".0f",
                },
            )
            lines += ["### 3. Stages of a fresh process (CPU s; the process's wall s)", ""]
            stages = section_stages(Path(tmp))
            lines += table(stages, {k: ".3f" for k in stages[0]})
    if args.parts:
        lines += ["### 4. Where a warm packet of filter spends its CPU time", ""]
        lines += table(section_parts(args.packets), {"ms_per_packet": ".3f"})
    return emit(lines, args.markdown)


if __name__ == "__main__":
    sys.exit(main())
