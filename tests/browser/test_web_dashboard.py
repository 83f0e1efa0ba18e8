"""The web dashboard in a real browser: Debian's chromium, headless, driven by Playwright, against
the real service (``evcbench serve`` under uvicorn, on a free port, a temp data dir and a small
hidden-effect bench). Every page is screenshotted into tests/artifacts/ and must log no console
error; the assertions read numbers off the page (text and data attributes) and check them against
the API.

Set-up and the shared fixtures: tests/support/browser.py and tests/browser/conftest.py.
"""

from __future__ import annotations

import json
import math
import os
import re

import pytest

from tests.support.api_client import wait_job
from tests.support.browser import goto, job_of, posted_result, serving, shot, swept_static_pi  # noqa: F401
from tests.support.realdata import MODEL_VI_DO as REAL

#: Live services and one browser, module fixtures: one worker runs the file.
pytestmark = [pytest.mark.browser, pytest.mark.realtime, pytest.mark.xdist_group("web_dashboard")]

#: The hidden-effect bench the tests run on (fixtures/benches/<name>.toml); its effect is the name.
HIDDEN = os.environ.get("EVCBENCH_WEB_TEST_BENCH", "creep")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """``evcbench serve`` on the hidden-effect bench, in a subprocess with its own data dir."""
    with serving(tmp_path_factory, HIDDEN) as s:
        yield s


def run_sweep_in_browser(page, server, frequencies: str = "10,50,100", cycles: int = 3, axes=("y",)) -> str:
    """Fill the Sweeps form, start it, wait for the progress line to reach 'succeeded'; the dataset id."""
    goto(page, server, "sweeps")
    for axis in ("y", "z"):
        page.set_checked(f"#sweep-form input[name=axis][value={axis}]", axis in axes)
    page.fill("#sweep-form input[name=frequencies]", frequencies)
    page.fill("#sweep-form input[name=cycles]", str(cycles))
    page.click("#sweep-start")
    page.wait_for_selector("#sweep-job .jobline[data-state='succeeded']", timeout=120_000)
    assert page.inner_text("#sweep-job .jpct") == "100 %"
    page.wait_for_selector("#sweep-dataset")
    page.wait_for_selector("#sweep-chart canvas")
    return page.get_attribute("#sweep-dataset", "data-dataset-id")


# ------------------------------------------------------------------------------------------------


