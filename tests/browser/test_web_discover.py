"""Issue 20 §2 in a real browser: the Models page's Discover button runs the discovery job and shows
it building up step by step (the steps, the effects found, what remains); the report's own figures
are inlined (the error history, the per-block loop and residual, the block with the largest
held-out RMS marked); and two models of the lineage are compared block by block. On the creep bench with
a short sweep (10 and 100 Hz, 5 cycles, as tests/api/test_discover_job.py), so each fit takes seconds.
Screenshots: tests/artifacts/web_discover_run.png, web_discover_blocks.png, web_discover_compare.png.
Set-up: tests/support/browser.py."""

from __future__ import annotations

import re

import pytest

from tests.support.browser import ARTIFACTS, goto, serving, swept_static_pi

pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_discover")]

QUICK_SWEEP = {"axes": ["y", "z"], "frequencies_hz": [10, 100], "cycles": 5, "together": False}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """A live service on the creep bench with a short two-axis sweep and a static PI of Y on it."""
    with serving(tmp_path_factory, "creep") as s:
        s["dataset"], s["base"] = swept_static_pi(s, QUICK_SWEEP)
        yield s


def _printed_um(text: str) -> float:
    """A length as the page prints it ('6.1 nm', '1.23 µm') in µm."""
    value, unit = text.split()
    return float(value) * {"nm": 1e-3, "µm": 1.0}[unit]


def _card_shot(page, selector: str, name: str) -> None:
    """A screenshot of one card, cut from the full page (the sticky top bar stays at the top)."""
    path = ARTIFACTS / f"web_{name}.png"
    page.evaluate("window.scrollTo(0, 0)")
    page.screenshot(path=str(path), full_page=True, clip=page.locator(selector).bounding_box())
    assert path.stat().st_size > 10_000


