"""Issue 21 §2 in a real browser: the Lab page of a lab of three services on one PostgreSQL database
(the default bench and the creep and dynamics variants, tests/support/lab_services.py). Each sweeps Y at
10 and 100 Hz (4 cycles) and fits a model: the default bench a static PI, the creep bench static
PI + creep, the dynamics bench static PI + dynamics. The dynamics service is then stopped. The page,
opened on the default bench's service, shows all three benches, the stopped one OFFLINE with its
dataset still counted, each bench's newest Y model; and the Y comparison shows every model's
held-out RMS and the fitted creep (about the bench's 3 %/decade) and resonance (about its 482.6 Hz)
as the API gives them; the Datasets page lists each bench's dataset with its bench. Screenshot: tests/artifacts/web_lab.png. Set-up: tests/support/browser.py."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from tests.support.api_client import wait_job
from tests.support.browser import shot
from tests.support.lab_services import LAB_BENCHES, fresh_database, lab_services

pytestmark = [pytest.mark.browser, pytest.mark.postgres, pytest.mark.slow]

SWEEP = {"axes": ["y"], "frequencies_hz": [10, 100], "cycles": 4}
EFFECTS = {"default": ["hysteresis"], "creep": ["hysteresis", "creep"], "dynamics": ["hysteresis", "dynamics"]}


def _posted(client: httpx.Client, path: str, body: dict) -> dict:
    job = wait_job(
        lambda i: client.get(f"/jobs/{i}").json(), client.post(path, json=body).json()["job_id"], timeout_s=300
    )
    assert job["state"] == "succeeded", job
    return job["result"]


@pytest.fixture(scope="module")
def lab(tmp_path_factory, postgres_url):
    """The three services, each with a sweep and a model of Y; the dynamics service stopped."""
    root = tmp_path_factory.mktemp("web_lab")
    with lab_services(root, fresh_database(postgres_url)) as services:
        clients = {
            b: httpx.Client(base_url=f"{s.url}/api", headers=s.headers, timeout=120) for b, s in services.items()
        }

        def sweep_and_fit(bench: str) -> str:
            dataset = _posted(clients[bench], "/sweeps", SWEEP)["dataset_id"]
            return _posted(clients[bench], "/models", {"axis": "y", "datasets": [dataset], "effects": EFFECTS[bench]})[
                "model_id"
            ]

        with ThreadPoolExecutor(len(services)) as pool:
            models = dict(zip(services, pool.map(sweep_and_fit, services)))
        assert services["dynamics"].stop()
        try:
            yield {"services": services, "models": models, "api": clients["default"]}
        finally:
            for client in clients.values():
                client.close()


def test_lab_page_shows_every_bench_and_compares_them(browser, lab):
    services, models, api = lab["services"], lab["models"], lab["api"]
    context = browser.new_context(viewport={"width": 1500, "height": 900})
    page = context.new_page()
    page.set_default_timeout(60_000)
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(services["default"].dashboard_url("lab"))
        page.wait_for_selector("#page[data-ready='1']")
        page.wait_for_selector("#lab-compare tr[data-bench-id='dynamics']")
        rows = page.locator("#lab-benches tr[data-bench-id]")
        assert rows.count() == 3
        assert [rows.nth(i).get_attribute("data-bench-id") for i in range(3)] == sorted(LAB_BENCHES)
        view = {b["id"]: b for b in api.get("/lab/benches").json()["benches"]}
        for bench in LAB_BENCHES:
            row = page.locator(f"#lab-benches tr[data-bench-id='{bench}']")
            online = bench != "dynamics"
            assert row.get_attribute("data-online") == str(online).lower()
            status = row.locator("td.status")
            assert status.get_attribute("data-status") == ("online" if online else "stopped")
            assert ("OFFLINE" in status.inner_text()) is (not online)
            assert row.locator("td.num").nth(1).inner_text() == "1"  # its dataset, even offline
            cell = row.locator(f"td[data-model-id='{models[bench]}']")
            assert cell.count() == 1
            assert float(cell.get_attribute("data-validation-rms-um")) == pytest.approx(
                view[bench]["latest_models"]["y"]["validation_rms_um"], rel=1e-12
            )
        assert "(this service)" in page.locator("#lab-benches tr[data-bench-id='default']").inner_text()
        assert page.locator("#lab-benches tr.offline").count() == 1

        compared = {b["id"]: b for b in api.get("/lab/compare", params={"axis": "y"}).json()["benches"]}
        for bench in LAB_BENCHES:
            row = page.locator(f"#lab-compare tr[data-bench-id='{bench}']")
            model = compared[bench]["model"]
            assert row.get_attribute("data-model-id") == models[bench] == model["id"]
            assert float(row.get_attribute("data-validation-rms-um")) == pytest.approx(
                model["validation_rms_um"], rel=1e-12
            )
            assert row.locator("td.effects").inner_text() == " + ".join(EFFECTS[bench])
        creep = page.locator("#lab-compare tr[data-bench-id='creep'] td[data-parameter='creep.creep_pct_per_decade']")
        creep_pct = float(creep.get_attribute("data-value"))
        assert creep_pct == pytest.approx(
            compared["creep"]["model"]["parameters"]["creep"]["creep_pct_per_decade"], rel=1e-12
        )
        assert 2.0 < creep_pct < 4.5  # the bench: 3 %/decade
        resonance = page.locator("#lab-compare tr[data-bench-id='dynamics'] td[data-parameter='dynamics.resonance_hz']")
        resonance_hz = float(resonance.get_attribute("data-value"))
        assert resonance_hz == pytest.approx(
            compared["dynamics"]["model"]["parameters"]["dynamics"]["resonance_hz"], rel=1e-12
        )
        assert resonance_hz == pytest.approx(482.6, rel=0.05)  # the bench's Y resonance
        assert (
            page.locator(
                "#lab-compare tr[data-bench-id='default'] td[data-parameter='creep.creep_pct_per_decade']"
            ).get_attribute("data-value")
            is None
        )  # static PI: no creep
        shot(page, "lab")

        page.select_option("#lab-axis", "z")
        page.wait_for_selector("#lab-compare[data-axis='z']")
        assert page.locator("#lab-compare tr[data-model-id='']").count() == 3  # no Z model anywhere yet

        # the Datasets page of one service lists every bench's dataset, with its bench
        page.goto(services["default"].dashboard_url("datasets"))
        page.wait_for_selector("#dataset-list tr[data-dataset-id]")
        for bench in LAB_BENCHES:
            dataset = api.get(f"/models/{models[bench]}").json()["datasets"][0]
            assert page.locator(f"#dataset-list tr[data-dataset-id='{dataset}'] td.bench").inner_text() == bench
    finally:
        context.close()
    assert errors == [], f"console errors on the Lab page: {errors}"
