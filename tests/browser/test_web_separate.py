"""The Models page's Separate in a real browser: where the diagnosis finds two candidate effects
alike it offers the experiment that separates them; the button runs it, the diagnosis is run again
with its dataset, and the scores before and with it are shown; after a reload the page shows the
same result, read from the dataset that records what it was the experiment of (issue 39: it was
gone). Moved from test_web_dashboard.py. Set-up: tests/support/browser.py."""

from __future__ import annotations

import json

import pytest

from tests.support.api_client import wait_job
from tests.support.browser import goto, job_of, posted_result, serving, shot

pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_separate")]

#: the characterisation discovery asks for: both axes one after the other
BOTH_AXES = {"axes": ["y", "z"], "together": False, "waveform": "sine", "frequencies_hz": [1, 10, 50, 100], "cycles": 5}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """A service on the delay bench, where delay and rate dependence look alike on a 1–100 Hz sine
    sweep of both axes one after the other (on Y alone the diagnosis already tells them apart)."""
    with serving(tmp_path_factory, "delay") as s:
        yield s


def test_separate_two_look_alike_effects(page, server):
    job = server["api"].post("/sweeps", json=BOTH_AXES).json()
    dataset_id = wait_job(job_of(server), job["job_id"])["result"]["dataset_id"]
    goto(page, server, f"models?dataset={dataset_id}")
    page.select_option("#identify-datasets", [dataset_id])
    page.click("#identify-start")
    page.wait_for_selector("#separate-run", timeout=120_000)
    # "where it fails" is shaded on the blocks the diagnosis names, by index: with Y and Z swept one after
    # the other each frequency has two blocks, and a failure in Z's block is shaded there, not on Y's
    page.wait_for_selector("#failure-shading")
    model_id = page.inner_text("#model-id")
    named = [
        f["block_index"]
        for f in server["api"].get(f"/models/{model_id}/diagnosis", params={"dataset": dataset_id}).json()["failures"]
        if f.get("block_index") is not None
    ]
    blocks = {b["index"]: b for b in server["api"].get(f"/datasets/{dataset_id}").json()["blocks"]}
    spans = json.loads(page.get_attribute("#failure-shading", "data-time-spans-s"))
    assert named and spans == [[blocks[i]["start"] / 20000.0, blocks[i]["stop"] / 20000.0] for i in named], (
        named,
        spans,
    )
    button = page.locator("#separate-run")
    a, b = button.get_attribute("data-a"), button.get_attribute("data-b")
    assert {a, b} == {"delay", "rate_dependence"}
    assert button.inner_text() == f"Run the experiment that separates {a} from {b}"
    scores = {e: float(page.get_attribute(f"#candidates tr[data-effect={e}]", "data-score")) for e in (a, b)}
    assert abs(scores[a] - scores[b]) <= 0.1, scores
    shot(page, "separate_offered")
    button.click()
    page.wait_for_selector("#separate-job .jobline[data-state='succeeded']", timeout=120_000)
    job_id = page.get_attribute("#separate-job .jobline", "data-job-id")
    new_id = server["api"].get(f"/jobs/{job_id}").json()["result"]["dataset_id"]
    ds = server["api"].get(f"/datasets/{new_id}").json()
    assert ds["plan"]["waveform"] == "sine" and max(ds["plan"]["frequencies_hz"]) > 100
    page.wait_for_selector("#separation", timeout=180_000)
    sep = page.locator("#separation")
    assert sep.get_attribute("data-dataset-id") == new_id
    assert page.get_attribute("#diagnosis-verdict", "data-extra-datasets") == new_id
    assert sep.get_attribute("data-separated") == "true"
    leader = sep.get_attribute("data-leader")
    assert leader == "delay"  # the hidden effect
    assert page.get_attribute("#candidates tr.best", "data-effect") == leader
    held_out = {e: float(page.get_attribute(f"#separation-table tr[data-effect={e}]", "data-nm-after")) for e in (a, b)}
    assert held_out["rate_dependence"] > 1.5 * held_out["delay"], held_out
    assert page.locator("#separate-run").count() == 0  # no ambiguity left to separate
    # the answer on the first screen is the diagnosis with the experiment's data, not the one before it
    # (a walk read "Missing: asymmetry or sensor_nonlinearity … a guess" above a card that told them apart)
    answer = page.inner_text("#model-answer-text")
    # ... and it says its figure is on the experiment's data too, beside the stored model's own
    stored_nm = server["api"].get(f"/models/{model_id}").json()["metrics"]["validation_rms_um"] * 1e3
    assert new_id in page.inner_text("#model-answer-extra") and f"{stored_nm:.4g} nm" in page.inner_text(
        "#model-answer-extra"
    )
    assert f"or {b}" not in answer and f"or {a}" not in answer and "a guess" not in answer, answer
    assert page.get_attribute("#model-answer-text", "data-effect") == page.get_attribute(
        "#candidates tr.best", "data-effect"
    )
    shot(page, "separate_result")
    # the dataset keeps what it was the experiment of, and after a reload the page shows the same result
    assert ds["experiment_of"] == {"model_id": model_id, "effects": [a, b], "extra_datasets": []}
    shown = _separation_figures(page)
    assert set(shown["rows"]) == {a, b} and all(v != "" for row in shown["rows"].values() for v in row), shown
    page.reload()
    page.wait_for_selector("#page[data-ready='1']")
    page.wait_for_selector("#separation", timeout=180_000)
    assert _separation_figures(page) == shown
    assert page.get_attribute("#diagnosis-verdict", "data-extra-datasets") == new_id
    assert "a guess" not in page.inner_text("#model-answer-text")
    assert page.locator("#separate-run").count() == 0


