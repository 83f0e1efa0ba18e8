"""Issue 20 §3 in a real browser: the Models page's "Report (HTML)" saves the model's report, and the
saved file, opened in Debian's chromium, shows its figures (SVG with polylines, visible). The
screenshot is tests/artifacts/model_report.png. Set-up: tests/support/browser.py."""

from __future__ import annotations

import pytest

from tests.support.browser import ARTIFACTS, goto, posted_result, serving, swept_static_pi

pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_report")]

FREQUENCIES_HZ = [1, 10, 50, 100]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """A live service on the creep bench with a swept Y axis, a static PI and its +creep refinement."""
    with serving(tmp_path_factory, "creep") as s:
        _, base = swept_static_pi(s, {"axes": ["y"], "frequencies_hz": FREQUENCIES_HZ, "cycles": 5})
        s["model"] = posted_result(s, f"/models/{base}/refine", {"add": "creep"})["model_id"]
        yield s


def test_the_models_page_saves_the_report_and_its_figures_show(page, server, tmp_path):
    model = server["model"]
    goto(page, server, f"models/{model}")
    page.wait_for_selector("#report-download")
    with page.expect_download(timeout=240_000) as info:
        page.click("#report-download")
    download = info.value
    assert download.suggested_filename == f"{model}-report.html"
    saved = tmp_path / download.suggested_filename
    download.save_as(saved)
    page.wait_for_selector("#report-status:has-text('saved')")

    page.goto(saved.as_uri())  # the file alone: no server, no script
    figures = page.locator("svg.figure")
    assert figures.count() == len(FREQUENCIES_HZ) + 1  # one per block and the error history
    for i in range(figures.count()):
        fig = figures.nth(i)
        fig.scroll_into_view_if_needed()
        assert fig.is_visible()
        box = fig.bounding_box()
        assert box and box["width"] > 300 and box["height"] > 200
        lines = fig.locator("polyline")
        assert lines.count() >= 1
        drawn = lines.first.bounding_box()
        assert drawn and drawn["width"] > 20, f"figure {i}: its curve spans no width"
    assert page.inner_text("#verdict") in ("complete", "missing_effect")
    assert "$(post /sweeps '" in page.inner_text("#reproduce-curl")  # the sweep is re-run first
    path = ARTIFACTS / "model_report.png"
    page.evaluate("window.scrollTo(0, 0)")
    page.screenshot(path=str(path), full_page=True)
    assert path.stat().st_size > 10_000
