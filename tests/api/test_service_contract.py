"""Issue 16 §3–4: every operation documents its success response (/openapi.json), the one
recorder keeps a run stopped early as a partial dataset with its reason (sweep and trajectory,
on the emulated bench), and a refused trajectory or fault names its field as data."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.factory import open_bench
from service.http.app import create_app
from service.runtime.jobs import JobInterrupted
from service.runtime.settings import Settings
from service.science.control.safety import ControlRefused
from service.science.control.session import SAMPLE_RATE_HZ, Controller
from service.science.control.trajectory import RAMP_PERIODS, Ellipse
from service.science.errors import FieldError
from service.store import Store
from service.store.chunks import META_FILE, chunk_dir
from service.usecases.acquire import plan_sweep, run_sweep
from service.usecases.track import check_trajectory, run_trajectory
from tests.support.api_client import authed_client

FS = 20_000.0
PERIOD = 200  # samples per period at 100 Hz
SWEEP = {"axes": ["y"], "frequencies_hz": [1.0], "cycles": 10}  # about 10.6 s of plan


class _Ctx:
    """A job's context for a job body run directly: records progress, and reports a cancel once
    the job's progress reached ``cancel_at`` (None: never). ``chunks_on_disk`` notes, at each
    report, whether the recorder's crash-safe directory (meta.json) was there."""

    def __init__(self, store: Store, job_id: str, cancel_at: float | None = None):
        self.store, self.job_id, self.cancel_at = store, job_id, cancel_at
        self.fractions: list[float] = []
        self.chunks_on_disk: list[bool] = []

    def progress(self, fraction: float, message: str | None = None) -> None:
        self.fractions.append(fraction)
        self.chunks_on_disk.append((chunk_dir(self.store.data_dir, self.job_id) / META_FILE).is_file())

    @property
    def cancelled(self) -> bool:
        return self.cancel_at is not None and bool(self.fractions) and self.fractions[-1] >= self.cancel_at


@pytest.fixture
def bench():
    b = open_bench("default", seed=2)
    yield b
    b.close()


# ------------------------------------------------------------------ typed API
def test_every_operation_documents_a_response_schema_for_its_success_status():
    spec = create_app().openapi()
    schemas = spec["components"]["schemas"]
    operations, missing = 0, []
    for path, methods in spec["paths"].items():
        for method, op in methods.items():
            operations += 1
            success = min(code for code in op["responses"] if code.startswith("2"))
            content = op["responses"][success].get("content") or {}
            if not content:
                missing.append(f"{method.upper()} {path} {success}: no content")
            for media, body in content.items():
                schema = body.get("schema") or {}
                ref = schema.get("$ref") or (schema.get("items") or {}).get("$ref")
                named = schemas[ref.rsplit("/", 1)[1]].get("properties") if ref else None
                if not (named or schema.get("type") == "string"):
                    missing.append(f"{method.upper()} {path} {success} {media}: {schema}")
    assert operations >= 28 and missing == []
    # the identification's fields are named in the schemas clients read
    assert {"id", "kind", "state", "progress", "result", "error"} <= set(schemas["Job"]["properties"])
    assert {"residual_rms_um", "noise_floor_um", "verdict", "candidates", "failures"} <= set(
        schemas["Diagnosis"]["properties"]
    )
    assert {"effect", "score", "expected_rms_um", "evidence"} <= set(schemas["Candidate"]["properties"])
    assert {"id", "axes", "samples", "sample_rate_hz", "drive_range_v"} <= set(schemas["Dataset"]["properties"])
    downloads = spec["paths"]["/api/datasets/{dataset_id}/data"]["get"]["responses"]["200"]["content"]
    assert set(downloads) == {"application/json", "text/csv", "application/x-ndjson", "application/x-hdf5"}
    events = spec["paths"]["/api/jobs/{job_id}/events"]["get"]["responses"]["200"]["content"]
    assert set(events) == {"text/event-stream"}


# ------------------------------------------------------------------ the recorder
def test_a_sweep_stopped_on_request_is_kept_partial_with_its_reason(store, bench):
    planned, plan = plan_sweep(bench, dict(SWEEP))
    ctx = _Ctx(store, "job_sweep", cancel_at=0.25)
    with pytest.raises(JobInterrupted) as info:
        run_sweep(ctx, bench, store, planned, plan)
    row = store.get_dataset(info.value.result["dataset_id"])
    assert info.value.cancelled and row["partial"] is True and row["partial_reason"] == "stopped on request"
    assert info.value.reason == f"stopped on request: {row['samples']} samples kept as partial dataset {row['id']}"
    assert info.value.result == {"dataset_id": row["id"], "samples": row["samples"], "partial": True}
    # stopped at the block after the cancel: about a quarter of the plan, whole 2000-sample blocks
    assert 0.25 * planned.samples <= row["samples"] <= 0.25 * planned.samples / 0.98 + 2 * 2000
    assert row["samples"] < planned.samples and row["samples"] % 2000 == 0
    arrays = store.load_arrays(row["id"])
    assert len(arrays["t_s"]) == len(arrays["x_y_um"]) == row["samples"]
    assert arrays["t_s"][-1] == pytest.approx((row["samples"] - 1) / FS)
    np.testing.assert_array_equal(arrays["u_y_v"], planned.u_v["y"][: row["samples"]])  # what was commanded
    assert row["job_id"] == "job_sweep" and row["source"] == "sweep" and row["finished_at"] >= row["started_at"]
    assert all(ctx.chunks_on_disk[1:])  # crash-safe chunks while it ran …
    assert not chunk_dir(store.data_dir, "job_sweep").exists()  # … removed once the dataset is stored