def test_every_page_renders_with_units_and_no_console_errors(page, server):
    dataset_id = run_sweep_in_browser(page, server)
    ds = server["api"].get(f"/datasets/{dataset_id}").json()
    assert ds["n_blocks"] == 3 and [b["frequency_hz"] for b in ds["blocks"]] == [10.0, 50.0, 100.0]
    shot(page, "sweeps")

    goto(page, server, "bench")
    page.wait_for_selector("#live canvas")
    page.wait_for_timeout(800)  # a few live samples
    bench = server["api"].get("/bench").json()
    assert page.locator("#limits tr").count() == 1 + len(bench["axes"])
    # one unit for a current on the page: the state's "current (mA)" and the hard limit's, both in mA
    assert "current (mA)" in page.inner_text("#state tr:first-child") and "current (mA)" in page.inner_text(
        "#limits tr:first-child"
    )
    limit_ma = page.locator("#limits tr").nth(1).locator("td").nth(4).inner_text()
    assert float(limit_ma) == pytest.approx(bench["limits"]["y"]["current_limit_a"] * 1e3, rel=1e-3)
    assert abs(float(page.get_attribute("#state tr[data-axis=y] td[data-output-v]", "data-output-v"))) < 0.5
    # a reading that rounds to zero prints unsigned: a signed zero (or -0.01 mA) is "0.0", not "-0.0"
    fixed = "import('./js/api.js').then((m) => [m.fmtFixed(-0, 1), m.fmtFixed(-1e-5, 1), m.fmtFixed(-0.06, 1), m.fmtFixed(-0.004, 2)])"
    assert page.evaluate(fixed) == ["0.0", "0.0", "-0.1", "0.00"]
    assert not re.search(r"(?<![0-9])-0\.0+(?![0-9])", page.inner_text("#state"))
    assert "amplifier output (V)" in page.inner_text("#live") or page.locator("#live canvas").count() > 0
    shot(page, "bench")

    goto(page, server, f"datasets/{dataset_id}")
    page.wait_for_selector(".loop canvas")
    loops = page.locator(".loop")
    assert loops.count() == 3
    assert [loops.nth(i).get_attribute("data-frequency-hz") for i in range(3)] == ["10", "50", "100"]
    assert page.get_attribute("#export-csv", "href").endswith(f"/api/datasets/{dataset_id}/data?format=csv")
    csv = server["api"].get(server["url"] + page.get_attribute("#export-csv", "href")).text
    assert csv.splitlines()[0].startswith("t,") and len(csv.splitlines()) == ds["samples"] + 1
    assert (
        server["api"].get(server["url"] + page.get_attribute("#export-hdf5", "href")).content[:8]
        == b"\x89HDF\r\n\x1a\n"
    )
    shot(page, "dataset")

    goto(page, server, "datasets")
    assert page.locator(f"#dataset-list tr[data-dataset-id='{dataset_id}']").count() == 1
    shot(page, "datasets")

    # Identify from the form, then the Compare view: the per-frequency table shows the API's numbers.
    goto(page, server, f"models?dataset={dataset_id}")
    page.select_option("#identify-form select[name=axis]", "y")
    page.select_option("#identify-datasets", [dataset_id])
    page.click("#identify-start")
    page.wait_for_selector("#model-id", timeout=120_000)
    model_id = page.inner_text("#model-id")
    page.wait_for_selector("#compare-loop canvas")
    compared = server["api"].get(f"/models/{model_id}/compare", params={"dataset": dataset_id, "arrays": False}).json()
    rows = page.locator("#table6 tr[data-frequency-hz]")
    assert rows.count() == 3
    for i, block in enumerate(compared["metrics"]["per_block"]):
        assert float(rows.nth(i).get_attribute("data-frequency-hz")) == block["frequency_hz"]
        assert math.isclose(float(rows.nth(i).get_attribute("data-rms")), block["validation"]["rms_um"], rel_tol=1e-9)
        shown_nm = float(rows.nth(i).locator("td.rms").inner_text())  # errors are printed in nm
        assert math.isclose(shown_nm, 1e3 * block["validation"]["rms_um"], rel_tol=1e-3)
    model = server["api"].get(f"/models/{model_id}").json()
    assert math.isclose(
        float(page.get_attribute("#model-validation-rms", "data-value")),
        model["metrics"]["validation_rms_um"],
        rel_tol=1e-9,
    )
    assert "nm" in page.inner_text("#compare-table") and "58.6" in page.inner_text("#table6")  # paper column, in nm
    assert "µm" not in page.inner_text("#table6")  # one unit for errors
    library = server["api"].get("/effects").json()
    assert len(library["effects"]) > 10
    page.wait_for_function(  # the card fills when GET /api/effects answers, after the page's first paint
        "n => document.querySelectorAll('#effects-library tr[data-effect]').length === n", arg=len(library["effects"])
    )
    assert "µm/V" in page.text_content("#effects-library tr[data-effect=cross_coupling]")
    shot(page, "models")

    goto(page, server, "trajectories")
    assert page.locator("#traj-errors").inner_text().count("308") == 1  # the paper's 0.308 µm, in nm
    # the paper's relative errors by the page's own definition (case 2: 154 nm / 4 µm), its stated bound in the note
    relative = page.locator("#traj-errors tr[data-key=relative_error_pct] td").all_inner_texts()
    assert "154" in page.inner_text("#traj-errors") and relative[-2:] == ["6.16", "3.85"]
    assert "< 6.2 %" in page.inner_text("#traj-relative-note")
    # the relative error says what it divides by what, as the service computes it (control/session.py)
    defined = "the larger over Y and Z of (max |error| on the axis ÷ the reference's peak-to-peak on that axis"
    assert page.get_attribute("#traj-errors tr[data-key=relative_error_pct] td", "title").startswith(defined)
    assert page.inner_text("#traj-relative-note").startswith(f"Relative error: {defined}")
    shot(page, "trajectories")