def _separation_figures(page) -> dict:
    """The separating experiment's result as the page shows it: its dataset, leader, verdict and per
    effect the scores and held-out figures (data attributes and the cells' text)."""
    sep = page.locator("#separation")
    rows = page.locator("#separation-table tr[data-effect]")
    return {
        "dataset": sep.get_attribute("data-dataset-id"),
        "leader": sep.get_attribute("data-leader"),
        "separated": sep.get_attribute("data-separated"),
        "said": page.inner_text("#separation p"),
        "rows": {
            rows.nth(i).get_attribute("data-effect"): (
                rows.nth(i).get_attribute("data-before"),
                rows.nth(i).get_attribute("data-after"),
                rows.nth(i).get_attribute("data-nm-after"),
                rows.nth(i).inner_text(),
            )
            for i in range(rows.count())
        },
    }


def test_the_experiment_a_discover_run_needs_is_recorded_as_its_diagnosis_experiment(page, server):
    """Discover stops at the ambiguity and offers its sweep; the button's dataset records the model whose
    diagnosis proposed it and the effects it separates, so Identify does not preselect it."""
    dataset_id = posted_result(server, "/sweeps", BOTH_AXES)["dataset_id"]
    model_id = posted_result(server, "/models", {"axis": "y", "datasets": [dataset_id]})["model_id"]
    goto(page, server, f"models/{model_id}")
    page.fill("#discover-form input[name=max_steps]", "2")
    page.click("#discover-start")
    page.wait_for_selector("#discover-job .jobline[data-state='succeeded']", timeout=300_000)
    button = page.locator("#discover-experiments .run-experiment")
    assert button.count() == 1
    effects = page.get_attribute("#discover-experiments li", "data-effects").split(",")
    assert set(effects) == {"delay", "rate_dependence"}
    button.click()
    page.wait_for_selector("#discover-experiments .experiment-job .jobline[data-state='succeeded']", timeout=120_000)
    job_id = page.get_attribute("#discover-experiments .experiment-job .jobline", "data-job-id")
    made = server["api"].get(f"/jobs/{job_id}").json()["result"]["dataset_id"]
    recorded = server["api"].get(f"/datasets/{made}").json()
    assert recorded["experiment_of"] == {"model_id": model_id, "effects": effects, "extra_datasets": []}
    goto(page, server, "models")
    chosen = page.evaluate("[...document.querySelectorAll('#identify-datasets option:checked')].map(o => o.value)")
    assert chosen == [dataset_id] and made != dataset_id
