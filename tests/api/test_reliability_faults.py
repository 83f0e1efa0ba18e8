"""Fault injection (issue 9 §3): each emulated fault, injected through POST /api/admin/faults or
the bench configuration's [faults] table, leads to the output at 0 V, the job failed with the reason
in words, and the samples so far stored as a dataset marked partial."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.factory import open_bench
from drivers.record import RunInterrupted
from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, wait_job

FS = 20_000.0
AFTER_S = 0.41
SWEEP = {"axes": ["y", "z"], "frequencies_hz": [5], "cycles": 10, "settle_s": 0.0}  # 2.0 s at 20 kHz
PLANNED_SAMPLES = int(2.0 * FS)


@pytest.fixture(params=["default"])
def app_client(request, tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench=request.param, seed=1))
    with authed_client(app) as http:
        yield app, http


@pytest.fixture
def wire_client(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default_wire", seed=1))
    with authed_client(app) as http:
        yield app, http


def _assert_zero_volts(app, via_driver: bool = True) -> None:
    """The last entry of the emulator's output log: 0 V DAQ volts at both amplifier inputs, amplifier
    outputs within 50 mV of 0 V (write_idle waits for < 10 mV, plus 2 mV noise). ``via_driver``: the
    amplifier driver reports the same (not when its serial link has failed: it then reads NaN)."""
    last = app.state.bench.parts.world.output_log.last()
    assert last["daq_ao_v"] == {"y": 0.0, "z": 0.0}, last
    assert max(abs(v) for v in last["amplifier_v"].values()) < 0.05, last
    if via_driver:
        assert max(abs(v) for v in app.state.bench.output_v().values()) < 0.05


def _inject_and_sweep(app, http, fault: str, axis: str | None) -> tuple[dict, dict, dict]:
    posted = http.post("/api/admin/faults", json={"fault": fault, "axis": axis, "after_s": AFTER_S})
    assert posted.status_code == 201, posted.text
    assert posted.json()["state"] == "armed"
    started = http.post("/api/sweeps", json=SWEEP)
    assert started.status_code == 202
    job = wait_job(http, started.json()["job_id"])
    listed = http.get("/api/admin/faults")
    assert listed.status_code == 200
    (fired,) = listed.json()["faults"]
    assert fired["state"] == "fired" and fired["fired_at_s"] == pytest.approx(AFTER_S, abs=1.0 / FS)
    ds = http.get(f"/api/datasets/{job['result']['dataset_id']}")
    assert ds.status_code == 200
    return job, ds.json(), http.get(f"/api/datasets/{job['result']['dataset_id']}/data").json()


def _assert_partial(ds: dict, data: dict, reason_part: str, min_s: float, max_s: float) -> None:
    assert ds["partial"] is True and reason_part in ds["partial_reason"]
    assert min_s * FS <= ds["samples"] <= max_s * FS < PLANNED_SAMPLES
    assert len(data["t_s"]) == len(data["x_z_um"]) == len(data["u_y_v"]) == ds["samples"]


# fault, axis, words in the reason, the partial dataset's length range (s): faults are checked after
# every 0.1 s block, so a fault at 0.41 s keeps the 0.5 s measured; a failed write keeps 0.4 s.
CASES = [
    ("sensor_dropout", "z", "sensor z: gauge z: dropout (injected at t=0.41 s)", 0.5, 0.5),
    ("sensor_saturation", "y", "sensor y: gauge y: saturated (injected at t=0.41 s)", 0.5, 0.5),
    ("amplifier_overcurrent", "y", "amplifier y: over-current", 0.5, 0.5),
    ("daq_underflow", None, "daq: AO buffer underflow at t=0.41 s (injected)", 0.4, 0.4),
    ("loop_stall", None, "watchdog: no sample written for", 0.4, 0.4),
]


@pytest.mark.parametrize("fault,axis,words,min_s,max_s", CASES, ids=[c[0] for c in CASES])
def test_each_fault_fails_the_job_keeps_partial_data_and_leaves_zero_volts(
    app_client, fault, axis, words, min_s, max_s
):
    app, http = app_client
    job, ds, data = _inject_and_sweep(app, http, fault, axis)
    assert job["state"] == "failed" and words in job["error"], job
    assert f"kept as partial dataset {ds['id']}" in job["error"]
    _assert_partial(ds, data, words, min_s, max_s)
    assert job["progress"] == pytest.approx(ds["samples"] / PLANNED_SAMPLES)  # 0.25 or 0.2: the share it kept
    _assert_zero_volts(app)
    if fault == "loop_stall":  # the watchdog tripped after its 1 s floor (4 × 0.1 s blocks < 1 s)
        trip = app.state.bench.watchdog.last_trip
        assert 1.0 <= trip["stalled_s"] < 2.0 and trip["timeout_s"] == 1.0
    cleared = http.delete("/api/admin/faults")
    assert cleared.status_code == 200 and cleared.json()["cleared"] == 1
    again = wait_job(http, http.post("/api/sweeps", json={**SWEEP, "cycles": 2}).json()["job_id"])
    assert again["state"] == "succeeded"  # cleared: the bench works again


@pytest.mark.parametrize(
    "fault,words",
    [
        ("serial_disconnect", "Input/output error"),
        ("serial_garbage", "garbled reply"),
        ("can_bus_off", "bus-off"),
    ],
    ids=["serial_disconnect", "serial_garbage", "can_bus_off"],
)
def test_transport_faults_act_on_the_wire(wire_client, fault, words):
    app, http = wire_client
    job, ds, data = _inject_and_sweep(app, http, fault, None)
    assert job["state"] == "failed" and words in job["error"], job
    _assert_partial(ds, data, words, 0.4, 0.5)
    _assert_zero_volts(app, via_driver=not fault.startswith("serial"))


def test_fault_requests_are_checked(app_client):
    app, http = app_client
    with authed_client(app, scope="operate") as operator:  # fault injection is for admins only
        refused = operator.post("/api/admin/faults", json={"fault": "loop_stall", "after_s": 1})
        assert refused.status_code == 403 and refused.json()["detail"]
    bad = http.post("/api/admin/faults", json={"fault": "meteor", "after_s": 1})
    assert bad.status_code == 422 and bad.json()["field"] == "fault" and "sensor_dropout" in bad.json()["detail"]
    no_axis = http.post("/api/admin/faults", json={"fault": "sensor_dropout"})
    assert no_axis.status_code == 422 and no_axis.json()["field"] == "axis"
    negative = http.post("/api/admin/faults", json={"fault": "loop_stall", "after_s": -1})
    assert negative.status_code == 422 and negative.json()["field"] == "after_s"
    wire_only = http.post("/api/admin/faults", json={"fault": "can_bus_off"})
    assert wire_only.status_code == 409 and "default_wire" in wire_only.json()["detail"]
    assert http.get("/api/admin/faults").json()["faults"] == []


def test_faults_from_the_bench_configuration(tmp_path):
    """[faults] in the configuration: the sensor drops out 0.25 s into the first run."""
    bench = open_bench("default", seed=1, overrides={"faults": {"sensor_dropout": {"axis": "y", "after_s": 0.25}}})
    try:
        t = np.arange(int(1.0 * FS)) / FS
        u = 60 - 60 * np.cos(2 * np.pi * 5 * t)
        with pytest.raises(RunInterrupted) as caught:
            bench.run({"y": u}, FS)
        assert "gauge y: dropout (injected at t=0.25 s)" in caught.value.reason and not caught.value.stopped
        assert caught.value.record.samples == int(0.3 * FS) and caught.value.record.partial
        assert bench.parts.world.faults.list()[0]["source"] == "config"
        assert bench.parts.world.output_log.last()["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    finally:
        bench.close()
    with pytest.raises(ValueError, match="faults.meteor: unknown fault"):
        open_bench("default", overrides={"faults": {"meteor": {"after_s": 1}}})


def test_output_log_file_records_the_applied_voltages(tmp_path: Path):
    log = tmp_path / "out.jsonl"
    bench = open_bench("default", seed=1, overrides={"emulator": {"output_log": str(log)}})
    bench.run({"y": np.full(4000, 30.0)}, FS)  # rate-limited ramp to 30 V, then 0 V
    bench.close()
    lines = log.read_text().splitlines()
    import json

    entries = [json.loads(line) for line in lines]
    assert entries[0]["event"] == "block" and entries[0]["daq_ao_v"]["y"] == pytest.approx(30.0 / 20.0, abs=1e-3)
    assert entries[-1]["event"] == "close" and entries[-1]["daq_ao_v"] == {"y": 0.0, "z": 0.0}
    assert abs(entries[-1]["amplifier_v"]["y"]) < 0.05


TRAJECTORY = {
    "y_range_um": [1, 6],
    "z_range_um": [1, 11],
    "frequency_hz": 100,
    "cycles": 60,
    "controller": {
        "pid": {"kp_y": 1.0, "ki_y": 300.0, "kd_y": 0.01, "kp_z": 1.0, "ki_z": 300.0, "kd_z": 0.01, "tf_s": 2e-4}
    },
}


@pytest.mark.parametrize(
    "fault,axis,words",
    [
        ("sensor_dropout", "y", "gauge y: dropout (injected at t=0.30 s)"),
        ("sensor_saturation", "z", "sensor at the end of its range or lost"),
        ("amplifier_overcurrent", "z", "amplifier z: over-current"),
        ("daq_underflow", None, "daq: AO buffer underflow at t=0.30 s"),
    ],
    ids=["sensor_dropout", "sensor_saturation", "amplifier_overcurrent", "daq_underflow"],
)
def test_faults_during_a_point_by_point_trajectory(app_client, fault, axis, words):
    app, http = app_client
    assert http.post("/api/admin/faults", json={"fault": fault, "axis": axis, "after_s": 0.3}).status_code == 201
    started = http.post("/api/trajectories", json=TRAJECTORY)
    assert started.status_code == 202
    job = wait_job(http, started.json()["job_id"])
    assert job["state"] == "failed" and job["error"].startswith("tripped: ") and words in job["error"], job
    ds = http.get(f"/api/datasets/{job['result']['dataset_id']}").json()
    # the run (after 50 ms of settling) reached the fault's period: 0.25 s of tracking, to one period more
    assert ds["partial"] is True and int(0.25 * FS) <= ds["samples"] <= int(0.25 * FS) + 200
    data = http.get(f"/api/datasets/{ds['id']}/data").json()
    assert len(data["x_y_um"]) == len(data["ref_z_um"]) == ds["samples"]
    _assert_zero_volts(app)
