"""Discovery end to end over REST on an emulated variant bench: sweep → POST /api/models →
GET diagnosis → POST refine → GET history, plus bad effect names (422 naming the field)."""

from __future__ import annotations

import warnings

import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, wait_job

pytestmark = pytest.mark.slow  # sweeps, identifications and diagnoses through the API


def _wait(http, job_id, timeout_s=120.0) -> dict:
    job = wait_job(http, job_id, timeout_s=timeout_s)
    assert job["state"] == "succeeded", job
    return job["result"]


@pytest.fixture
def http(tmp_path):
    warnings.simplefilter("ignore")
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="creep", seed=0))) as client:
        yield client


def test_discovery_over_rest(http):
    r = http.post(
        "/api/sweeps", json={"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 5, "together": False}
    )
    assert r.status_code == 202, r.text
    dataset_id = _wait(http, r.json()["job_id"])["dataset_id"]

    r = http.post("/api/models", json={"axis": "y", "datasets": [dataset_id], "effects": ["hysteresis", "warp"]})
    assert r.status_code == 422 and r.json()["field"] == "effects"
    r = http.post("/api/models", json={"axis": "y", "datasets": [dataset_id], "effects": ["hysteresis"]})
    assert r.status_code == 202, r.text
    base_id = _wait(http, r.json()["job_id"])["model_id"]

    d = http.get(f"/api/models/{base_id}/diagnosis")
    assert d.status_code == 200, d.text
    d = d.json()
    for key in ("residual_rms_um", "noise_floor_um", "verdict", "candidates", "failures", "ambiguity"):
        assert key in d
    assert d["verdict"] == "missing_effect"
    assert d["candidates"][0]["effect"] == "creep"
    # one noise floor for one model's data: its page (stored metrics) and its diagnosis, both read at rest
    stored = http.get(f"/api/models/{base_id}").json()["metrics"]["noise_floor_um"]
    assert d["noise"]["source"] == "rests" and stored == pytest.approx(d["noise_floor_um"], rel=1e-9)
    assert {"effect", "score", "expected_rms_um", "evidence", "kind"} <= set(d["candidates"][0])
    # the sweep's dataset carries its amplifier's rating (0.2 A into 1.8 µF): its 37.7 kV/s cannot test a limit
    slew = next(c for c in d["not_testable"] if c["effect"] == "slew_limit")
    assert "37.7 kV/s" in slew["reason"] and "111 kV/s" in slew["reason"], slew
    # a failing block is named by what it is, beside the record and block it is
    blocks = [f for f in d["failures"] if f["by"] == "frequency"]
    assert blocks, d["failures"]
    for f in blocks:
        assert f["record"] == dataset_id and f"{f['frequency_hz']:g} Hz block" in f["where"]
        assert f["block"] == f"Y {f['frequency_hz']:g} Hz sine (held-out cycle 5)", f

    assert http.post(f"/api/models/{base_id}/refine", json={"add": "warp"}).status_code == 422
    assert http.post(f"/api/models/{base_id}/refine", json={"remove": "creep"}).json()["field"] == "remove"
    r = http.post(f"/api/models/{base_id}/refine", json={"add": "creep"})
    assert r.status_code == 202, r.text
    new_id = _wait(http, r.json()["job_id"])["model_id"]
    model = http.get(f"/api/models/{new_id}").json()
    assert model["parent_id"] == base_id and model["effects"] == ["hysteresis", "creep"]
    assert model["kind"] == "composite"
    by_freq = model["metrics"]["held_out_frequencies"]
    assert [p["frequency_hz"] for p in by_freq["per_frequency"]] == [1.0, 10.0, 50.0, 100.0]
    assert by_freq["validation_rms_um"] > 0
    bad = http.get(f"/api/models/{new_id}/diagnosis", params={"extra_datasets": "ds_nope"})
    assert bad.status_code == 422 and bad.json()["field"] == "extra_datasets"

    cmp = http.get(f"/api/models/{new_id}/compare", params={"dataset": dataset_id, "arrays": False})
    assert cmp.status_code == 200, cmp.text

    h = http.get(f"/api/models/{new_id}/history").json()["steps"]
    assert [s["model_id"] for s in h] == [base_id, new_id]
    assert h[1]["change"] == "+creep"
    assert h[1]["validation_rms_um"] <= 0.5 * h[0]["validation_rms_um"]

    d2 = http.get(f"/api/models/{new_id}/diagnosis").json()
    assert all(c["effect"] != "creep" for c in d2["candidates"])
    assert d2["residual_rms_um"] == pytest.approx(model["metrics"]["validation_rms_um"], rel=1e-9)
    r = http.post(f"/api/models/{new_id}/refine", json={"effects": ["hysteresis"]})
    back = _wait(http, r.json()["job_id"])["model_id"]
    assert http.get(f"/api/models/{back}").json()["effects"] == ["hysteresis"]


def test_a_sweep_imported_as_a_bare_csv_is_cut_into_its_blocks_and_diagnosed(tmp_path):
    """A characterisation that reaches the service as a CSV without its block table (exported
    elsewhere, simulated, ...) is validated per frequency like a sweep: the import finds the blocks,
    and the diagnosis finds the hidden effect (a frequency-dependent one: the held-out part of a
    bare file's last 20 % would be one axis at rest)."""
    warnings.simplefilter("ignore")
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="dynamics", seed=0))) as http:
        r = http.post(
            "/api/sweeps", json={"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 5, "together": False}
        )
        swept = _wait(http, r.json()["job_id"])["dataset_id"]
        csv = http.get(f"/api/datasets/{swept}/data", params={"format": "csv"}).content
        r = http.post("/api/datasets", files={"file": ("sweep.csv", csv, "text/csv")}, data={"name": "bare sweep"})
        assert r.status_code == 201, r.text
        imported = http.get(f"/api/datasets/{r.json()['id']}").json()
        blocks = imported["blocks"]
        assert [round(b["frequency_hz"], 3) for b in blocks] == [1.0, 10.0, 50.0, 100.0] * 2
        assert [b["axes"] for b in blocks] == [["y"]] * 4 + [["z"]] * 4 and all(b["cycles"] >= 4 for b in blocks)

        r = http.post("/api/models", json={"axis": "y", "datasets": [imported["id"]], "effects": ["hysteresis"]})
        base_id = _wait(http, r.json()["job_id"])["model_id"]
        d = http.get(f"/api/models/{base_id}/diagnosis").json()
        assert d["verdict"] == "missing_effect" and d["candidates"][0]["effect"] == "dynamics", d["candidates"][:3]
        r = http.post(f"/api/models/{base_id}/refine", json={"add": "dynamics"})
        new_id = _wait(http, r.json()["job_id"])["model_id"]
        history = http.get(f"/api/models/{new_id}/history").json()
        rms = [step["validation_rms_um"] for step in history["steps"]]
        assert len(rms) == 2 and rms[-1] < 0.5 * rms[0], rms
