"""A sweep made as an experiment says so (issue 39): POST /api/sweeps with ``experiment_of`` (the
Models page's Separate: the model whose diagnosis proposed it, the effects it separates, the datasets
that diagnosis had added) is stored with its dataset and shown in the list and on the dataset, so the
page finds the result again after a reload and Identify does not preselect it; a sweep the user
planned has none. The commands that reproduce a model leave it out of the sweep's body."""

from __future__ import annotations

import pytest

from service.http.app import create_app
from service.render.reproduce import dataset_request
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, wait_job

SWEEP = {"axes": ["y"], "frequencies_hz": [10], "cycles": 2}


@pytest.fixture
def http(tmp_path):
    with authed_client(create_app(Settings(data_dir=tmp_path, seed=0))) as client:
        yield client


def _swept(http, body: dict) -> str:
    r = http.post("/api/sweeps", json=body)
    assert r.status_code == 202, r.text
    job = wait_job(http, r.json()["job_id"])
    assert job["state"] == "succeeded", job
    return job["result"]["dataset_id"]


def test_an_experiments_dataset_keeps_what_it_is_the_experiment_of(http):
    planned = _swept(http, SWEEP)
    r = http.post("/api/models", json={"axis": "y", "datasets": [planned]})
    model_id = wait_job(http, r.json()["job_id"])["result"]["model_id"]
    made_for = {"model_id": model_id, "effects": ["delay", "rate_dependence"], "extra_datasets": [planned]}
    experiment = _swept(http, {**SWEEP, "experiment_of": made_for})

    listed = {d["id"]: d for d in http.get("/api/datasets").json()}
    assert listed[planned]["experiment_of"] is None
    assert listed[experiment]["experiment_of"] == made_for
    stored = http.get(f"/api/datasets/{experiment}").json()
    assert stored["experiment_of"] == made_for and stored["plan"]["frequencies_hz"] == [10.0]
    # re-recording it is a plain sweep: the model it was made for is not the one the steps make again
    assert "experiment_of" not in dataset_request(stored)["body"]

    for bad, why in (
        ({"model_id": "md_nope"}, "no model md_nope"),
        ({"model_id": model_id, "effects": ["a", "b", "c"]}, None),
        ({"model_id": model_id, "colour": "red"}, None),
    ):
        r = http.post("/api/sweeps", json={**SWEEP, "experiment_of": bad})
        assert r.status_code == 422, (bad, r.text)
        if why:
            assert r.json()["field"] == "experiment_of" and why in r.json()["detail"], r.text
    assert len(http.get("/api/datasets").json()) == 2  # nothing queued for a refused one


def test_a_discover_finds_the_experiment_already_recorded_for_its_model(http):
    """The walk ran a diagnosis's separating sweep from the Models page, then a discover with
    experiments ran the identical sweep again: the loop now joins the dataset recorded for that model
    with that body (service.usecases.discover_experiments.recorded_already)."""
    from service.usecases.discover_experiments import recorded_already

    planned = _swept(http, SWEEP)
    r = http.post("/api/models", json={"axis": "y", "datasets": [planned]})
    model_id = wait_job(http, r.json()["job_id"])["result"]["model_id"]
    body = {**SWEEP, "waveform": "sine", "frequencies_hz": [10.0, 20.0]}
    experiment = _swept(http, {**body, "experiment_of": {"model_id": model_id, "effects": ["delay", "dynamics"]}})
    store = http.app.state.store
    assert recorded_already(store, model_id, [body], exclude=[planned]) == experiment
    assert recorded_already(store, model_id, [{**body, "frequencies_hz": [10.0, 30.0]}], exclude=[]) is None
    assert recorded_already(store, model_id, [body], exclude=[experiment]) is None
    assert recorded_already(store, "md_other", [body], exclude=[]) is None
    # the user's own sweep with the same body is not an experiment of the model: never joined for it
    assert recorded_already(store, model_id, [SWEEP], exclude=[]) is None
