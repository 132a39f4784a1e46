"""``radiopose demo``: its outputs, its table, and the figure of the filter's track.

End to end on a short walk (the default is 30 s; a few seconds keep the suite
fast), then the plotting functions of the new figure on hand-made tracks whose
drawing can be checked exactly.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import PatchCollection

from radiopose import plots
from radiopose.cli import main
from radiopose.estimates import Estimates, read_estimates_csv
from radiopose.evaluate.demo import MethodRun, calibration
from radiopose.tracker import METHODS, RunSummary

FIGURES = (
    "scene.png",
    "survey_map_rx1.png",
    "patterns.png",
    "mse_map.png",
    "trajectory.png",
    "orientation_error.png",
    "filter_track.png",
)
ROW = re.compile(r"^\| [\d.]+ \| (\w+) \| ([\d.]+) % \| ([\d.]+) \|", re.MULTILINE)


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """One short demo (4 s of the walk, 200 packets), shared by the tests below."""
    out = tmp_path_factory.mktemp("demo") / "d"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["demo", "-o", str(out), "--duration-s", "4", "--seed", "11"])
    assert code == 0
    return out, buf.getvalue()


def test_demo_prints_a_table_with_every_method_and_a_filter_row(demo_run) -> None:
    _, out = demo_run
    rows = {m: (float(cov), float(pos)) for m, cov, pos in ROW.findall(out)}
    assert list(rows) == list(METHODS)
    cov, pos_m = rows["filter"]
    assert cov >= 99.0  # an estimate for every packet
    assert rows["full"][0] < 50.0  # the paper's pipeline answers sparsely
    assert pos_m < 1.5  # a broken filter (or scoring) lands metres off
    assert "4 s walk with turns: 200 packets, one every 20 ms (the paper: 5 ms" in out
    assert re.search(r"filter's stated uncertainty: median position_std_m [\d.]+ m", out)
    assert "and the Bayesian tracker (filter)" in out


def test_demo_writes_non_trivial_figures_and_estimates(demo_run) -> None:
    d, out = demo_run
    for name in FIGURES:
        path = d / name
        assert path.stat().st_size > 20_000, name
        assert f"wrote {path}" in out
        img = plt.imread(path)
        assert img.ndim == 3 and img[..., :3].std() > 0.05, name  # not a blank canvas
    h, w = plt.imread(d / "filter_track.png").shape[:2]
    assert (w, h) == (1760, 935)  # 16 in × 8.5 in at 110 dpi
    for m in METHODS:
        est = read_estimates_csv(d / f"estimates_{m}.csv")
        assert len(est) > 0 and set(est.method) == {m}
    f = read_estimates_csv(d / "estimates_filter.csv")
    assert f.position_std_m is not None and f.azimuth_std_deg is not None
    assert len(f) >= 0.99 * 200
    assert (d / "scenario" / "truth.csv").is_file() and (d / "scenario" / "packets.csv").is_file()


def test_demo_follows_every_methods_packets(tmp_path: Path, capsys, monkeypatch) -> None:
    """On a terminal the demo's bar follows each method's packets to the last
    (``radiopose demo`` once printed only "localising ..." for 20 s)."""
    import radiopose.cli as cli

    seen: list[tuple[str, int, int]] = []

    @contextlib.contextmanager
    def recording(label: str, show: bool):  # type: ignore[no-untyped-def]
        yield (lambda m, d, t: seen.append((m, d, t))), print

    monkeypatch.setattr(cli, "method_progress", recording)
    code, _, _ = _run(["demo", "-o", str(tmp_path / "d"), "--duration-s", "1"], capsys)
    assert code == 0
    assert {m for m, _, _ in seen} == set(METHODS)
    for m in METHODS:
        _, done, total = [x for x in seen if x[0] == m][-1]
        assert done == total == 50  # 1 s, a packet every 20 ms


def test_demo_method_option_is_for_live(tmp_path: Path, capsys) -> None:
    code, _, err = _run(["demo", "-o", str(tmp_path / "d"), "--method", "full"], capsys)
    assert code == 2 and "--method applies to --live" in err and err.count("\n") == 1
    code, _, err = _run(["demo", "-o", str(tmp_path / "d"), "--live", "--method", "x"], capsys)
    assert code == 2 and "--method must be one of" in err and err.count("\n") == 1
    for pose in ("2d", "3d"):  # --port, even at its default value, only with --live
        code, _, err = _run(
            ["demo", "-o", str(tmp_path / "d"), "--pose", pose, "--port", "8000"], capsys
        )
        assert code == 2 and "--port applies to --live" in err and err.count("\n") == 1
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--live"], "--live does not"),
        (["--seed", "7"], "--seed does not"),  # the default value, still given
        (["--noise-db", "2"], "--noise-db does not"),
        (["--duration-s", "3", "--interval-ms", "5"], "--duration-s, --interval-ms do not"),
        (["--method", "filter"], "--method does not"),
        (["--port", "8001"], "--port does not"),
        (["--pose", "2d"], "--pose does not"),
    ],
)
def test_real_demo_refuses_the_options_it_would_ignore(
    tmp_path: Path, capsys, extra, named
) -> None:
    code, _, err = _run(["demo", "--real", "-o", str(tmp_path / "d"), *extra], capsys)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"radiopose: {named} apply to --real")
    assert not (tmp_path / "d").exists()


def test_live_demo_serves_the_chosen_method() -> None:
    from radiopose.server.demo import serve_command

    cmd = serve_command(Path("site"), "sqlite:///x.db", 8123, "filter")
    assert cmd[cmd.index("--method") + 1] == "filter"
    assert "--method" not in serve_command(Path("site"), "sqlite:///x.db", 8123)


# ----------------------------------------------------------------------------- figures
def _track(n: int = 50, *, method: str = "filter", std: bool = True) -> Estimates:
    t = np.arange(n) * 0.1
    pos = np.column_stack([1.0 + 0.1 * np.arange(n), np.full(n, 5.0), np.ones(n)])
    ori = np.column_stack([np.linspace(350.0, 370.0, n) % 360.0, np.zeros(n), np.zeros(n)])
    return Estimates(
        t,
        np.full(n, "tx", dtype=object),
        np.array([str(i) for i in range(n)], dtype=object),
        pos,
        ori,
        np.full(n, method, dtype=object),
        position_std_m=np.linspace(0.1, 2.0, n) if std else None,
        azimuth_std_deg=np.linspace(5.0, 40.0, n) if std else None,
    )


def test_track_plot_draws_the_stated_uncertainty() -> None:
    track = _track()
    sparse = _track(method="full", std=False).select(np.arange(50) % 10 == 0)
    ax = plots.plot_track_uncertainty(
        track.timestamp_s,
        track.position_m,
        track.orientation_deg[:, 0],
        track,
        {"full": sparse},
        n_packets=50,
        n_wedges=5,
    )
    cols = [c for c in ax.collections if isinstance(c, PatchCollection)]
    discs, wedges = cols[0], cols[1]
    # one disc per estimate, radius position_std_m, fainter the wider (1/r²)
    paths = discs.get_paths()
    assert len(paths) == 50
    radii = [0.5 * np.ptp(p.vertices[:, 0]) for p in paths]
    np.testing.assert_allclose(radii, track.position_std_m, rtol=1e-6)
    alpha = discs.get_facecolors()[:, 3]
    assert alpha[0] > alpha[-1] and np.all(np.diff(alpha) <= 0)
    # a wedge of ± azimuth_std_deg around the top (azimuth + 90° from +x)
    assert len(wedges.get_paths()) == 5
    idx = np.linspace(0, 49, 5).astype(int)
    for p, i in zip(wedges.get_paths(), idx, strict=True):
        v = p.vertices - track.position_m[i, :2]
        far = np.hypot(v[:, 0], v[:, 1]) > 0.5
        ang = np.degrees(np.arctan2(v[far, 1], v[far, 0]))
        centre = track.orientation_deg[i, 0] + 90.0
        spread = np.abs((ang - centre + 180.0) % 360.0 - 180.0)
        assert spread.max() == pytest.approx(track.azimuth_std_deg[i], abs=0.5)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "filter (100.0 % of packets)" in labels
    assert "full (10.0 % of packets)" in labels
    plt.close(ax.figure)


def test_azimuth_plot_unwraps_along_the_truth() -> None:
    track = _track()
    truth_az = track.orientation_deg[:, 0].copy()
    track.orientation_deg[:, 0] = (truth_az + 3.0) % 360.0  # 3° off, across 0/360
    ax = plots.plot_azimuth_over_time(track.timestamp_s, truth_az, track)
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    truth = lines["truth"].get_ydata()
    est = lines["filter"].get_ydata()
    np.testing.assert_allclose(truth, np.linspace(350.0, 370.0, 50), atol=1e-9)
    np.testing.assert_allclose(np.asarray(est) - truth, 3.0, atol=1e-9)
    plt.close(ax.figure)


def test_error_plot_legend_has_coverage_and_mean() -> None:
    t = np.arange(4.0)
    ax = plots.plot_error_over_time(
        {"filter": (t, np.array([0.1, 0.2, 0.3, 0.4])), "full": (t[:1], np.array([1.0]))},
        coverage={"filter": 1.0, "full": 0.25},
        stated=("filter: position_std_m", t, np.full(4, 0.5)),
    )
    labels = [x.get_text() for x in ax.get_legend().get_texts()]
    assert labels == [
        "filter: 100.0 % coverage, mean 0.25 m",
        "full: 25.0 % coverage, mean 1.00 m",
        "filter: position_std_m",
    ]
    plt.close(ax.figure)


def test_track_figure_needs_the_uncertainty_columns() -> None:
    track = _track(std=False)
    with pytest.raises(ValueError, match="position_std_m"):
        plots.track_figure(
            track.timestamp_s,
            track.position_m,
            track.orientation_deg[:, 0],
            track,
            (np.zeros(50), np.zeros(50)),
            {},
            n_packets=50,
        )
    plt.close("all")


def test_calibration_counts_errors_within_twice_the_stated_std() -> None:
    track = _track(n=4)
    assert track.position_std_m is not None
    track.position_std_m[:] = 1.0
    track.azimuth_std_deg[:] = 10.0
    run = MethodRun(
        "filter",
        track,
        RunSummary("filter", 4, 4),
        np.array([0.5, 1.9, 2.1, 5.0]),
        np.array([1.0, 25.0, 30.0, 2.0]),
        np.arange(4),
        4,
    )
    cal = calibration(run)
    assert cal is not None
    assert cal.position_within_2sd == 0.5 and cal.orientation_within_2sd == 0.5
    assert cal.median_position_std_m == 1.0 and cal.median_azimuth_std_deg == 10.0
    no_std = MethodRun(
        "full",
        _track(n=4, std=False),
        RunSummary("full", 4, 4),
        run.position_error_m,
        run.orientation_error_deg,
        run.truth_index,
        4,
    )
    assert calibration(no_std) is None


# ----------------------------------------------------------------------------- --pose 3d
def test_demo_3d_tracks_a_hand_held_walk(tmp_path: Path, capsys) -> None:
    """``radiopose demo --pose 3d`` on a 1 s walk: the three filter runs
    (offline, live, causal) answer every packet with a 3-D pose (height, pitch
    and roll move), the table has a row for each, the figures are drawn, and
    the offline track is closer to the truth than a fixed guess at the area's
    centre."""
    out = tmp_path / "d3"
    code, printed, err = _run(
        ["demo", "--pose", "3d", "-o", str(out), "--duration-s", "1", "--seed", "11"], capsys
    )
    assert code == 0, err
    rows = re.findall(r"^\| (offline|live|causal) \| ([\d.]+) % \| ([\d.]+) / ", printed, re.M)
    assert [r[0] for r in rows] == ["offline", "live", "causal"]
    assert all(float(r[1]) == 100.0 for r in rows)
    assert len((out / "errors.md").read_text().strip().splitlines()) == 5  # head, rule, rows
    for name in ("offline", "live", "causal"):
        assert (out / f"pose3d_{name}.png").stat().st_size > 50_000
        est = read_estimates_csv(out / f"estimates_{name}.csv")
        assert len(est) == 50
        assert np.ptp(est.position_m[:, 2]) > 0.01 and np.ptp(est.orientation_deg[:, 1]) > 1.0
    truth = np.loadtxt(out / "scenario" / "truth.csv", delimiter=",", skiprows=1,
                       usecols=(2, 3, 4))  # fmt: skip
    est = read_estimates_csv(out / "estimates_offline.csv")
    err_m = np.linalg.norm(est.position_m - truth, axis=1).mean()
    centre = np.linalg.norm(truth - np.array([10.0, 10.0, 1.2]), axis=1).mean()
    assert err_m < 0.25 * centre


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--pose", "4d"], "--pose must be 2d or 3d"),
        (["--pose", "3d", "--live", "--method", "full"], "--pose 3d --live runs the filter"),
        (["--pose", "3d", "--real"], "--pose does not apply to --real"),
        (["--pose", "3d", "--duration-s", "-1"], "--duration-s -1.0 is out of range (allowed"),
        (["--pose", "3d", "--noise-db", "-1"], "--noise-db -1.0 is out of range (allowed: [0"),
        (["--noise-db", "-1"], "--noise-db -1.0 is out of range (allowed: [0, 30])"),
    ],
)
def test_demo_3d_bad_options_are_one_line_errors(tmp_path: Path, capsys, extra, needle) -> None:
    code, _, err = _run(["demo", "-o", str(tmp_path / "d"), *extra], capsys)
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not (tmp_path / "d").exists()


def test_pose3d_figure_draws_roll_in_one_range_and_the_errors() -> None:
    """The roll panel draws truth and track in (−180, 180] (a truth stored as
    350° is drawn at −10°, not across the panel), and the error panel's
    legend carries both means."""
    n = 40
    t = np.linspace(0.0, 2.0, n)
    pos = np.column_stack([np.linspace(1, 3, n), np.full(n, 2.0), np.linspace(1.0, 1.4, n)])
    ori = np.column_stack([np.full(n, 90.0), np.full(n, 45.0), np.full(n, 350.0)])
    track = Estimates(
        t, np.array(["phone"] * n), np.array([str(i) for i in range(n)]), pos + 0.1,
        ori - np.array([0.0, 0.0, 355.0]), np.array(["filter"] * n),
        position_std_m=np.full(n, 0.2), azimuth_std_deg=np.full(n, 5.0),
    )  # fmt: skip
    fig = plots.pose3d_figure(
        t, pos, ori, track, (np.full(n, 0.17), np.full(n, 5.0)), n_packets=n,
        receivers_m=np.array([[0.0, 0.0, 2.5], [5.0, 5.0, 1.0]]),
    )  # fmt: skip
    axes = fig.get_axes()
    roll = next(a for a in axes if a.get_ylabel() == "roll (°)")
    truth_line, est_line = roll.get_lines()[:2]
    np.testing.assert_allclose(truth_line.get_ydata(), -10.0)
    np.testing.assert_allclose(est_line.get_ydata(), -5.0)
    height = next(a for a in axes if a.get_ylabel() == "height (m)")
    np.testing.assert_allclose(height.get_lines()[1].get_ydata(), pos[:, 2] + 0.1)
    labels = [x.get_text() for ax in axes if ax.get_legend() for x in ax.get_legend().get_texts()]
    assert "position, mean 0.17 m" in labels and "rotation, mean 5.0°" in labels
    plt.close(fig)


# ----------------------------------------------------------------------- --live, end to end
@pytest.mark.slow
@pytest.mark.parametrize("pose", ["2d", "3d"])
def test_live_demo_tracks_the_replayed_walk(tmp_path: Path, pose: str) -> None:
    """``radiopose demo --live [--pose 3d]`` for 30 s on a 4 s walk: the server
    (its default method at the site: ``filter`` at the 3-D one) stores estimates
    of the replayed packets; at the 3-D site with height, pitch and roll."""
    import socket

    from radiopose.server.db import Database
    from radiopose.server.demo import run_live_demo

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    said: list[str] = []
    tokens = run_live_demo(
        tmp_path, duration_s=4.0, interval_ms=100.0, port=port, echo=said.append,
        stop_after_s=30.0, pose=pose,
    )  # fmt: skip
    assert tokens["url"] == f"http://127.0.0.1:{port}/" and said[-1] == "stopped"
    db = Database(f"sqlite:///{tmp_path / 'live.db'}")
    est = db.estimates(limit=10**6)
    assert len(est) >= 30 and {e["method"] for e in est} == {"filter"}
    if pose == "3d":
        z = np.array([e["z_m"] for e in est])
        pitch = np.array([e["pitch_deg"] for e in est])
        assert np.ptp(z) > 0.01 and np.mean(pitch) > 10.0
