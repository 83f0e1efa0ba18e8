"""The browser tests' shared pieces: Debian's chromium driven by Playwright (its own browser
download is never used), a live service per module, and helpers that read the dashboard. The
fixtures built on them (``browser``, ``page``) are in tests/browser/conftest.py.

Set-up: ``make test`` installs chromium (tests/setup/install_browser.sh), Playwright (the dev extra)
and the charting library (npm ci in web/).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import httpx
from playwright import sync_api

from tests.support.api_client import wait_job
from tests.support.live_server import Server

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "tests" / "artifacts"
CHROMIUM = Path(os.environ.get("EVCBENCH_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
UPLOT = ROOT / "web" / "node_modules" / "uplot" / "dist" / "uPlot.esm.js"


@contextlib.contextmanager
def serving(tmp_path_factory, bench: str, timeout_s: float = 120):
    """A live service on ``bench`` with an authenticated API client: {"url", "api", "live"}."""
    tmp = tmp_path_factory.mktemp(f"web_{bench}")
    live = Server(tmp / "var", tmp / "server.log", bench=bench, seed=1)
    try:
        with httpx.Client(base_url=f"{live.url}/api", timeout=timeout_s, headers=live.headers) as api:
            yield {"url": live.url, "api": api, "live": live}
    finally:
        live.stop()


def launch_chromium(playwright: sync_api.Playwright) -> sync_api.Browser:
    """Debian's headless chromium under Playwright."""
    return playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)


def goto(page, server, route: str) -> None:
    page.goto(server["live"].dashboard_url(route))
    page.wait_for_selector("#page[data-ready='1']")
    assert not page.is_visible("#banner.error"), page.inner_text("#banner")


def shot(page, name: str) -> Path:
    path = ARTIFACTS / f"web_{name}.png"
    page.evaluate("window.scrollTo(0, 0)")  # the sticky top bar stays at the top of a full-page shot
    page.screenshot(path=str(path), full_page=True)
    assert path.stat().st_size > 10_000
    return path


def job_of(server):
    """``job_id -> job`` through the server's API client (rooted at /api), for wait_job."""
    return lambda job_id: server["api"].get(f"/jobs/{job_id}").json()


def posted_result(server, path: str, body: dict) -> dict:
    """POST a job over the server's API client, wait for it (it must succeed): its result."""
    job = wait_job(job_of(server), server["api"].post(path, json=body).json()["job_id"], timeout_s=300)
    assert job["state"] == "succeeded", job
    return job["result"]


def swept_static_pi(server, sweep: dict) -> tuple[str, str]:
    """A sweep over REST and a static PI of Y on it: (dataset id, model id)."""
    dataset = posted_result(server, "/sweeps", sweep)["dataset_id"]
    return dataset, posted_result(server, "/models", {"axis": "y", "datasets": [dataset]})["model_id"]
