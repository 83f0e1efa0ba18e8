"""POST /api/trajectories/prepare (issue 39): the guided path runs as one service job, not in the
browser tab. Refused before anything is queued when a given model cannot be used (422 naming the
field) or while another prepare job is unfinished (409); a cancel of the job cancels the sweep it
is waiting for. The whole path to case 2 is run by tests/browser/test_web_tracking_flow.py."""

from __future__ import annotations

import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, wait_job
from tests.support.foreign_stage import SAMPLE_RATE_HZ, drive_v, stage_um

CASE2 = {"shape": "ellipse", "y_range_um": [1, 5], "z_range_um": [1, 9], "inclination_deg": 20, "frequency_hz": 100}

pytestmark = pytest.mark.realtime


@pytest.fixture
def client(tmp_path):
    # paced: the first sweep is still running at the cancel
    app = create_app(Settings(data_dir=tmp_path, bench="default_realtime", seed=0))
    with authed_client(app) as c:
        yield c


def test_prepare_refuses_a_model_it_cannot_use_and_queues_nothing(client):
    answer = client.post("/api/trajectories/prepare", json={**CASE2, "controller": {"feedforward_model_y": "mdl_none"}})
    assert answer.status_code == 422, answer.text
    assert answer.json()["field"] == "controller.feedforward_model_y"
    assert "mdl_none" in answer.json()["detail"]
    assert client.get("/api/jobs").json() == []


def test_prepare_refuses_a_model_fitted_on_another_stages_data(client):
    """The span is read from the given model: an imported model's span is another stage's (a walk
    swept 0–61 V where this bench needs 8–90 V, and the run was then refused)."""
    u = drive_v(frequencies_hz=(1,), cycles=(6,))
    x = stage_um("clean", u)
    lines = ["t_s,u_V,x_um"] + [f"{i / SAMPLE_RATE_HZ!r},{float(u[i])!r},{float(x[i])!r}" for i in range(u.size)]
    files = {"file": ("other_lab.csv", "\n".join(lines).encode(), "text/csv")}
    dataset = client.post("/api/datasets", files=files, data={"axis": "y"}).json()["id"]
    job = wait_job(client, client.post("/api/models", json={"axis": "y", "datasets": [dataset]}).json()["job_id"])
    model = job["result"]["model_id"]
    answer = client.post("/api/trajectories/prepare", json={**CASE2, "controller": {"feedforward_model_y": model}})
    assert answer.status_code == 422, answer.text
    assert answer.json()["field"] == "controller.feedforward_model_y" and "imported" in answer.json()["detail"]
    assert client.get("/api/jobs?kind=prepare").json() == [] and client.get("/api/jobs?kind=sweep").json() == []


def test_one_prepare_at_a_time_and_its_cancel_stops_the_sweep_it_waits_for(client):
    started = client.post("/api/trajectories/prepare", json=CASE2)
    assert started.status_code == 202, started.text
    job_id = started.json()["job_id"]

    def sweeping(job_id_):
        sweeps = client.get("/api/jobs?kind=sweep").json()
        return {"id": job_id_, "state": "sweeping" if sweeps else "waiting", "sweeps": sweeps}

    first = wait_job(sweeping, job_id, until=lambda j: j["state"] == "sweeping", timeout_s=60)["sweeps"]
    assert [s["params"]["axes"] for s in first] == [["y", "z"]]  # the first sweep, both axes without a model
    assert first[0]["params"]["frequencies_hz"] == [1, 10, 50, 100]

    again = client.post("/api/trajectories/prepare", json=CASE2)
    assert again.status_code == 409, again.text
    assert again.json()["field"] == "job" and job_id in again.json()["detail"]

    assert client.delete(f"/api/jobs/{job_id}").status_code == 202
    prepare = wait_job(client, job_id, timeout_s=60)
    assert prepare["state"] == "cancelled", prepare
    assert prepare["params"]["y_range_um"] == [1, 5]  # the ellipse it prepared for, for a reloaded page
    sweep = wait_job(client, first[0]["id"], timeout_s=60)
    assert sweep["state"] == "cancelled", sweep
    partial = client.get(f"/api/datasets/{sweep['result']['dataset_id']}").json()  # its samples kept
    assert partial["name"] == "the first sweep of Y and Z" and partial["partial"], partial
    # nothing is left running: a new prepare is accepted once the last one has ended
    assert client.post("/api/trajectories/prepare", json=CASE2).status_code == 202