def test_a_tripped_trajectory_is_kept_partial_with_its_reason(store, bench):
    bench.parts.world.faults.add("sensor_dropout", "z", 0.3)
    ellipse = Ellipse((1.0, 6.0), (1.0, 11.0), 0.0, 100.0, 60)
    ctx = _Ctx(store, "job_trip")
    with pytest.raises(JobInterrupted) as info:
        run_trajectory(ctx, bench, store, ellipse, Controller(), "point_by_point", {"cycles": 60}, None)
    result = info.value.result
    row = store.get_dataset(result["dataset_id"])
    assert not info.value.cancelled and result["tripped"] and not result["stopped"]  # a fault: the job fails
    assert row["partial"] is True and "gauge z: dropout" in row["partial_reason"]
    assert info.value.reason == (
        f"tripped: {row['partial_reason']}: {row['samples']} samples kept as partial dataset {row['id']}"
    )
    planned = (ellipse.cycles + 2 * RAMP_PERIODS) * PERIOD
    assert 0 < row["samples"] <= int(0.3 * FS) + PERIOD < planned
    assert row["sample_rate_hz"] == SAMPLE_RATE_HZ and row["source"] == "trajectory"
    assert set(store.load_arrays(row["id"])) == {"t_s", "u_y_v", "x_y_um", "ref_y_um", "u_z_v", "x_z_um", "ref_z_um"}
    assert not chunk_dir(store.data_dir, "job_trip").exists()


def test_a_trajectory_stopped_on_request_is_kept_partial_with_its_reason(store, bench):
    ellipse = Ellipse((1.0, 6.0), (1.0, 11.0), 0.0, 100.0, 60)
    ctx = _Ctx(store, "job_stop", cancel_at=10 / 66)  # after 10 of 66 periods
    with pytest.raises(JobInterrupted) as info:
        run_trajectory(ctx, bench, store, ellipse, Controller(), "point_by_point", {"cycles": 60}, None)
    row = store.get_dataset(info.value.result["dataset_id"])
    assert info.value.cancelled and info.value.result["stopped"] and not info.value.result["tripped"]
    assert row["partial"] is True and row["partial_reason"] == "stopped on request"
    assert info.value.reason == f"stopped on request: {row['samples']} samples kept as partial dataset {row['id']}"
    assert 10 * PERIOD <= row["samples"] <= 12 * PERIOD
    assert not chunk_dir(store.data_dir, "job_stop").exists()


# ------------------------------------------------------------------ fields as data
def test_refusals_carry_their_field_as_data(store, bench):
    pid = {"kp_y": 1.0, "ki_y": 0.0, "kd_y": 0.0, "kp_z": 1.0, "ki_z": 0.0, "kd_z": 0.0, "tf_s": 1e-4}
    controller = {
        "feedforward_model_y": None,
        "feedforward_model_z": None,
        "pid": None,
        "ilc": False,
        "ilc_gain": 0.2,
        "ilc_harmonics": 20,
        "allow_saturation": False,
    }
    cases = [
        (Ellipse((1, 6), (1, 11), 45.0, 100.0, 5), controller, "point_by_point", "inclination_deg"),
        (Ellipse((1, 6), (1, 11), 0.0, 333.0, 5), controller, "point_by_point", "frequency_hz"),
        (Ellipse((1, 6), (1, 11), 0.0, 100.0, 5), {**controller, "pid": pid}, "buffered", "controller.pid"),
        (
            Ellipse((1, 6), (1, 11), 0.0, 100.0, 5),
            {**controller, "feedforward_model_z": "md_none"},
            "point_by_point",
            "controller.feedforward_model_z",
        ),
    ]
    for ellipse, ctl, mode, field in cases:
        with pytest.raises(FieldError) as info:
            check_trajectory(bench, store, ellipse, ctl, mode)
        assert info.value.field == field and not info.value.message.startswith(field)
        assert str(info.value) == f"{field}: {info.value.message}"
    with pytest.raises(ControlRefused) as info:
        check_trajectory(bench, store, Ellipse((1, 6), (1, 11), 0.0, 100.0, 5), {**controller, "pid": pid}, "buffered")
    assert info.value.field == "controller.pid" and info.value.reason == info.value.message


def test_the_api_answers_a_refusal_with_its_field(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=1))
    with authed_client(app) as http:
        cases = [
            (
                "/api/trajectories",
                {"amplitude_y_um": 3, "amplitude_z_um": 4, "frequency_hz": 333},
                "frequency_hz",
                "333 Hz is not a whole number of samples at 20000 Hz",
            ),
            (
                "/api/trajectories",
                {"amplitude_y_um": 3, "amplitude_z_um": 4, "inclination_deg": 45},
                "inclination_deg",
                "45° leaves the semi-axes undetermined by the ranges",
            ),
            (
                "/api/admin/faults",
                {"fault": "sensor_dropout"},
                "axis",
                "sensor_dropout needs an axis, one of y, z; got None",
            ),
            ("/api/admin/faults", {"fault": "nope"}, "fault", "unknown fault 'nope'"),
        ]
        for route, body, field, words in cases:
            answer = http.post(route, json=body)
            assert answer.status_code == 422 and answer.json()["field"] == field, answer.text
            assert answer.json()["detail"].startswith(f"{field}: {words}")
        assert http.get("/api/jobs").json() == []  # nothing was queued
