"""Load (issue 9 §6): a live service keeps answering correctly while a real-time trajectory runs.

``evcbench serve`` on the emulated bench with its DAQ paced to real time runs the load benchmark's
point-by-point ellipse (100 Hz, PID, ``service.perf.service_load.ELLIPSE``) while eight clients send
REQUESTS requests round-robin to the status and data endpoints. Asserted: behaviour — every answer is
2xx and right (the job asked for, the bench running that job, the imported samples unchanged, the
dataset listed, the service healthy), the load overlapped the running job, and the job succeeds
untripped with a steady tracking error and every period recorded. Not asserted: latencies and late
blocks (overruns), which on a shared host are timing: ``evcbench bench service --json`` reports
them (docs/explanation/architecture.md, "What keeps the real-time loop on time under load").
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest

from service.perf.service_load import ELLIPSE, FREQUENCY_HZ
from service.science.control.trajectory import RAMP_PERIODS
from tests.support.api_client import job_running, wait_job
from tests.support.live_server import Server

pytestmark = [pytest.mark.realtime, pytest.mark.slow]

REQUESTS = 250  # the benchmark's 5 s at 50 requests/s
CYCLES = 300  # 3 s of 100 Hz ellipse, paced to real time
SAMPLE_RATE_HZ = 20_000.0


def _loop_csv() -> bytes:
    """A 2 s, 2 kHz single-axis loop (4000 rows) for the data endpoint to serve."""
    t = np.arange(4000) / 2000.0
    u = 60 - 60 * np.cos(2 * np.pi * t)
    rows = "\n".join(f"{a:.6f},{b:.4f},{b * 0.05:.5f}" for a, b in zip(t, u))
    return f"t,u,x\n{rows}\n".encode()


def test_answers_stay_right_and_the_job_succeeds_while_a_realtime_trajectory_runs(tmp_path):
    server = Server(tmp_path / "store", tmp_path / "serve.log", bench="default_realtime")
    try:
        with httpx.Client(base_url=server.url, headers=server.headers, timeout=60) as client:
            r = client.post(
                "/api/datasets",
                files={"file": ("load.csv", _loop_csv(), "text/csv")},
                data={"axis": "y", "name": "load"},
            )
            assert r.status_code == 201, r.text
            dataset_id = r.json()["id"]
            data_path = f"/api/datasets/{dataset_id}/data?max_points=1000"
            expected_data = client.get(data_path).json()
            assert len(expected_data["t_s"]) <= 1000 and expected_data["x_y_um"]

            r = client.post("/api/trajectories", json={**ELLIPSE, "cycles": CYCLES, "name": "under load"})
            assert r.status_code == 202, r.text
            job_id = r.json()["job_id"]
            wait_job(client, job_id, until=job_running(), timeout_s=120)

            checks = [
                (f"/api/jobs/{job_id}", lambda b: b["id"] == job_id and b["state"] in ("running", "succeeded")),
                ("/api/bench", lambda b: b["running_job_id"] in (job_id, None) and b["timing"]["realtime"] is True),
                (data_path, lambda b: b == expected_data),
                ("/api/datasets", lambda b: dataset_id in [d["id"] for d in b]),
                ("/api/health", lambda b: b["backend"] == "emulated:default_realtime"),
            ]

            def one(k: int) -> tuple[str, int, bool, str | None]:
                path, right = checks[k % len(checks)]
                answer = client.get(path)
                body = answer.json() if answer.status_code == 200 else None
                state = body.get("state") if isinstance(body, dict) and path.startswith("/api/jobs/") else None
                return path, answer.status_code, body is not None and right(body), state

            with ThreadPoolExecutor(max_workers=8) as pool:
                answers = list(pool.map(one, range(REQUESTS)))
            wrong = [(path, status) for path, status, right, _ in answers if not right]
            assert len(answers) == REQUESTS and wrong == [], wrong
            assert "running" in {state for *_, state in answers}  # the load met the running job

            job = wait_job(client, job_id, timeout_s=120)
            assert job["state"] == "succeeded" and job["error"] is None, job
            result = job["result"]
            assert result["tripped"] is None and len(result["error_per_period_um"]) == CYCLES
            # the PID alone tracks with a steady error (≈ 2.2 µm RMS, 44 %): every period as good as the others
            err = np.array(result["error_per_period_um"])
            assert np.all(np.isfinite(err)) and err[-1] < err[0] and err[20:].max() < 1.1 * err[20:].min(), err
            ds = client.get(f"/api/datasets/{result['dataset_id']}").json()
            periods = CYCLES + 2 * RAMP_PERIODS  # the ellipse and its ramps
            assert ds["partial"] is False and ds["samples"] == periods * SAMPLE_RATE_HZ / FREQUENCY_HZ
    finally:
        assert server.stop()