def test_trajectory_pid_select_offers_auto_tuned_paper_and_custom(page, server):
    goto(page, server, "trajectories")
    options = page.eval_on_selector_all("#traj-pid option", "els => els.map((e) => e.value)")
    assert options == ["", "auto", "tuned", "paper", "custom"]
    assert not page.is_visible("#traj-form input[name=kp_z]")
    page.select_option("#traj-pid", "custom")
    assert page.is_visible("#traj-form input[name=kp_z]")
    page.select_option("#traj-pid", "paper")  # refused before anything runs (issue 19 §2)
    page.click("#traj-start")
    page.wait_for_function("() => document.querySelector('#traj-error').textContent.includes('paper')")
    # in the page's words: the API's body path (controller.pid) is named by its control's label, marked
    refusal = page.inner_text("#traj-error")
    assert "controller." not in refusal and "“PID”" in refusal, refusal
    assert "invalid" in (page.get_attribute("#traj-pid", "class") or "")
    assert all("422" in e for e in page.console_errors)  # the browser logs the refusal it was meant to get
    page.console_errors.clear()


def _static_pi_per_axis(server, **sweep) -> dict:
    """A two-axis sweep over REST and a static PI on it per axis: {axis: model id}."""
    api = server["api"]
    job = api.post("/sweeps", json={"axes": ["y", "z"], **sweep}).json()
    dataset_id = wait_job(job_of(server), job["job_id"])["result"]["dataset_id"]
    models = {}
    for axis in ("y", "z"):
        job = api.post("/models", json={"axis": axis, "datasets": [dataset_id], "model": "static_pi"}).json()
        models[axis] = wait_job(job_of(server), job["job_id"])["result"]["model_id"]
    return models


def test_trajectory_page_sweeps_the_span_the_ellipse_needs(page, server):
    """ "Prepare the models it needs" runs one sweep per axis over the feedforward drive's span ± 5 V and
    selects the models identified on them."""
    models = _static_pi_per_axis(server, frequencies_hz=[1], cycles=2)
    goto(page, server, "trajectories")
    page.select_option("#traj-preset", "case2")
    page.select_option("#traj-form select[name=feedforward_model_y]", models["y"])
    page.select_option("#traj-form select[name=feedforward_model_z]", models["z"])
    page.click("#traj-span-sweep")
    page.wait_for_selector("#traj-prepared", timeout=300_000)
    assert page.locator("#traj-span .jobline[data-state='succeeded']").count() == 1  # one prepare job
    for axis in ("y", "z"):  # a span sweep and a model on it per axis, the model selected
        assert page.locator(f"#traj-span .prep-step[data-axis={axis}]").count() == 2
        chosen = page.input_value(f"#traj-form select[name=feedforward_model_{axis}]")
        assert chosen != models[axis] and server["api"].get(f"/models/{chosen}").json()["axis"] == axis
    assert "span" in page.inner_text("#traj-span") and " V for a 100 Hz ellipse" in page.inner_text("#traj-span")


def test_import_headerless_file_with_column_mapping(page, server):
    goto(page, server, "datasets")
    page.set_input_files("#import-file", str(REAL))
    page.wait_for_selector("#preview-table")
    # The preview parses the first lines here: 7 columns, no header, 10 rows.
    assert page.locator("#preview-table .col-role").count() == 7
    assert page.locator("#preview-table tr").count() == 11
    first = REAL.read_text().split()[:7]
    assert [float(page.locator("#preview-table tr").nth(1).locator("td").nth(i).inner_text()) for i in (0, 4)] == [
        float(first[0]),
        float(first[4]),
    ]
    # numbered from 1 as the record's README numbers them: its "col 1" drive and "col 5" sensor
    labels = page.locator("#preview-table .col-number").all_inner_texts()
    assert labels == [f"col {i}" for i in range(1, 8)], labels
    page.select_option("#import-delimiter", "whitespace")
    page.wait_for_selector("#preview-delimiter:has-text('whitespace')")
    page.select_option(".col-role[data-col='0']", "u")
    page.select_option(".col-role[data-col='4']", "x")
    page.select_option("#import-axis", "y")
    page.fill("#import-rate", "200")
    shot(page, "import_preview")
    page.click("#import-submit")
    page.wait_for_selector("#import-done")
    dataset_id = page.get_attribute("#import-done", "data-dataset-id")
    assert page.get_attribute("#import-done", "data-samples") == "8027"
    ds = server["api"].get(f"/datasets/{dataset_id}").json()
    assert ds["samples"] == 8027 and ds["sample_rate_hz"] == 200.0 and ds["axes"] == ["y"]
    assert json.loads(ds["plan"]["import"]["columns"]) == {"u": 0, "x": 4}
    assert ds["plan"]["import"]["delimiter"] == "whitespace"
    data = server["api"].get(f"/datasets/{dataset_id}/data").json()
    assert data["u_y_v"][0] == float(first[0]) and data["x_y_um"][0] == float(first[4])
    assert "8027 samples at 200 Hz" in page.inner_text("#import-result")
    page.click("#import-done a")
    page.wait_for_selector(".loop canvas")
    assert page.get_attribute("#dataset-summary", "data-samples") == "8027"
    shot(page, "import_dataset")


