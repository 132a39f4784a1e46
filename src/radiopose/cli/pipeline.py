"""``radiopose locate`` and ``radiopose score`` (interchange contract, "CLI calls")."""

from __future__ import annotations

import gc
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from radiopose.cli import app


@app.command(short_help="Estimate each packet's position and orientation.")
def locate(
    site: Annotated[Path, typer.Argument(help="Site directory (site.toml, receivers.csv, …).")],
    packets: Annotated[Path, typer.Argument(help="Synchronised packets.csv.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Estimates CSV to write.")],
    method: Annotated[
        str,
        typer.Option(
            help="full, location, orientation, top, lms, filter or a plugin's (docs/methods.md)."
        ),
    ] = "full",
    kernel: Annotated[
        str,
        typer.Option(
            help="Likelihood scorer: numba (compiled, default), numpy (fallback) or "
            "reference (exhaustive); all give the same estimates."
        ),
    ] = "numba",
    acquisition_window_ms: Annotated[
        float | None,
        typer.Option(
            help="Window over which packets are pooled to (re-)acquire a track, ms "
            "(0: each packet on its own, the paper's pipeline applied literally). "
            "Default: TrackerConfig's."
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Estimate position and orientation of every packet; write ESTIMATES.csv.

    The run summary (packets in, estimates out, skips with reasons) goes to stderr.
    A site may carry its own noise and motion priors for ``filter`` in
    SITE/tracker.toml (docs/real-data.md); they are used and named on stderr.
    """
    frozen = gc.get_freeze_count()  # 0 unless a host process froze its own objects
    try:
        _locate(site, packets, out, method, kernel, acquisition_window_ms, quiet)
    finally:
        if not frozen:
            gc.unfreeze()  # undo _locate's freeze (a no-op if it did not get there)


def _locate(
    site: Path,
    packets: Path,
    out: Path,
    method: str,
    kernel: str,
    acquisition_window_ms: float | None,
    quiet: bool,
) -> None:
    """The body of :func:`locate` (its arguments)."""
    from radiopose.errors import InputError
    from radiopose.estimates import write_estimates_csv
    from radiopose.likelihood import SCORERS
    from radiopose.packets import read_packets_csv
    from radiopose.site_io import load_site
    from radiopose.tracker import METHODS, TrackerConfig
    from radiopose.tracker import locate as run_locate
    from radiopose.tracker_settings import apply_tracker_settings, load_site_settings

    if method not in METHODS:
        raise InputError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    if kernel not in SCORERS:
        raise InputError(f"--kernel must be one of {', '.join(sorted(SCORERS))}, got {kernel!r}")
    if acquisition_window_ms is not None and not 0 <= acquisition_window_ms < math.inf:
        raise InputError(
            f"--acquisition-window-ms must be a finite number >= 0, got {acquisition_window_ms}"
        )
    from radiopose.tables import check_output_paths, check_outputs_not_inputs

    check_output_paths(files=[out])  # before the work, not after it
    check_outputs_not_inputs([out], [packets, site])
    if not gc.get_freeze_count():
        # The objects made so far (the imported modules: numpy's, numba's,
        # ours) outlive the run: kept out of the cyclic collector's full passes
        # while it runs, which otherwise rescan them (≈ 0.1 CPU s of a
        # 2,000-packet `filter` run; docs/performance.md, "Ninth pass"); undone
        # by locate when the run ends. The same estimates.
        gc.freeze()
    the_site = load_site(site)
    pk = read_packets_csv(packets)
    from radiopose.site import site_is_3d
    from radiopose.tracker import PAPER_METHODS, needs_scorer

    if site_is_3d(the_site) and method in PAPER_METHODS and needs_scorer(METHODS[method]):
        # the paper's top-k methods search the whole candidate grid per packet
        print(
            f"note: {site} is a 3-D site; {method} scores every candidate of every "
            "packet there (slow: ≈ 8 packets per CPU-second on the simulated 3-D site); "
            "--method filter tracks height, pitch and roll (docs/pose3d.md)",
            file=sys.stderr,
        )
    config = TrackerConfig(kernel=kernel)
    settings, settings_path = load_site_settings(site)
    if settings_path is not None:  # [filter], [filter.pose3d] and the lag
        config = apply_tracker_settings(config, settings)
        print(f"tracker settings from {settings_path}", file=sys.stderr)
    if acquisition_window_ms is not None:
        config = replace(config, acquisition_window_s=acquisition_window_ms / 1000.0)
    from radiopose.cli import packet_progress

    with packet_progress(f"locate ({method})", not quiet and sys.stderr.isatty()) as (progress, _):
        result = run_locate(the_site, pk, method, config, progress)
    extra = None
    if method == "filter" and len(result.estimates):
        from radiopose.packets import group_packets
        from radiopose.security.detection import ALARM_COLUMN, SCORE_COLUMN, score_estimates

        det = score_estimates(
            the_site,
            group_packets(pk),
            result.estimates,
            reacquire_gap_s=config.filter.reacquire_gap_s,
        )
        extra = {SCORE_COLUMN: det.score_nats, ALARM_COLUMN: det.alarm.astype("int64")}
        onsets = det.alarm_onsets().size
        print(
            f"spoofing detector: {onsets} alarm{'s' * (onsets != 1)} "
            f"({int(det.alarm.sum())} of {len(det.alarm)} estimates flagged; docs/security.md)",
            file=sys.stderr,
        )
    write_estimates_csv(result.estimates, out, extra)
    for line in result.summary.lines():
        print(line, file=sys.stderr)
    print(f"wrote {out}", file=sys.stderr)


@app.command(short_help="The tracking methods --method accepts, and where each is from.")
def methods() -> None:
    """Every registered tracking method: the paper's five, filter, and those of
    plugins (entry points of radiopose.methods, RADIOPOSE_METHODS;
    docs/methods.md), with what each estimates and where it comes from."""
    from radiopose.tracker import METHOD_NAMES, METHODS
    from radiopose.tracker.registry import plugin_sources

    sources = plugin_sources()
    print(f"{'method':<16} {'orientation':<11} {'lagged':<6}  {'from':<24} label")
    for name, m in METHODS.items():
        origin = "built-in" if name in METHOD_NAMES else sources.get(name, "register_method")
        print(
            f"{name:<16} {'yes' if m.estimates_orientation else 'no':<11} "
            f"{'yes' if m.lagged else 'no':<6}  {origin:<24} {m.label}"
        )


@app.command(short_help="Errors and coverage of estimates vs. the truth.")
def score(
    truth: Annotated[Path, typer.Argument(help="truth.csv of the packets.")],
    estimates: Annotated[Path, typer.Argument(help="estimates.csv to score.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    tolerance_ms: Annotated[
        float | None,
        typer.Option(
            "--tolerance-ms",
            help="How far an estimate's time may be from its truth row's, ms (default: just "
            "under half the smallest spacing of one transmitter's truth rows, so each "
            "estimate has one row; 2.5 ms at the simulator's 5 ms, which covers packets "
            "that went through pcap and sync).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Position error (m), orientation error (°) and coverage: mean, median, p95 per method."""
    from radiopose.errors import InputError
    from radiopose.estimates import read_estimates_csv
    from radiopose.evaluate.scoring import score as run_score
    from radiopose.packets import read_truth_csv

    t = read_truth_csv(truth)
    e = read_estimates_csv(estimates)
    if tolerance_ms is not None and not (math.isfinite(tolerance_ms) and 0 <= tolerance_ms <= 1000):
        raise InputError(f"--tolerance-ms must be in [0, 1000] ms, got {tolerance_ms:g}")
    scores = run_score(t, e, None if tolerance_ms is None else tolerance_ms / 1e3)
    if as_json:
        print(json.dumps([s.to_dict() for s in scores], indent=1))
        return

    def fmt(x: float | None, d: int) -> str:
        return "-" if x is None else f"{x:.{d}f}"

    print(
        f"{'method':<12} {'coverage':>9} {'estimates':>10}  {'position error (m)':>24}  "
        f"{'orientation error (deg)':>24}"
    )
    print(
        f"{'':<12} {'':>9} {'':>10}  {'mean':>7} {'median':>7} {'p95':>8}  "
        f"{'mean':>7} {'median':>7} {'p95':>8}"
    )
    for s in scores:
        p = s.position_m
        o = s.orientation_deg
        om, omed, op = (None, None, None) if o is None else (o.mean, o.median, o.p95)
        print(
            f"{s.method:<12} {100 * s.coverage:>8.1f}% {s.n_estimates:>10}  "
            f"{fmt(p.mean, 3):>7} {fmt(p.median, 3):>7} {fmt(p.p95, 3):>8}  "
            f"{fmt(om, 2):>7} {fmt(omed, 2):>7} {fmt(op, 2):>8}"
        )
