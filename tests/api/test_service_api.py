"""The REST API end to end (in-process, httpx via TestClient) on the emulated bench: sweeps,
datasets, identification, compare, jobs, cancel, bad input, and persistence across restarts."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import h5py
import numpy as np
import pytest

from service.frontends.client import ApiError, Client
from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, job_running, wait_job
from tests.support.realdata import MODEL_VI_DO as REAL

SHORT = {"axes": ["y"], "frequencies_hz": [10, 50, 100], "cycles": 3}
LONG = {"axes": ["y"], "frequencies_hz": [0.5], "cycles": 100, "name": "long"}  # 200 s of plan


def _service(data_dir: Path):
    app = create_app(Settings(data_dir=data_dir, bench="default", seed=1))
    http = authed_client(app)
    return app, http, Client(http=http)


@pytest.fixture
def service(tmp_path):
    app, http, api = _service(tmp_path)
    with http:
        yield app, api


def test_sweep_identify_and_compare(service):
    app, api = service
    events = []
    job = api.sweep(**SHORT, on_progress=events.append)
    assert job["state"] == "succeeded" and job["kind"] == "sweep"
    assert events[-1]["state"] == "succeeded" and any(e["state"] == "running" for e in events)
    progress = [e["progress"] for e in events]
    assert progress == sorted(progress) and progress[-1] == 1.0
    dataset_id = job["result"]["dataset_id"]

    ds = api.dataset(dataset_id)
    assert ds["axes"] == ["y", "z"] and ds["sample_rate_hz"] == 20000.0 and not ds["partial"]
    assert [b["frequency_hz"] for b in ds["blocks"]] == [10.0, 50.0, 100.0]
    assert ds["config"]["parameters"] == app.state.bench.parts.config  # the full bench configuration
    assert ds["config"]["backend"] == "emulated:default"
    assert ds["plan"]["frequencies_hz"] == [10.0, 50.0, 100.0] and ds["plan"]["cycles"] == 3
    assert ds["units"]["x_y_um"] == "µm" and ds["software_version"] and ds["created_at"].endswith("Z")
    data = api.dataset_arrays(dataset_id)  # every sample (NDJSON, streamed)
    assert len(data["x_y_um"]) == ds["samples"] == len(data["t_s"])
    u = np.array(data["u_y_v"])
    assert u.max() == pytest.approx(120.0, abs=0.01) and u[0] == 0.0 and u[-1] == 0.0

    model = api.identify("y", [dataset_id], model="static_pi", n_operators=10, name="Y static PI, 10 ops")
    assert model["kind"] == "static_pi" and model["effects"] == ["hysteresis"] and model["parent_id"] is None
    assert model["name"] == "Y static PI, 10 ops"  # labelled as it is identified, as sweeps are
    # the loops it was trained on (each block's training cycles, 0-120 V), for trajectories to check against
    assert np.allclose(model["metrics"]["trained_loops_v"], [[0.0, 120.0]] * 3, atol=0.05)
    assert len(model["parameters"]["weights_um_per_v"]) == 10
    m = model["metrics"]
    assert 0 < m["train_rms_um"] < 0.5 and 0 < m["validation_rms_um"] < 0.5
    blocks = m["per_dataset"][0]["blocks"]
    assert [b["frequency_hz"] for b in blocks] == [10.0, 50.0, 100.0]
    assert m["validation_rms_um"] == pytest.approx(np.mean([b["validation"]["rms_um"] for b in blocks]))
    assert all(b["validation"]["samples"] == 20000 / b["frequency_hz"] for b in blocks)  # one held-out cycle

    cmp = api.compare(model["id"], dataset_id, max_points=ds["samples"])  # every sample
    x, x_hat, e = (np.array(cmp[k]) for k in ("x_measured_um", "x_predicted_um", "residual_um"))
    assert len(x) == ds["samples"] and cmp["stride"] == 1 and cmp["used_in_fit"]
    np.testing.assert_allclose(e, x - x_hat, atol=1e-12)
    overall = cmp["metrics"]["overall"]
    assert overall["fit_pct"] > 90 and overall["max_abs_um"] >= overall["rms_um"] > 0
    assert cmp["metrics"]["validation_rms_um"] == pytest.approx(m["validation_rms_um"])
    assert len(api.compare(model["id"], dataset_id, max_points=1000)["t_s"]) <= 1000
    default = api.compare(model["id"], dataset_id)  # decimated as a JSON download: ≤ 10 000 points per array
    assert default["stride"] == -(-ds["samples"] // 10_000) and len(default["t_s"]) <= 10_000
    assert default["x_measured_um"] == cmp["x_measured_um"][:: default["stride"]]
    assert default["metrics"] == cmp["metrics"]  # metrics always over every sample

    # a dataset the model never saw: every block row is unseen
    other = api.sweep(axes=["y"], frequencies_hz=[20], cycles=2)["result"]["dataset_id"]
    unseen = api.compare(model["id"], other, arrays=False)
    assert not unseen["used_in_fit"] and unseen["metrics"]["train_rms_um"] is None
    assert unseen["metrics"]["validation_rms_um"] < 0.5 and "x_measured_um" not in unseen


def test_rate_dependent_models_and_the_models_list(service):
    _, api = service
    dataset_id = api.sweep(**SHORT)["result"]["dataset_id"]
    static = api.identify("y", [dataset_id], model="static_pi")
    dynamic = api.identify("y", [dataset_id], model="dynamic_pi")
    assert dynamic["kind"] == "dynamic_pi" and len(dynamic["parameters"]["alpha_um_per_v2_s"]) == 4
    assert dynamic["metrics"]["train_rms_um"] <= static["metrics"]["train_rms_um"] * 1.001
    assert [m["id"] for m in api.models()] == [static["id"], dynamic["id"]]


def _snapshot(api: Client, data_dir: Path) -> dict:
    files = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (data_dir / "arrays").glob("*")}
    return {"datasets": [api.dataset(d["id"]) for d in api.datasets()], "models": api.models(), "files": files}


def _csv(rows=20, bad=None):
    lines = ["t,u_y,x_y"] + [
        f"{k / 1000},{60 - 50 * np.cos(2 * np.pi * k / 100):.4f},{k * 0.01:.4f}" for k in range(rows)
    ]
    if bad:
        lines[bad[0]] = bad[1]
    return ("\n".join(lines) + "\n").encode()


BAD_REQUESTS = [
    (("post", "/api/datasets", {"files": {"file": ("bad.csv", _csv(bad=(4, "0.003,1,2,3")))}}), 422, "file"),
    (("post", "/api/datasets", {"files": {"file": ("nan.csv", _csv(bad=(4, "0.003,nan,1")))}}), 422, "u_y"),
    (
        ("post", "/api/datasets", {"files": {"file": ("slow.csv", _csv())}, "data": {"sample_rate_hz": "1e-300"}}),
        422,
        "sample_rate_hz",
    ),
    (("post", "/api/datasets", {"files": {"file": ("empty.csv", b"")}}), 422, "file"),
    (("post", "/api/datasets", {"data": {"axis": "y"}}), 422, "file"),
    (("post", "/api/datasets", {"files": {"file": ("a.dat", _csv()[10:])}, "data": {"columns": "[1"}}), 422, "columns"),
    (("post", "/api/sweeps", {"json": {**SHORT, "v_max": 151}}), 422, "v_max"),  # beyond the 150 V rating
    (("post", "/api/sweeps", {"json": {**SHORT, "v_min": -5}}), 422, "v_min"),
    (("post", "/api/sweeps", {"json": {**SHORT, "waveform": "square"}}), 422, "waveform"),
    (("post", "/api/sweeps", {"json": {**SHORT, "frequencies_hz": [10, 400]}}), 422, "frequencies_hz"),
    (("post", "/api/sweeps", {"json": {**SHORT, "sample_rate_hz": 30000}}), 422, "sample_rate_hz"),
    (("post", "/api/sweeps", {"json": {**SHORT, "sample_rate_hz": 1000}}), 422, "sample_rate_hz"),
    (("post", "/api/sweeps", {"json": {**SHORT, "sample_rate_hz": 1_000_000}}), 422, "sample_rate_hz"),
    (("post", "/api/sweeps", {"json": {**SHORT, "frequencies_hz": [0.001], "cycles": 100}}), 422, "cycles"),
    (("post", "/api/sweeps", {"json": {**SHORT, "axes": ["x"]}}), 422, "axes.0"),
    (("post", "/api/sweeps", {"json": {**SHORT, "cycles": 0}}), 422, "cycles"),
    (
        ("post", "/api/sweeps", {"content": b'{"v_max": NaN}', "headers": {"content-type": "application/json"}}),
        422,
        "v_max",
    ),
    (("post", "/api/models", {"json": {"axis": "y", "datasets": ["ds_nope"]}}), 422, "datasets"),
    (("post", "/api/models", {"json": {"axis": "y", "datasets": ["@DS"], "effects": ["creep"]}}), 422, "effects"),
    (("post", "/api/models", {"json": {"axis": "y", "datasets": ["@DS"], "model": "preisach"}}), 422, "model"),
    (("post", "/api/models", {"json": {"axis": "z", "datasets": ["@DS"]}}), 422, "datasets"),
    (("get", "/api/datasets/ds_nope", {}), 404, "dataset"),
    (("get", "/api/models/md_nope", {}), 404, "model"),
    (("get", "/api/models/@MD/compare?dataset=ds_nope", {}), 404, "dataset"),
    (("get", "/api/models/@MD/compare", {}), 422, "dataset"),
    (("get", "/api/jobs/job_nope", {}), 404, "job"),
]


@pytest.fixture(scope="module")
def stocked(tmp_path_factory):
    """A service holding one imported dataset and one model, shared by the bad-input cases."""
    data_dir = tmp_path_factory.mktemp("stocked")
    _, http, api = _service(data_dir)
    with http:
        dataset_id = api.import_dataset(_csv(rows=400), filename="ok.csv")["id"]
        model_id = api.identify("y", [dataset_id], n_operators=4)["id"]
        yield http, api, data_dir, {"@DS": dataset_id, "@MD": model_id}


def _fill(value, ids: dict):
    if isinstance(value, str):
        for key, real in ids.items():
            value = value.replace(key, real)
        return value
    if isinstance(value, dict):
        return {k: _fill(v, ids) for k, v in value.items()}
    if isinstance(value, list):
        return [_fill(v, ids) for v in value]
    return value


@pytest.mark.xdist_group("service_api_stocked")  # one worker builds the module's `stocked` service
@pytest.mark.parametrize("request_, status, field", BAD_REQUESTS)
def test_bad_input_names_the_field_and_changes_nothing(stocked, request_, status, field):
    http, api, data_dir, ids = stocked
    before = _snapshot(api, data_dir)
    method, url, kwargs = _fill(list(request_), ids)
    response = http.request(method.upper(), url, **kwargs)
    assert response.status_code == status, response.text
    body = response.json()
    assert body["field"] == field and isinstance(body["detail"], str) and len(body["detail"]) > 10
    assert _snapshot(api, data_dir) == before
    assert not list((data_dir / "arrays").glob(".*.tmp"))


def test_cancelled_sweep_keeps_partial_data_and_leaves_zero_volts(service):
    app, api = service
    first = api.start_sweep(**LONG)
    second = api.start_sweep(**SHORT)
    wait_job(api.job, first["job_id"], until=job_running(0.02))
    assert api.job(second["job_id"])["state"] == "queued"  # one owner of the bench at a time
    assert api.bench()["running_job_id"] == first["job_id"]

    cancelled = api.cancel(second["job_id"])  # queued: cancelled at once, never started
    assert cancelled["state"] == "cancelled" and cancelled["started_at"] is None
    asked = api.http.delete(f"/api/jobs/{first['job_id']}")
    assert asked.status_code == 202  # accepted: the sweep stops at its next block
    job = wait_job(api.job, first["job_id"])
    assert job["state"] == "cancelled" and job["error"] is None
    again = api.http.delete(f"/api/jobs/{first['job_id']}")  # already over: nothing to accept
    assert again.status_code == 200 and again.json()["state"] == "cancelled"
    assert again.json()["finished_at"] == job["finished_at"]
    assert all(abs(v) < 0.05 for v in app.state.bench.output_v().values())

    ds = api.dataset(job["result"]["dataset_id"])
    assert ds["partial"] and "stopped on request" in ds["partial_reason"]
    assert 0 < ds["samples"] < first["samples"] and ds["name"] == "long"
    assert ds["blocks"][0]["complete"] is False and ds["blocks"][0]["stop"] == ds["samples"]
    assert len(api.dataset_arrays(ds["id"])["x_y_um"]) == ds["samples"]
    assert api.job(second["job_id"])["state"] == "cancelled"


def test_emergency_stop_cancels_the_bench_job(service):
    app, api = service
    started = api.start_sweep(**LONG)
    wait_job(api.job, started["job_id"], until=job_running(0.01))
    answer = api.stop_bench()
    assert answer["cancelled_job_id"] == started["job_id"]
    job = wait_job(api.job, started["job_id"])
    assert job["state"] == "cancelled" and api.dataset(job["result"]["dataset_id"])["partial"]
    assert all(abs(v) < 0.05 for v in app.state.bench.output_v().values())
    assert api.sweep(**SHORT)["state"] == "succeeded"  # the bench works again afterwards


def test_a_device_fault_fails_the_sweep_but_keeps_its_samples(service):
    app, api = service
    started = api.start_sweep(**LONG)
    wait_job(api.job, started["job_id"], until=job_running(0.01))
    app.state.bench.parts.world.inject_fault("sensor_dropout", "y")
    try:
        job = wait_job(api.job, started["job_id"])
    finally:
        app.state.bench.parts.world.clear_faults()
    assert job["state"] == "failed" and "sensor y" in job["error"]
    ds = api.dataset(job["result"]["dataset_id"])
    assert ds["partial"] and "sensor y" in ds["partial_reason"] and 0 < ds["samples"] < started["samples"]
    assert all(abs(v) < 0.05 for v in app.state.bench.output_v().values())


def test_reset_clears_a_latched_amplifier_fault_so_the_bench_runs_again(service):
    app, api = service
    app.state.bench.parts.world.inject_fault("amplifier_overcurrent", "z")  # latches, output to 0 V
    job = api.sweep(axes=["z"], frequencies_hz=[50], cycles=3)
    assert job["state"] == "failed" and "amplifier z: over-current" in job["error"]
    assert api.sweep(axes=["z"], frequencies_hz=[50], cycles=3)["state"] == "failed"  # latched until reset
    out = api.reset_bench()
    assert len(out["cleared"]) == 1 and out["cleared"][0].startswith("amplifier z: over-current")
    assert out["remaining"] is None and all(abs(v) < 0.05 for v in out["output_v"].values())
    assert api.sweep(axes=["z"], frequencies_hz=[50], cycles=3)["state"] == "succeeded"
    assert api.reset_bench()["cleared"] == []


def test_reset_is_refused_while_a_job_owns_the_bench(service):
    app, api = service
    started = api.start_sweep(**LONG)
    wait_job(api.job, started["job_id"], until=job_running(0.01))
    with pytest.raises(ApiError) as exc:
        api.reset_bench()
    assert exc.value.status_code == 409 and started["job_id"] in exc.value.detail
    api.stop_bench()


def test_one_cycle_sweep_cannot_train_and_says_so(service):
    _, api = service
    dataset_id = api.sweep(axes=["y"], frequencies_hz=[50], cycles=1)["result"]["dataset_id"]
    with pytest.raises(ApiError) as info:
        api.start_identify("y", [dataset_id])
    assert info.value.status_code == 422 and info.value.field == "datasets" and "2 cycles" in info.value.detail
    with pytest.raises(ApiError) as info:
        api.start_identify("z", [dataset_id])  # z was measured but not driven
    assert info.value.field == "datasets" and "drives axis z" in info.value.detail
    assert api.models() == []


def test_identification_runs_beside_a_bench_job(service):
    _, api = service
    dataset_id = api.sweep(**SHORT)["result"]["dataset_id"]
    sweep = api.start_sweep(**LONG)
    wait_job(api.job, sweep["job_id"], until=job_running(0.01))
    model = api.identify("y", [dataset_id])
    assert api.job(sweep["job_id"])["state"] == "running"  # the identification did not wait for it
    assert model["metrics"]["validation_rms_um"] > 0
    api.cancel(sweep["job_id"])
    assert wait_job(api.job, sweep["job_id"])["state"] == "cancelled"


def test_real_data_imports_identifies_and_exports(service):
    _, api = service
    ds = api.import_dataset(REAL, columns={"u": 0, "x": 4}, axis="y", sample_rate_hz=200, delimiter="whitespace")
    assert (ds["axes"], ds["samples"], ds["sample_rate_hz"]) == (["y"], 8027, 200.0)
    assert ds["blocks"][0]["kind"] == "imported" and ds["blocks"][0]["frequency_hz"] == pytest.approx(1.0, rel=1e-3)
    model = api.identify("y", [ds["id"]], model="static_pi")
    assert model["metrics"]["per_dataset"][0]["blocks"][0]["validation"]["samples"] == 8 * 200  # 8 of 40 cycles
    assert model["metrics"]["validation_rms_um"] < 1.0  # on a 50 µm stroke
    csv = api.dataset_data(ds["id"], format="csv")
    assert csv.splitlines()[0] == "t,u_y,x_y" and len(csv.splitlines()) == 8028
    again = api.import_dataset(csv.encode(), filename="again.csv")
    np.testing.assert_allclose(api.dataset_data(again["id"])["x_y_um"], np.loadtxt(REAL)[:, 4], rtol=1e-9)
    with h5py.File(io.BytesIO(api.dataset_data(ds["id"], format="hdf5")), "r") as handle:
        np.testing.assert_array_equal(handle["u_y_v"][()], np.loadtxt(REAL)[:, 0])
        assert handle.attrs["sha256"] == ds["sha256"]


def test_a_gauge_reading_against_the_drive_is_fitted_like_the_upright_file(service):
    """Another lab's gauge may read against the drive (mounted on the far side, negative scale):
    every model fits sign·x and predicts sign·(…), so the held-out error is the upright file's."""
    _, api = service
    flipped_ds = api.import_dataset(
        REAL, columns={"u": 0, "x": {"column": 4, "scale": -1}}, axis="y", sample_rate_hz=200, delimiter="whitespace"
    )
    upright_ds = api.import_dataset(
        REAL, columns={"u": 0, "x": 4}, axis="y", sample_rate_hz=200, delimiter="whitespace"
    )
    for model in ("static_pi", "dynamic_pi", "grpi", "composite"):
        flipped = api.identify("y", [flipped_ds["id"]], model=model)
        upright = api.identify("y", [upright_ds["id"]], model=model)
        assert flipped["metrics"]["validation_rms_um"] == pytest.approx(
            upright["metrics"]["validation_rms_um"], rel=1e-6
        ), model
        assert flipped["parameters"]["sign"] == -1.0 and upright["parameters"]["sign"] == 1.0
    below = {"u": {"column": 0, "offset": -4.0}, "x": 4}  # measured data is not a command (issue 17 §6)
    shifted = api.import_dataset(REAL, columns=below, axis="y", sample_rate_hz=200, delimiter="whitespace")
    drive = np.loadtxt(REAL)[:, 0] - 4.0
    assert shifted["drive_range_v"]["y"] == pytest.approx([drive.min(), drive.max()]) and drive.min() < 0


