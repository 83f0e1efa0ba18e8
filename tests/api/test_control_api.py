"""POST /api/trajectories end to end on the emulated bench: refusals name the field and the reason,
a buffered ILC job reports the error per period and stores the traces as a dataset."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client, job_ended, wait_job

BASE = {
    "shape": "ellipse",
    "y_range_um": [1, 5],
    "z_range_um": [1, 9],
    "inclination_deg": 20,
    "frequency_hz": 100,
    "cycles": 20,
}


@pytest.fixture(scope="module")
def http(tmp_path_factory):
    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("ctl"), bench="default", seed=4))
    with authed_client(app) as client:
        client.app_state = app.state
        yield client


def _wait(http, job_id, timeout_s=120.0):
    """The ended job and every message it showed on the way (read by the one poller, wait_job)."""
    seen = set()

    def ended(job):
        if job.get("message"):
            seen.add(job["message"])
        return job_ended(job)

    return wait_job(http, job_id, until=ended, timeout_s=timeout_s, poll_s=0.05), seen


def test_refusals_name_the_field_and_reason(http):
    r = http.post(
        "/api/trajectories", json={**BASE, "frequency_hz": 400, "controller": {"pid": {"kp_y": 1, "kp_z": 1}}}
    )
    assert r.status_code == 422 and r.json()["field"] == "frequency_hz"
    assert "150 Vpp at 400 Hz needs 339 mA; the amplifier's limit is 200 mA" in r.json()["detail"]  # the full 0–150 V
    r = http.post("/api/trajectories", json={**BASE, "mode": "buffered", "controller": {"pid": {"kp_y": 1, "kp_z": 1}}})
    assert r.status_code == 422 and r.json()["field"] == "controller.pid"
    assert "buffered" in r.json()["detail"]
    r = http.post("/api/trajectories", json={**BASE, "controller": {"feedforward_model_y": "md_nope"}})
    assert r.status_code == 422 and r.json()["field"] == "controller.feedforward_model_y"
    r = http.post("/api/trajectories", json={"shape": "ellipse", "z_range_um": [1, 9]})
    assert r.status_code == 422 and "y_range_um" in r.json()["detail"]
    daq = http.app_state.bench.parts.daq  # a USB DAQ: no point-by-point
    original = daq.capabilities
    daq.capabilities = dataclasses.replace(
        original, point_by_point=False, point_by_point_reason="USB X Series: buffered streaming only"
    )
    try:
        r = http.post("/api/trajectories", json={**BASE, "controller": {"ilc": True}})
        assert r.status_code == 422 and r.json()["field"] == "mode"
        assert "USB X Series: buffered streaming only" in r.json()["detail"]
    finally:
        daq.capabilities = original
    assert http.get("/api/jobs").json() == [] or all(j["kind"] != "trajectory" for j in http.get("/api/jobs").json())


@pytest.mark.slow
def test_buffered_ilc_job_reports_error_per_period_and_stores_traces(http):
    body = {
        "shape": "ellipse",
        "amplitude_y_um": 4,
        "amplitude_z_um": 8,
        "inclination_deg": 20,
        "frequency_hz": 100,
        "cycles": 25,
        "mode": "buffered",
        "controller": {"ilc": True},
    }
    r = http.post("/api/trajectories", json=body)
    assert r.status_code == 202, r.text
    job, _ = _wait(http, r.json()["job_id"])
    assert job["state"] == "succeeded", job
    res = job["result"]
    err = res["error_per_period_um"]
    # Without feedforward the ILC learns the whole hysteresis inverse through a 2-period latency: it
    # falls below 0.4 µm within 10-12 periods and may then swing (0.3-1.6 µm); convergence with
    # feedforward is asserted in test_control_loop.py. Here: it learns, and every period is reported.
    assert len(err) == 25 and min(err[:15]) < 0.15 * err[0] and all(np.isfinite(err))
    for key in ("max_error_y_um", "max_error_z_um", "rms_error_um", "relative_error_pct"):
        assert res[key] >= 0
    # progress messages ("period k/n: error … nm RMS") are sampled by the poller and a buffered run
    # can end between two polls, so the per-period figures above are what is asserted
    data = http.get(f"/api/datasets/{res['dataset_id']}/data").json()
    text = str(data.keys()) if isinstance(data, dict) else str(data)
    assert "ref_y_um" in text and "x_z_um" in text


@pytest.mark.slow
def test_point_by_point_pid_job(http):
    body = {
        **BASE,
        "cycles": 5,
        "controller": {
            "pid": {"kp_y": 1, "ki_y": 300, "kd_y": 0.01, "kp_z": 1, "ki_z": 300, "kd_z": 0.01, "tf_s": 2e-4}
        },
    }
    r = http.post("/api/trajectories", json=body)
    assert r.status_code == 202, r.text
    job, _ = _wait(http, r.json()["job_id"])
    assert job["state"] == "succeeded", job
    res = job["result"]
    assert res["mode"] == "point_by_point" and res["tripped"] is None
    assert len(res["error_per_period_um"]) == 5 and res["error_per_period_um"][-1] < res["error_per_period_um"][0]


@pytest.mark.slow
def test_composite_model_ids_as_feedforward_and_stroke_refusal(http):
    """A discovery composite model (hysteresis + delay + dynamics) stored by POST /api/models is usable
    as feedforward_model_y/z; a Z range beyond its stroke is refused with the reason."""
    r = http.post(
        "/api/sweeps", json={"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 3, "together": False}
    )
    assert r.status_code == 202, r.text
    job, _ = _wait(http, r.json()["job_id"])
    dataset_id = job["result"]["dataset_id"]
    ids = {}
    for ax in ("y", "z"):
        r = http.post(
            "/api/models", json={"axis": ax, "datasets": [dataset_id], "effects": ["hysteresis", "delay", "dynamics"]}
        )
        assert r.status_code == 202, r.text
        job, _ = _wait(http, r.json()["job_id"])
        assert job["state"] == "succeeded", job
        ids[ax] = job["result"]["model_id"]
    ff = {"feedforward_model_y": ids["y"], "feedforward_model_z": ids["z"]}
    r = http.post(
        "/api/trajectories",
        json={
            "shape": "ellipse",
            "y_range_um": [1, 6],
            "z_range_um": [1, 14],
            "frequency_hz": 100,
            "cycles": 5,
            "controller": ff,
        },
    )  # beyond 150 V
    assert r.status_code == 422 and r.json()["field"] == "z_range_um", r.text
    assert "the axis reaches" in r.json()["detail"] and "at 150 V" in r.json()["detail"]  # the stacks' rating
    # PID "auto" on the composite's plant (its identified mode); issue 6's scanned gains (kp 1, ki 300,
    # kd 0.01) are borderline there: the 1–100 Hz sweeps may identify Y's mode as very lightly damped
    # (ζ ≈ 0.005 at ≈513 Hz seen once), and then they are refused as predicted unstable
    r = http.post("/api/trajectories", json={**BASE, "cycles": 10, "controller": ff})
    ff_only, _ = _wait(http, r.json()["job_id"])
    r = http.post("/api/trajectories", json={**BASE, "cycles": 10, "controller": {**ff, "pid": "auto"}})
    assert r.status_code == 202, r.text
    job, _ = _wait(http, r.json()["job_id"])
    assert job["state"] == "succeeded", job
    # measured: FF alone 10.9 %, FF + auto 9.4 % (a 60° / 6 dB loop leaves little gain at 100 Hz; the
    # scanned gains reached < 6.2 % on margins the targets refuse)
    assert job["result"]["tripped"] is None
    assert job["result"]["relative_error_pct"] < ff_only["result"]["relative_error_pct"]
    assert all(a["margins"]["stable"] for a in job["result"]["pid"]["axes"].values())


@pytest.mark.slow
def test_the_paper_dynamic_pi_feedforward_runs_solved_period_by_period(http):
    """The paper's dynamic PI, fitted on 1/10/50/100 Hz, has a per-sample inverse that misses the
    100 Hz ellipse (1.5 and 2.2 µm RMS on Y and Z); its drive is solved period by period instead
    (0.11 and 0.33 µm) and the run goes ahead. Measured (FF alone, 5 periods): 15.6 % against the
    static PI's 9.0 %: the dynamic PI's rate terms, fitted on sines, extrapolate to the ellipse less
    well on this bench, whose 290.7 Hz mode neither model draws."""
    r = http.post(
        "/api/sweeps", json={"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 3, "together": False}
    )
    dataset_id = _wait(http, r.json()["job_id"])[0]["result"]["dataset_id"]
    ids = {}
    for kind in ("dynamic_pi", "static_pi"):
        for axis in ("y", "z"):
            r = http.post("/api/models", json={"axis": axis, "datasets": [dataset_id], "model": kind})
            ids[kind, axis] = _wait(http, r.json()["job_id"])[0]["result"]["model_id"]
    errors = {}
    for kind in ("dynamic_pi", "static_pi"):
        r = http.post(
            "/api/trajectories",
            json={
                **BASE,
                "cycles": 5,
                "controller": {"feedforward_model_y": ids[kind, "y"], "feedforward_model_z": ids[kind, "z"]},
            },
        )
        assert r.status_code == 202, r.text
        job = _wait(http, r.json()["job_id"])[0]
        assert job["state"] == "succeeded" and job["result"]["tripped"] is None, job
        errors[kind] = job["result"]["relative_error_pct"]
    assert errors["dynamic_pi"] < 2 * errors["static_pi"], errors
    # the other axis's model is refused naming the field and the axis it belongs to (a new user
    # swapped them: accepted silently, 71 % error)
    r = http.post(
        "/api/trajectories",
        json={
            **BASE,
            "cycles": 5,
            "controller": {"feedforward_model_y": ids["static_pi", "z"], "feedforward_model_z": ids["static_pi", "y"]},
        },
    )
    assert r.status_code == 422 and r.json()["field"] == "controller.feedforward_model_y", r.text
    assert "identified on the Z axis" in r.json()["detail"]
