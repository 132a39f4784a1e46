"""The dashboard draws the filter's track: a trail of its estimates and, when an
estimate states them, a circle of radius ``position_std_m`` and a wedge of
± ``azimuth_std_deg``.

Debian's Chromium, headless, driven by Playwright (skipped with the reason when
either is missing, like ``test_server_dashboard.py``). The drawing is checked
twice: through what the page records it drew (``window.radiopose.drawn``), and
through the canvas pixels themselves.
"""

from __future__ import annotations

import math
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from radiopose.receiver import run_replay
from radiopose.server.app import import_site_dir
from radiopose.server.auth import create_token
from radiopose.server.db import Database
from server_support import RECEIVERS, Running, Tiny, fast_live, run_server, tiny  # noqa: F401

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-sync"]
SCREENSHOT = Path(__file__).resolve().parents[1] / "docs" / "img" / "dashboard-filter.png"
FIRST = "[...window.radiopose.tracks.values()][0]"


@pytest.fixture
def page(tmp_path: Path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="pip install playwright")
    if not Path(CHROMIUM).exists():
        pytest.skip("system Chromium not found (apt-get install chromium)")
    with sync_api.sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            str(tmp_path / "profile"),
            executable_path=CHROMIUM,
            headless=True,
            args=ARGS,
            viewport={"width": 1280, "height": 800},
        )
        try:
            yield ctx.new_page()
        finally:
            ctx.close()


@pytest.fixture
def filter_server(tiny: Tiny, tmp_path: Path) -> Iterator[Running]:  # noqa: F811
    """The live server on the tiny site, tracking with ``filter``."""
    _compile_filter_kernels()
    db = Database(f"sqlite:///{tmp_path / 'live.db'}")
    import_site_dir(db, tiny.site_dir)
    tokens = {"admin": create_token(db, "admin"), "viewer": create_token(db, "viewer")}
    for r in RECEIVERS:
        tokens[r] = create_token(db, "receiver", r)
    with run_server(db, fast_live(method="filter")) as running:
        running.tokens = tokens
        yield running
    db.close()


def _compile_filter_kernels() -> None:
    """Run the filter once in this process, with the live server's fixed lag, before
    the server starts, so that a cold numba cache (a fresh clone) is compiled here
    and not inside the test's wait for the trail (the server runs in a thread of
    this process)."""
    from radiopose.server.live import MAX_LIVE_LAG_S
    from radiopose.simulate import ScenarioConfig, simulate
    from radiopose.tracker import TrackerConfig, locate

    sim = simulate(ScenarioConfig(size_m=6.0, step_m=0.5, n_receivers=3, duration_s=0.2), seed=1)
    locate(sim.site, sim.packets, "filter", TrackerConfig(smoothing_lag_s=MAX_LIVE_LAG_S))


def _open(page, server: Running) -> None:
    page.goto(f"{server.url}/#token={server.tokens['viewer']}")
    page.wait_for_function("document.body.dataset.receivers === '3'", timeout=20_000)


def _pixel(page, x: float, y: float) -> list[int]:
    return page.evaluate(
        "([x, y]) => [...document.getElementById('floor').getContext('2d')"
        ".getImageData(Math.round(x), Math.round(y), 1, 1).data]",
        [x, y],
    )


def _to_canvas(page, x_m: float, y_m: float) -> tuple[float, float, float]:
    """Canvas pixel of a floor point and the scale (px per metre), as app.js's view()."""
    return tuple(
        page.evaluate(
            """([x, y]) => {
              const c = document.getElementById('floor'), a = window.radiopose.site.area;
              const pad = 30, w = a.x_max_m - a.x_min_m, h = a.y_max_m - a.y_min_m;
              const s = Math.min((c.width - 2 * pad) / w, (c.height - 2 * pad) / h);
              return [pad + (x - a.x_min_m) * s, c.height - pad - (y - a.y_min_m) * s, s]; }""",
            [x_m, y_m],
        )
    )