def test_an_import_with_units_in_its_header_says_what_it_converted(page, server, tmp_path):
    """Another lab's export, 'Time [ms],Voltage (V),Displacement [nm]', mapped by the page's roles:
    stored in s, V and µm, and the conversions shown after the upload and on the dataset's page."""
    t_ms = [i * 1.0 for i in range(3000)]  # 1 kHz, 3 s of a 1 Hz drive
    u_v = [50 - 50 * math.cos(2 * math.pi * t / 1000) for t in t_ms]
    x_nm = [120 * u - 1200 * math.sin(2 * math.pi * t / 1000) for t, u in zip(t_ms, u_v)]
    path = tmp_path / "lab-b.csv"
    path.write_text(
        "Time [ms],Voltage (V),Displacement [nm]\n"
        + "".join(f"{t},{u:.6f},{x:.4f}\n" for t, u, x in zip(t_ms, u_v, x_nm))
    )
    goto(page, server, "datasets")
    page.set_input_files("#import-file", str(path))
    page.wait_for_selector("#preview-table")
    for col, role in ((0, "t"), (1, "u"), (2, "x")):
        page.select_option(f".col-role[data-col='{col}']", role)
    page.select_option("#import-axis", "y")
    page.click("#import-submit")
    page.wait_for_selector("#import-done")
    notes = page.locator("#import-result .import-note").all_inner_texts()
    assert any("'Time [ms]' gives ms" in n for n in notes) and any("'Displacement [nm]' gives nm" in n for n in notes)
    dataset_id = page.get_attribute("#import-done", "data-dataset-id")
    assert float(page.get_attribute("#import-done", "data-sample-rate-hz")) == 1000.0
    data = server["api"].get(f"/datasets/{dataset_id}/data").json()
    assert abs(data["x_y_um"][250] - x_nm[250] / 1000) < 1e-6  # stored in µm
    page.click("#import-done a")
    page.wait_for_selector("#import-notes")
    assert "converted to µm" in page.inner_text("#import-notes")


def test_emergency_stop_during_a_sweep(page, server):
    goto(page, server, "sweeps")
    page.fill("#sweep-form input[name=frequencies]", "0.5")
    page.fill("#sweep-form input[name=cycles]", "100")
    page.click("#sweep-start")
    page.wait_for_function(
        "() => { const j = document.querySelector('#sweep-job .jobline');"
        " return j && j.dataset.state === 'running' && Number(j.dataset.progress) > 0; }",
        timeout=60_000,
    )
    job_id = page.get_attribute("#sweep-job .jobline", "data-job-id")
    assert server["api"].get("/bench").json()["running_job_id"] == job_id
    page.click("#estop")
    page.wait_for_selector("#banner.info:has-text('Emergency stop')")
    page.wait_for_selector("#sweep-job .jobline[data-state='cancelled']", timeout=60_000)
    assert "cancelled" in page.inner_text("#sweep-job")
    stopped = json.loads(page.get_attribute("#banner", "data-stopped"))
    assert stopped["cancelled_job_id"] == job_id
    assert stopped["door"] == "stop port"  # the engine's own port, not the web process's route
    bench = server["api"].get("/bench").json()
    # 0 V, to the amplifier's output noise (the tolerance of tests/api/test_service_api.py)
    assert all(abs(bench["amplifiers"][a]["output_v"]) < 0.05 for a in bench["axes"])
    assert all(abs(v) < 0.05 for v in stopped["output_v"].values())
    assert server["api"].get(f"/jobs/{job_id}").json()["state"] == "cancelled"
    assert job_id in page.inner_text("#banner")
    volts = dict(re.findall(r"\b([yz]) (-?[0-9.]+) V", page.inner_text("#banner")))
    assert sorted(volts) == sorted(bench["axes"]) and all(abs(float(v)) < 0.05 for v in volts.values())
    shot(page, "emergency_stop")
    # The Bench page shows 0 V on every axis and no running job.
    goto(page, server, "bench")
    for axis in bench["axes"]:
        assert abs(float(page.get_attribute(f"#state tr[data-axis={axis}] td[data-output-v]", "data-output-v"))) < 0.05
    assert page.inner_text("#running") == "none"


