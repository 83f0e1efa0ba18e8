"""Fixtures of the browser tests (tests/support/browser.py has the helpers): one chromium per
module, and a page per test that fails the test on any console error. EVCBENCH_SKIP_BROWSER=1 leaves
the folder out; otherwise a missing browser, Playwright or chart library fails, it does not skip."""

from __future__ import annotations

import os

import pytest

if os.environ.get("EVCBENCH_SKIP_BROWSER") == "1":
    collect_ignore_glob = ["test_*.py"]
else:
    from playwright import sync_api

    from tests.support.browser import ARTIFACTS, CHROMIUM, UPLOT, launch_chromium

    @pytest.fixture(scope="module", autouse=True)
    def _browser_setup_is_complete():
        assert CHROMIUM.exists(), f"{CHROMIUM} is missing: run tests/setup/install_browser.sh (make test does)"
        assert UPLOT.exists(), "web/node_modules is missing: run `npm ci` in web/ (make test does)"

    @pytest.fixture(scope="module")
    def browser():
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        with sync_api.sync_playwright() as p:
            b = launch_chromium(p)
            try:
                yield b
            finally:
                b.close()

    @pytest.fixture
    def page(browser, server):
        """A 1280×800 page on the dashboard that records console errors; the test fails on any."""
        context = browser.new_context(viewport={"width": 1280, "height": 800}, accept_downloads=True)
        pg = context.new_page()
        pg.set_default_timeout(60_000)
        errors: list[str] = []
        pg.on("console", lambda m: errors.append(f"console.{m.type}: {m.text}") if m.type == "error" else None)
        pg.on("pageerror", lambda e: errors.append(f"uncaught: {e}"))
        pg.console_errors = errors
        yield pg
        context.close()
        assert errors == [], f"console errors on the dashboard: {errors}"
