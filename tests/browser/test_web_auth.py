"""The dashboard and API tokens in a real browser (Debian's chromium via Playwright, as in
test_web_dashboard.py): without a token the page asks for one, a pasted token is kept in
localStorage and used, and a link's #…?token= is stored and removed from the address. (The
API's ?token= on the event stream is tested in test_service_auth.py.)"""

from __future__ import annotations

import pytest

from tests.support.browser import ARTIFACTS, launch_chromium, sync_api
from tests.support.live_server import Server

#: A live service, a module fixture: one worker runs the file.
pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_auth")]


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("webauth")
    server = Server(tmp / "var", tmp / "server.log", seed=1)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def page():
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        try:
            pg = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
            pg.set_default_timeout(60_000)
            yield pg
        finally:
            browser.close()


def test_the_dashboard_asks_for_a_token_and_keeps_it(live, page):
    page.goto(f"{live.url}/web/#/datasets")
    page.wait_for_selector("#page[data-ready='1']")
    page.wait_for_selector("#settings[open] #token")
    text = page.inner_text("#banner")
    assert text.startswith("missing API token") and "Paste an API token under Settings" in text
    assert page.evaluate("document.activeElement.id") == "token"
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "web_token_prompt.png"))

    page.fill("#token", live.token)
    page.click("#token-save")
    page.wait_for_selector("#banner.info")
    assert page.inner_text("#banner") == "API token saved in this browser."
    # saved, the settings popover closes: it no longer covers the page
    assert page.get_attribute("#settings", "open") is None and not page.is_visible("#token")
    assert page.evaluate("localStorage.getItem('evcbench.token')") == live.token
    page.reload()
    page.wait_for_selector("#page[data-ready='1']")
    page.wait_for_function("document.getElementById('bench-pill').textContent.startsWith('bench idle')")


def test_a_link_token_is_stored_and_dropped_from_the_address(live, page):
    page.goto(live.dashboard_url("bench"))
    page.wait_for_selector("#page[data-ready='1']")
    assert page.url.endswith("/web/#/bench") and "token" not in page.url
    assert page.evaluate("localStorage.getItem('evcbench.token')") == live.token