def test_discovery_story_in_the_browser(page, server):
    # A 1 Hz block gives creep (log-time) room to show within a block.
    dataset_id = run_sweep_in_browser(page, server, frequencies="1,10,50,100")
    goto(page, server, f"models?dataset={dataset_id}")
    page.select_option("#identify-datasets", [dataset_id])
    page.click("#identify-start")
    page.wait_for_selector("#model-id", timeout=120_000)
    model_id = page.inner_text("#model-id")
    page.wait_for_selector("#candidates tr[data-effect]", timeout=120_000)
    diagnosis = server["api"].get(f"/models/{model_id}/diagnosis").json()
    shown = [
        page.locator("#candidates tr[data-effect]").nth(i).get_attribute("data-effect")
        for i in range(page.locator("#candidates tr[data-effect]").count())
    ]
    assert shown == [c["effect"] for c in diagnosis["candidates"] if c.get("testable", True)]
    # what this data cannot test is listed apart, each with the sweep that would test it
    untestable = [c["effect"] for c in diagnosis["not_testable"]]
    assert page.locator("#not-testable li").count() == len(untestable)
    assert page.locator("#not-testable .run-test").count() == len(untestable)
    assert shown[0] == HIDDEN, f"the diagnosis ranks {shown} on the {HIDDEN} bench"
    assert page.get_attribute("#diagnosis-verdict", "data-verdict") == diagnosis["verdict"]
    history = json.loads(page.get_attribute("#history-chart", "data-values"))
    assert len(history) == 1
    page.wait_for_selector("#compare-loop canvas")
    shot(page, "diagnosis")

    page.click(f"#candidates button.add-effect[data-effect='{HIDDEN}']")
    # the refine job makes a new model and the page moves to it: its route and its content, as after Identify
    page.wait_for_function(
        "id => { const e = document.querySelector('#model-id'); return e && e.textContent !== id; }",
        arg=model_id,
        timeout=150_000,
    )
    child = page.inner_text("#model-id")
    refine = server["api"].get("/jobs", params={"kind": "refine", "limit": 1}).json()[0]
    assert refine["state"] == "succeeded" and refine["result"]["model_id"] == child
    assert page.evaluate("location.hash") == f"#/models/{child}"
    assert f"refined from {model_id}" in page.inner_text("#model-detail .card h2")
    page.wait_for_selector("#page[data-ready='1']")
    page.wait_for_selector("#candidates tr[data-effect]", timeout=120_000)  # the new model's own diagnosis
    assert page.locator(f"#candidates button.add-effect[data-effect='{HIDDEN}']").count() == 0
    page.wait_for_function("() => JSON.parse(document.querySelector('#history-chart').dataset.values).length === 2")
    values = json.loads(page.get_attribute("#history-chart", "data-values"))
    models = json.loads(page.get_attribute("#history-chart", "data-models"))
    assert models == [model_id, child]
    api_values = [server["api"].get(f"/models/{m}").json()["metrics"]["validation_rms_um"] for m in models]
    assert values == pytest.approx(api_values, rel=1e-9)
    assert values[1] < values[0] / 2, f"the error did not fall by half: {values}"
    # The refit lands where the diagnosis said it would (its expected RMS for the top candidate).
    assert values[1] == pytest.approx(diagnosis["candidates"][0]["expected_rms_um"], rel=0.1)
    assert server["api"].get(f"/models/{child}").json()["parent_id"] == model_id
    page.wait_for_selector(f"#model-list tr.best[data-model-id='{child}']")  # the stored list shows it, marked
    shot(page, "refine_history")
    page.reload()  # the route is the new model's: a reload shows it again
    page.wait_for_selector("#page[data-ready='1']")
    assert page.inner_text("#model-id") == child


