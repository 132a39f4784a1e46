"""The dashboard in a real browser: Debian's Chromium, headless, driven by Playwright.

The page loads with a viewer token, draws the receivers, and the transmitter
arrow moves as reports arrive. Skipped (with the reason) when Playwright or
the system Chromium is missing; ``.ci/run`` installs both.
"""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

import pytest

from radiopose.receiver import run_replay
from server_support import (  # fixtures and helpers
    RECEIVERS,
    Running,
    db_url,
    pg_server,
    server,
    tiny,
)

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENSHOT = Path(__file__).resolve().parents[1] / "docs" / "img" / "dashboard.png"


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


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_dashboard_shows_receivers_and_a_moving_arrow(
    server: Running, tiny, page, tmp_path: Path
) -> None:
    from test_server_live import _agent

    page.goto(f"{server.url}/#token={server.tokens['viewer']}")
    page.wait_for_function("document.body.dataset.receivers === '3'", timeout=20_000)
    assert page.locator("#rx-table tbody tr").count() in (0, 3)  # health arrives with the stream
    assert page.evaluate("window.radiopose.site.receivers.map(r => r.receiver_id)") == list(
        RECEIVERS
    )
    assert page.evaluate("location.hash") == ""  # the token is not left in the address bar

    agents = [_agent(server.url, server.tokens[r], r, tmp_path / "spool") for r in RECEIVERS]
    threads = [
        threading.Thread(
            target=run_replay, args=(a, tiny.frames[a.config.receiver_id]), kwargs={"speed": 2.0}
        )
        for a in agents
    ]
    for a in agents:
        a.refresh_transmitters()
    for t in threads:
        t.start()
    try:
        page.wait_for_function("Number(document.body.dataset.moves || 0) >= 1", timeout=30_000)
        first = page.evaluate("[...window.radiopose.tracks.values()][0].trail.slice(-1)[0]")
        # The arrow moves: a later estimate with another pose arrives. (Two
        # consecutive packets can share a pose on this coarse grid, so wait for
        # a different pose, not merely a different packet.)
        page.wait_for_function(
            f"(() => {{ const t = [...window.radiopose.tracks.values()][0].trail.slice(-1)[0];"
            f" return t.packet_id !== '{first['packet_id']}' && (t.x_m !== {first['x_m']!r}"
            f" || t.y_m !== {first['y_m']!r} || t.azimuth_deg !== {first['azimuth_deg']!r});"
            " })()",
            timeout=30_000,
        )
        last = page.evaluate("[...window.radiopose.tracks.values()][0].trail.slice(-1)[0]")
        assert (last["x_m"], last["y_m"], last["azimuth_deg"]) != (
            first["x_m"],
            first["y_m"],
            first["azimuth_deg"],
        )
        page.wait_for_function(
            "document.querySelectorAll('#rx-table tbody tr').length === 3", timeout=20_000
        )
        assert "live" in page.locator("#status").inner_text()
        if os.environ.get("RADIOPOSE_SCREENSHOT"):  # regenerate docs/img/dashboard.png
            for t in threads:
                t.join(30)
            page.wait_for_timeout(2500)
            page.screenshot(path=str(SCREENSHOT))
    finally:
        for t in threads:
            t.join(30)
        for a in agents:
            a.drain(30)
            a.close()


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
def test_dashboard_asks_for_a_token(server: Running, page) -> None:
    page.goto(server.url + "/")
    page.wait_for_selector("#login:not([hidden])", timeout=20_000)
    page.fill("#token-input", "rp_wrong")
    page.click("button[type=submit]")
    page.wait_for_function(
        "document.getElementById('login-error').textContent.includes('unknown token')",
        timeout=20_000,
    )
    page.fill("#token-input", server.tokens["viewer"])
    page.click("button[type=submit]")
    page.wait_for_function("document.body.dataset.receivers === '3'", timeout=20_000)
