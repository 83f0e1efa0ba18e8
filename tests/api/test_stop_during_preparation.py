"""A stop pressed as a job starts, before its run moves the bench, holds for the whole job: the run
that follows ends at once at 0 V, and the job ends cancelled. Found by a new user (stop 28): a stop
pressed while a long trajectory was still computing its drive was answered, then the run's session
cleared the flag and drove every period. (The drive is now computed when the request is checked;
the job's own start, measuring the ILC's response included, is the window left.)"""

from __future__ import annotations

import time

import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, job_ended, wait_job

CASE2 = {"shape": "ellipse", "y_range_um": [1, 5], "z_range_um": [1, 9], "inclination_deg": 20, "frequency_hz": 100}


@pytest.fixture(scope="module")
def http_ff(tmp_path_factory):
    """(client, feedforward ids): static PIs on a 1 Hz sweep of an in-process service (its emulator in reach)."""
    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("prep"), bench="default", seed=2))
    with authed_client(app) as http:
        http.app_state = app.state
        job = http.post("/api/sweeps", json={"axes": ["y", "z"], "frequencies_hz": [1], "cycles": 2}).json()
        dataset_id = wait_job(http, job["job_id"], until=job_ended)["result"]["dataset_id"]
        ff = {}
        for axis in ("y", "z"):
            job = http.post("/api/models", json={"axis": axis, "datasets": [dataset_id], "model": "static_pi"}).json()
            ff[f"feedforward_model_{axis}"] = wait_job(http, job["job_id"], until=job_ended)["result"]["model_id"]
        yield http, ff


@pytest.mark.parametrize("controller", [{}, {"ilc": True}], ids=["ff", "ff+ilc"])
def test_a_stop_during_the_preparation_holds_for_the_run(http_ff, controller):
    http, ff = http_ff
    r = http.post("/api/trajectories", json={**CASE2, "cycles": 3000, "controller": {**ff, **controller}})
    assert r.status_code == 202, r.text
    job_id = r.json()["job_id"]
    deadline = time.monotonic() + 60
    while http.get(f"/api/jobs/{job_id}").json()["state"] != "running":
        assert time.monotonic() < deadline
        time.sleep(0.01)
    stop = http.post("/api/bench/stop").json()
    assert stop["cancelled_job_id"] == job_id, stop
    job = wait_job(http, job_id, until=job_ended, timeout_s=120)
    assert job["state"] == "cancelled", job
    kept = (job.get("result") or {}).get("dataset_id")
    samples = 0 if kept is None else http.get(f"/api/datasets/{kept}").json()["samples"]
    assert samples < 200, f"{samples} samples ran after the stop (a period is 200)"
    assert max(abs(v) for v in http.app_state.bench.output_v().values()) < 0.05