def test_trajectory_with_ilc_error_falls_on_screen(page, server):
    api = server["api"]
    models = _static_pi_per_axis(server, frequencies_hz=[10, 50, 100], cycles=3)
    goto(page, server, "trajectories")
    page.select_option("#traj-preset", "case1")
    page.fill("#traj-form input[name=amplitude_y_um]", "7")  # no longer the paper's case 1 ellipse
    assert page.input_value("#traj-preset") == ""
    page.select_option("#traj-preset", "case1")
    page.select_option("#traj-form select[name=feedforward_model_y]", models["y"])
    page.select_option("#traj-form select[name=feedforward_model_z]", models["z"])
    page.fill("#traj-form input[name=cycles]", "30")
    assert page.input_value("#traj-preset") == "case1"  # the periods are not the ellipse
    page.set_checked("#traj-form input[name=ilc]", True)
    page.click("#traj-start")
    page.wait_for_selector("#traj-job .jobline[data-state='succeeded']", timeout=150_000)
    page.wait_for_function("() => Number(document.querySelector('#period-chart').dataset.points || 0) > 1")
    values = json.loads(page.get_attribute("#period-chart", "data-values"))
    assert values[-1] < values[0] / 3, f"the error per period did not fall: {values[:3]} … {values[-3:]}"
    job_id = page.get_attribute("#traj-job .jobline", "data-job-id")
    result = api.get(f"/jobs/{job_id}").json()["result"]
    for key in ("max_error_y_um", "max_error_z_um", "rms_error_um", "relative_error_pct"):
        cell = page.locator(f"#traj-errors tr[data-key={key}] td[data-value]")
        assert math.isclose(float(cell.get_attribute("data-value")), result[key], rel_tol=1e-9)
    page.wait_for_selector("#ellipse-chart canvas")
    shot(page, "trajectory")
    # The tracking loop fed the live signals too: its last run spans the 36 periods at 100 Hz.
    live = api.get("/bench/live", params={"max_points": 20_000}).json()
    run = [k for k, r in enumerate(live["runs"]) if r == live["run"]]
    assert live["label"] == "tracking" and len(run) > 200
    assert live["t_s"][run[-1]] == pytest.approx(36 / 100.0, abs=0.02)
    assert 5.0 < max(live["x_z_um"][k] for k in run) < 12.5


def test_live_chart_shows_points_during_a_job(page, server):
    """The Bench page draws u and x per axis while a sweep streams (GET /api/bench/live)."""
    goto(page, server, "bench")
    page.wait_for_selector("#live-y canvas")
    job = server["api"].post("/sweeps", json={"axes": ["y"], "frequencies_hz": [0.5], "cycles": 60}).json()
    # a job started from another client is seen at the page's next idle poll (1.5 s); the emulator runs
    # this 120 s sweep in about 1.3 s, so the test asks the page to look now, as a job started on it does
    page.evaluate("window.dispatchEvent(new Event('evc:job'))")
    page.wait_for_function(
        "id => { const l = document.querySelector('#live'); const y = document.querySelector('#live-y');"
        " return l.dataset.job === id && Number(y.dataset.points) > 300; }",
        arg=job["job_id"],
        timeout=60_000,
    )
    y = page.locator("#live-y")
    # The drive swings over most of 0–120 V within the first cycles and the stage follows in µm.
    page.wait_for_function("() => Number(document.querySelector('#live-y').dataset.uMaxV) > 60", timeout=60_000)
    assert float(y.get_attribute("data-u-max-v")) <= 120.5
    assert float(y.get_attribute("data-x-max-um")) > 1.0
    assert "Streaming: job " + job["job_id"] in page.inner_text("#live-status")
    labels = page.inner_text("#live-y")
    assert "u_y (V)" in labels and "x_y (µm)" in labels and "time in run (s)" in labels
    # (No "still growing" check: the emulator streams this 120 s sweep in about a second.)
    shot(page, "bench_live")
    assert wait_job(job_of(server), job["job_id"])["state"] == "succeeded"