def test_discover_run_its_figures_and_a_comparison_on_the_page(page, server):
    api, base = server["api"], server["base"]
    goto(page, server, f"models/{base}")
    # the diagnosis names the blocks where the model fails by what they are
    page.wait_for_selector("#failures li", timeout=120_000)
    named = page.locator("#failures li[data-block]")
    assert named.count() >= 1 and re.match(
        r"Y \d+ Hz sine \(held-out cycle 5\): held-out residual RMS [\d.]+ nm", named.first.inner_text()
    ), page.inner_text("#failures")

    # 1. Discover: the run builds up step by step, as the job's result has it
    page.fill("#discover-form input[name=max_steps]", "4")
    page.click("#discover-start")
    page.wait_for_selector("#discover-steps tr[data-step='1']", timeout=300_000)  # shown while it runs on
    page.wait_for_selector("#discover-job .jobline[data-state='succeeded']", timeout=300_000)
    page.wait_for_selector("#discover-stopped")
    job = api.get(f"/jobs/{page.get_attribute('#discover-job .jobline', 'data-job-id')}").json()
    assert job["kind"] == "discover" and job["params"]["model_id"] == base and job["params"]["max_steps"] == 4
    steps = job["result"]["steps"]
    rows = page.locator("#discover-steps tr[data-step]")
    assert rows.count() == len(steps) >= 2
    assert len(steps) >= 3  # a middle step is there: section 4 opens its page (the run found through its job_id)
    for i, step in enumerate(steps):
        row = rows.nth(i)
        assert row.get_attribute("data-model-id") == step["model_id"]
        assert row.get_attribute("data-added") == (step["added"] or "")
        printed = row.locator("td.num").first.inner_text()
        assert printed.endswith(" nm"), printed  # nm below 1 µm
        assert _printed_um(printed) == pytest.approx(step["validation_rms_um"], rel=5e-3)
    assert steps[1]["added"] == "creep" and "+creep" in rows.nth(1).inner_text()
    found = page.locator("#discover-found tr[data-effect='creep']")
    assert found.count() == 1 and "creep_pct_per_decade" in found.inner_text()
    remains = job["result"]["remains"]
    assert float(page.get_attribute("#discover-remains", "data-ratio")) == pytest.approx(
        remains["ratio_to_noise_floor"], rel=1e-9
    )
    assert page.get_attribute("#discover-stopped", "data-stopped") == job["result"]["stopped"]
    # the page names its checkboxes by their labels, the API parameter kept in brackets (issue 39)
    labels = {
        "allow_experiments": "run the experiments it needs on the bench",
        "continue_past_ambiguity": "at an ambiguity, add the leading effect and go on",
    }
    for name, label in labels.items():
        assert page.locator(f"#discover-form label:has(input[name={name}])").inner_text().strip() == label
        text = page.inner_text("#discover-card")
        assert text.count(name) == text.count(f"“{label}” ticked ({name})"), text
    said = page.evaluate(
        "async () => (await import('./js/pages/discover.js')).pageWords("
        "'stops here: ask again with allow_experiments to run it, or with continue_past_ambiguity to add creep')"
    )
    assert said == (
        "stops here: ask again with “run the experiments it needs on the bench” ticked "
        '<span class="muted">(allow_experiments)</span> to run it, or with “at an ambiguity, add the leading '
        'effect and go on” ticked <span class="muted">(continue_past_ambiguity)</span> to add creep'
    )
    _card_shot(page, "#discover-card", "discover_run")

    # 2. The report's figures of the final model: the history labelled per step, a figure per block
    final = job["result"]["final_model_id"]
    page.wait_for_selector(f"#figures-history[data-model-id='{final}'] svg polyline", timeout=240_000)
    history = page.locator("#figures-history svg").text_content()
    assert "+creep" in history and "2× noise floor" in history
    assert "log scale" in history
    blocks = page.locator("#figures-blocks .block-figure")
    figures = api.get(f"/models/{final}/report/figures").json()
    assert blocks.count() == len(figures["blocks"]) == 2  # Y 10 Hz and Y 100 Hz
    titles = [blocks.nth(i).locator("h3").inner_text() for i in range(blocks.count())]
    assert [re.search(r"Y \d+ Hz sine", t)[0] for t in titles] == ["Y 10 Hz sine", "Y 100 Hz sine"]
    for i in range(blocks.count()):
        svg = blocks.nth(i).locator("svg")
        svg.scroll_into_view_if_needed()
        assert svg.is_visible()
        box = svg.bounding_box()
        assert box and box["width"] > 400 and box["height"] > 100
        line = svg.locator("polyline").first
        assert line.is_visible() and line.bounding_box()["width"] > 20
    worst = page.locator("#figures-blocks .block-figure.worst")
    assert worst.count() == 1 and "worst block" in worst.locator("h3").inner_text()
    assert worst.get_attribute("data-block-index") == str(figures["blocks"][figures["worst_block"]]["block_index"])
    assert page.locator("#figures-card script").count() == 0
    _card_shot(page, "#figures-card", "discover_blocks")

    # 3. Two models of the lineage, block by block: the first fit against the one with creep
    page.select_option("#compare-a", steps[0]["model_id"])
    page.select_option("#compare-b", steps[1]["model_id"])
    page.click("#compare-run")
    page.wait_for_selector("#compare-blocks tr[data-block-index]")
    table = page.locator("#compare-blocks tr[data-block-index]")
    assert table.count() == 2
    for which, model_id in (("data-a", steps[0]["model_id"]), ("data-b", steps[1]["model_id"])):
        expected = api.get(
            f"/models/{model_id}/compare", params={"dataset": server["dataset"], "arrays": "false"}
        ).json()["metrics"]["per_block"]
        shown = [float(table.nth(i).get_attribute(which)) for i in range(table.count())]
        assert shown == pytest.approx([b["validation"]["rms_um"] for b in expected], rel=1e-9)
    assert all(
        float(table.nth(i).get_attribute("data-b")) < float(table.nth(i).get_attribute("data-a"))
        for i in range(table.count())
    ), "creep lowers every block's held-out RMS on the creep bench"
    assert "Y 10 Hz sine" in table.nth(0).inner_text()
    effects_b = page.locator(f"#compare-effects tr[data-model-id='{steps[1]['model_id']}']").inner_text()
    assert "creep" in effects_b
    _card_shot(page, "#lineage-compare", "discover_compare")

    # 4. The run outlives the page: back on the starting model after a reload, on a middle step's model
    # (the run that stored it) and on its final model, the last run is shown again with every step as the job has it
    for model_id in dict.fromkeys([base] + [s["model_id"] for s in steps] + [job["result"]["final_model_id"]]):
        goto(page, server, f"models/{model_id}")
        page.wait_for_selector("#discover-restored", timeout=60_000)
        assert page.get_attribute("#discover-restored", "data-job-id") == job["id"]
        again = page.locator("#discover-steps tr[data-step]")
        assert again.count() == len(steps)
        assert [again.nth(i).get_attribute("data-model-id") for i in range(again.count())] == [
            s["model_id"] for s in steps
        ]
        # steps numbered from 0 on the run, its lineage and the history alike; after a reload the Compare
        # selects still hold the run's later steps (they held the lineage up to this model alone)
        assert again.first.get_attribute("data-step") == "0" and again.first.locator("td").first.inner_text() == "0"
        page.wait_for_function(
            "n => document.querySelectorAll('#compare-b option').length >= n", arg=len(steps), timeout=60_000
        )
        options = page.locator("#compare-b option")
        values = [options.nth(i).get_attribute("value") for i in range(options.count())]
        assert values[-len(steps) :] == [s["model_id"] for s in steps] and page.input_value("#compare-b") == final
        lineage = api.get(f"/models/{final}/history").json()["steps"]
        assert [s["step"] for s in lineage] == list(range(len(lineage)))
        assert options.nth(0).inner_text().startswith("step 0: ")
        page.wait_for_selector("#history tr td")
        assert page.locator("#history tr").nth(1).locator("td").first.inner_text() == "0"


def test_a_run_is_cancelled_from_the_page_and_keeps_its_steps(page, server):
    """The Discover card has a Cancel button while a run is at work (a walk found no way to stop one
    from the page): the job ends cancelled, the steps done are kept and shown, the button goes away."""
    api, base = server["api"], server["base"]
    goto(page, server, f"models/{base}")
    page.wait_for_selector("#discover-start:not([disabled])", timeout=120_000)
    page.fill("#discover-form input[name=max_steps]", "6")
    page.click("#discover-start")
    page.click("#discover-cancel", timeout=60_000)  # offered as soon as the job is queued or running
    page.wait_for_selector("#discover-job .jobline[data-state='cancelled']", timeout=300_000)
    job = api.get(f"/jobs/{page.get_attribute('#discover-job .jobline', 'data-job-id')}").json()
    assert job["state"] == "cancelled" and job["result"]["stopped"] == "cancelled", job["state"]
    # a cancel stops the fit at work (none kept when it lands in step 0's diagnosis)
    assert page.locator("#discover-steps tr[data-step]").count() == len(job["result"]["steps"])
    assert page.locator("#discover-cancel").is_hidden()