def test_datasets_and_models_survive_a_restart_unchanged(tmp_path):
    _, http, api = _service(tmp_path)
    with http:
        dataset_id = api.sweep(**SHORT)["result"]["dataset_id"]
        model = api.identify("y", [dataset_id], model="dynamic_pi")
        before = _snapshot(api, tmp_path)
        compare_before = api.compare(model["id"], dataset_id, arrays=False)
        jobs_before = api.jobs()
    _, http, api = _service(tmp_path)
    with http:
        assert _snapshot(api, tmp_path) == before
        assert api.compare(model["id"], dataset_id, arrays=False) == compare_before
        assert api.jobs() == jobs_before
        row = api.dataset(dataset_id)
        assert hashlib.sha256((tmp_path / row["file"]).read_bytes()).hexdigest() == row["sha256"]


def test_openapi_documents_the_service(service):
    _, api = service
    spec = api.http.get("/openapi.json").json()
    for path in (
        "/api/jobs/{job_id}/events",
        "/api/sweeps",
        "/api/datasets/{dataset_id}/data",
        "/api/models/{model_id}/compare",
        "/api/bench/stop",
    ):
        assert path in spec["paths"]
    assert api.http.get("/docs").status_code == 200
    with pytest.raises(ApiError) as info:
        api.job("job_missing")
    assert info.value.status_code == 404 and info.value.field == "job"