def test_errors_are_shown_in_words(page, server):
    """A refused sweep and a refused import show the API's words next to the form."""
    goto(page, server, "sweeps")
    page.fill("#sweep-form input[name=frequencies]", "10,400")  # above half the Y resonance (482.6 Hz)
    page.click("#sweep-start")
    page.wait_for_selector("#sweep-error.error")
    text = page.inner_text("#sweep-error")
    assert text.startswith("frequencies_hz: ") and "400 Hz" in text and "mA" in text, text
    goto(page, server, "datasets")
    before = len(server["api"].get("/datasets").json())
    page.set_input_files(
        "#import-file",
        files=[{"name": "broken.csv", "mimeType": "text/csv", "buffer": b"t,u_y,x_y\n0,1,2\n0.001,abc,3\n"}],
    )
    page.wait_for_selector("#preview-table")
    page.click("#import-submit")
    page.wait_for_selector("#import-result.error")
    text = page.inner_text("#import-result")
    assert text.startswith("Import refused: ") and len(text) > 30 and not re.search(r"\b\d{3} [A-Z]", text), text
    assert len(server["api"].get("/datasets").json()) == before
    shot(page, "errors")
    # The browser logs each refused request as a failed resource; nothing else may be logged.
    refused = [e for e in page.console_errors if re.search(r"status of 4\d\d", e)]
    assert len(refused) == 2, page.console_errors
    page.console_errors[:] = [e for e in page.console_errors if e not in refused]


def test_a_latched_amplifier_fault_is_reset_from_the_bench_page(page, server):
    api = server["api"]
    assert (
        api.post("/admin/faults", json={"fault": "amplifier_overcurrent", "axis": "z", "after_s": 0.05}).status_code
        == 201
    )
    job = api.post("/sweeps", json={"axes": ["z"], "frequencies_hz": [50], "cycles": 20}).json()
    ended = wait_job(job_of(server), job["job_id"])
    assert ended["state"] == "failed" and "amplifier z: over-current" in ended["error"]
    goto(page, server, "bench")
    page.wait_for_selector("#fault-actions:not([hidden])")
    assert "over-current" in page.inner_text("#state tr[data-axis=z]")
    page.click("#reset-faults")
    page.wait_for_selector("#reset-result:has-text('Cleared: amplifier z: over-current')")
    page.wait_for_selector("#fault-actions[hidden]", state="attached")
    shot(page, "bench_reset")
    bench = api.get("/bench").json()
    assert not bench["amplifiers"]["z"]["fault"] and abs(bench["amplifiers"]["z"]["output_v"]) < 0.05
    assert api.delete("/admin/faults").status_code == 200
    again = api.post("/sweeps", json={"axes": ["z"], "frequencies_hz": [50], "cycles": 3}).json()
    assert wait_job(job_of(server), again["job_id"])["state"] == "succeeded"


def test_a_single_axis_file_whose_header_names_its_columns_imports_on_the_axis_shown(page, server, tmp_path):
    """A new user's 't_s,u_V,x_um' file, roles left as the page guessed them and the axis select as it
    shows (y): imported on axis y (it was refused, "needs axis set … got None", while the page showed y)."""
    path = tmp_path / "bw.csv"
    path.write_text(
        "t_s,u_V,x_um\n" + "".join(f"{i / 1000},{50 - 50 * math.cos(i / 100):.6f},{0.1 * i:.4f}\n" for i in range(2000))
    )
    goto(page, server, "datasets")
    page.set_input_files("#import-file", str(path))
    page.wait_for_selector("#preview-table")
    assert page.input_value("#import-axis") == "y"
    page.click("#import-submit")
    page.wait_for_selector("#import-done")
    ds = server["api"].get(f"/datasets/{page.get_attribute('#import-done', 'data-dataset-id')}").json()
    assert ds["axes"] == ["y"] and ds["samples"] == 2000
