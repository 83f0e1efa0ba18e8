"""The dashboard when the bench engine dies (issue 42), in a real browser: the engine of a live
service is SIGKILLed; the strip turns red with the reason while no engine is attached, then amber
with the latched fault; the Bench page marks its State table stale and disables the reset while no
engine is attached, then offers the reset, and after it the strip clears."""

from __future__ import annotations

import os
import signal
import time

import httpx
import pytest

from tests.support.browser import ARTIFACTS, launch_chromium, sync_api
from tests.support.live_server import Server

#: A live service, a module fixture: one worker runs the file.
pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_engine_death")]

STRIP = "#engine-state"


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("webengine")
    server = Server(tmp / "var", tmp / "server.log", bench="default", seed=1)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def page():
    """A page that records console errors other than the 503s a degraded service answers."""
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        try:
            pg = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
            pg.set_default_timeout(60_000)
            errors: list[str] = []
            pg.on("console", lambda m: errors.append(m.text) if m.type == "error" and " 503 " not in m.text else None)
            pg.on("pageerror", lambda e: errors.append(f"uncaught: {e}"))
            yield pg
            assert errors == [], f"console errors on the dashboard: {errors}"
        finally:
            browser.close()


def _strip(page) -> tuple[str, str, bool]:
    return page.evaluate(
        "(() => { const s = document.querySelector('#engine-state');"
        " return [s.dataset.state, s.textContent, s.hidden]; })()"
    )


def _strip_and_state(page) -> tuple[str, str, bool, dict]:
    """The strip and, read in the same task, the Bench page's State table: its stale note (None while
    hidden), whether the table is marked stale, and whether the reset button is disabled."""
    return page.evaluate(
        "(() => { const s = document.querySelector('#engine-state');"
        " const n = document.querySelector('#state-stale');"
        " return [s.dataset.state, s.textContent, s.hidden, {note: n.hidden ? null : n.textContent,"
        " stale: 'stale' in document.querySelector('#state').dataset,"
        " reset_disabled: document.querySelector('#reset-faults').disabled}]; })()"
    )


def test_a_killed_engine_shows_degraded_then_the_latched_fault_until_the_reset(live, page):
    page.goto(live.dashboard_url("bench"))
    page.wait_for_selector("#page[data-ready='1']")
    assert _strip(page)[2] is True  # an engine attached, nothing latched: no strip
    with httpx.Client(base_url=live.url, headers=live.headers, timeout=30) as http:
        pid = http.get("/api/bench").json()["engine"]["pid"]
        os.kill(pid, signal.SIGKILL)
        # the dashboard reads the health every 2 s; a restart may take less: the test asks the page
        # to read it again each 50 ms, as a job's event does ('evc:job'), until it shows the red strip
        killed_at = time.gmtime()
        seen, table, deadline = None, None, time.monotonic() + 30
        while seen is None and time.monotonic() < deadline:
            page.evaluate("window.dispatchEvent(new Event('evc:job'))")
            state, text, hidden, table = _strip_and_state(page)
            if state == "degraded" and not hidden:
                seen = text
            elif state == "latched":
                break  # back already: the red strip was missed; the assertion below says so
            page.wait_for_timeout(50)
        assert seen is not None, "the dashboard never showed the engine as absent"
        assert "SIGKILL" in seen and "Outputs are driven to 0 V" in seen, seen
        # the State table's values are the last read before the kill: marked stale, the reset refused
        assert table["stale"] and table["reset_disabled"], table
        read_at = table["note"].split("last values read at ")[1][:8]
        assert table["note"].startswith("Engine absent: ") and " UTC, not current (" in table["note"], table
        # read by the page's 1 s poll before the kill (5 s on a loaded machine), not at the 503
        assert -5 <= _seconds(read_at) - _seconds(time.strftime("%H:%M:%S", killed_at)) <= 1, (read_at, table)
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "web_engine_degraded.png"))

        page.wait_for_selector(f"{STRIP}[data-state='latched']", timeout=60_000)
        state, text, hidden = _strip(page)
        assert not hidden and text.startswith("Latched fault: engine restarted: ") and "SIGKILL" in text, text
        assert "outputs set to 0 V at" in text
        assert http.get("/api/bench").json()["engine"]["pid"] != pid
        page.wait_for_selector("#fault-actions:not([hidden]) #reset-faults:enabled")  # the Bench page's poll (1 s)
        assert page.is_hidden("#state-stale") and page.get_attribute("#state", "data-stale") is None
        page.screenshot(path=str(ARTIFACTS / "web_engine_latched.png"))
        page.click("#reset-faults")
        page.wait_for_function("document.getElementById('reset-result').textContent.startsWith('Cleared: ')")
        assert "engine restarted" in page.inner_text("#reset-result")
        page.wait_for_function(  # the next health read (every 2 s)
            "(() => { const s = document.querySelector('#engine-state'); return s.dataset.state === '' && s.hidden; })()",
            timeout=10_000,
        )
        assert http.get("/api/health").json()["latched_fault"] is None
        assert page.is_hidden("#fault-actions")


def _seconds(hms: str) -> int:
    """Seconds since midnight of "HH:MM:SS"."""
    h, m, sec = (int(x) for x in hms.split(":"))
    return 3600 * h + 60 * m + sec