def test_dashboard_draws_a_stated_uncertainty(filter_server: Running, page) -> None:
    _open(page, filter_server)
    est = {
        "timestamp_s": 1.0,
        "transmitter": "phone",
        "packet_id": "1",
        "x_m": 3.0,
        "y_m": 3.0,
        "z_m": 1.0,
        "azimuth_deg": 90.0,  # the top points to world -x (left on the canvas)
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
        "method": "filter",
        "position_std_m": 1.0,
        "azimuth_std_deg": 20.0,
    }
    page.evaluate("(e) => { window.radiopose.addEstimates([e]); window.radiopose.draw(); }", est)
    drawn = page.evaluate("window.radiopose.drawn['phone']")
    cx, cy, s = _to_canvas(page, 3.0, 3.0)
    assert drawn["method"] == "filter"
    assert drawn["circle_px"] == pytest.approx(1.0 * s)
    assert drawn["wedge_deg"] == [70.0, 110.0]
    assert page.evaluate("document.body.dataset.uncertainty") == "1"
    # (the canvas is transparent where nothing is drawn; the page behind it is white)
    # inside the circle, off the wedge, arrow and label: the circle's translucent fill
    inside = _pixel(page, cx, cy + 0.6 * s)
    assert 0 < inside[3] < 255 and inside[2] > inside[0]  # blue-ish, see-through
    # outside the circle: nothing drawn (a grid line aside)
    outside = _pixel(page, cx + 0.5 * s, cy + 1.4 * s)
    assert outside[3] == 0 or outside[:3] == [238, 238, 238]

    # in the wedge (to the left, 15° off its axis, beyond the arrow's 36 px) but not
    # beyond it (35° off the axis, same distance)
    def polar(deg: float, r: float) -> tuple[float, float]:
        return cx + r * math.cos(math.radians(deg)), cy - r * math.sin(math.radians(deg))

    inside_wedge = _pixel(page, *polar(180.0 - 15.0, 50.0))
    beyond_wedge = _pixel(page, *polar(180.0 - 35.0, 50.0))
    assert beyond_wedge[3] > 0  # within the circle
    assert inside_wedge[3] > beyond_wedge[3] + 30  # the wedge's fill on top of the circle's

    # an estimate without the optional fields: no circle, no wedge
    plain = {**est, "packet_id": "2"}
    del plain["position_std_m"], plain["azimuth_std_deg"]
    page.evaluate("(e) => { window.radiopose.addEstimates([e]); window.radiopose.draw(); }", plain)
    drawn = page.evaluate("window.radiopose.drawn['phone']")
    assert drawn["circle_px"] is None and drawn["wedge_deg"] is None
    assert page.evaluate("document.body.dataset.uncertainty") == "0"


def test_dashboard_draws_the_filter_track_live(
    filter_server: Running,
    tiny: Tiny,  # noqa: F811
    page,
    tmp_path: Path,
) -> None:
    from test_server_live import _agent

    _open(page, filter_server)
    agents = [
        _agent(filter_server.url, filter_server.tokens[r], r, tmp_path / "spool") for r in RECEIVERS
    ]
    for a in agents:
        a.refresh_transmitters()
    threads = [
        threading.Thread(
            target=run_replay, args=(a, tiny.frames[a.config.receiver_id]), kwargs={"speed": 2.0}
        )
        for a in agents
    ]
    for t in threads:
        t.start()
    try:
        # the filter answers every packet: a trail of many estimates builds up
        page.wait_for_function(
            f"(() => {{ const t = {FIRST}; return t !== undefined && t.trail.length >= 20; }})()",
            timeout=90_000,
        )
        trail = page.evaluate(f"{FIRST}.trail")
        assert {e["method"] for e in trail} == {"filter"}
        assert len({(e["x_m"], e["y_m"]) for e in trail}) > 5  # a track, not one point
        drawn = page.evaluate("Object.values(window.radiopose.drawn)[0]")
        assert drawn["method"] == "filter"
        last = trail[-1]
        if "position_std_m" in last:  # the server's estimates state their uncertainty
            _, _, s = _to_canvas(page, 0.0, 0.0)
            assert drawn["circle_px"] == pytest.approx(max(last["position_std_m"] * s, 1.0))
        if os.environ.get("RADIOPOSE_SCREENSHOT"):  # regenerate docs/img/dashboard-filter.png
            for t in threads:
                t.join(60)
            page.wait_for_timeout(2500)
            page.screenshot(path=str(SCREENSHOT))
    finally:
        for t in threads:
            t.join(60)
        for a in agents:
            a.drain(30)
            a.close()
