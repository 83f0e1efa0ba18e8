"""Benchmark: the service under load while a real-time trajectory job runs (issue 9 §6).

    evcbench bench service --json [--duration 60]

Starts ``evcbench serve`` in a subprocess on a fresh store and the emulated default bench with its
DAQ paced to real time (fixtures/benches/default_realtime.toml), imports a small dataset, runs a
short warm-up trajectory (it compiles the control loop), then starts a point-by-point ellipse
(100 Hz, FF-free PID) long enough to cover the whole measurement and fires ``rate_hz`` requests per
second for ``duration_s`` at the status and data endpoints, round-robin:

    GET /api/jobs/{job}, GET /api/bench, GET /api/datasets/{id}/data?max_points=1000 (as the dashboard
    asks for a chart), GET /api/datasets, GET /api/health

Requests leave on a fixed schedule (open loop: request k at t0 + k/rate_hz from a small thread
pool), so a slow answer does not lower the load. Reported:

- ``p50_ms``, ``p99_ms``, ``max_ms``: request latency (client side, ms);
- ``requests``, ``errors`` (non-2xx or transport failure), ``achieved_rate_hz`` (requests sent
  over the time it took to send them);
- ``job_overruns`` / ``job_periods``: blocks the paced DAQ received late during the job (more than
  one block after their slot: see drivers/emulated/pacing.py) / blocks paced (GET /api/bench
  ``timing``, before and after);
- ``job_state``, ``job_error``, ``job_rms_error_um`` of the trajectory.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np

from service.science.control.session import SCANNED_PID
from service.security.auth import read_bootstrap_token

ROOT = Path(__file__).resolve().parents[2]
BENCH = "default_realtime"
FREQUENCY_HZ = 100.0
#: PID without a feedforward model (service.science.control.session.SCANNED_PID): tracks the ellipse stably.
PID = {
    **{f"{gain}_{axis}": getattr(SCANNED_PID[axis], gain) for axis in SCANNED_PID for gain in ("kp", "ki", "kd")},
    "tf_s": SCANNED_PID["y"].tf_s,
}
ELLIPSE = {
    "shape": "ellipse",
    "amplitude_y_um": 5.0,
    "amplitude_z_um": 10.0,
    "frequency_hz": FREQUENCY_HZ,
    "mode": "point_by_point",
    "controller": {"pid": PID},
}


def run_service_benchmark(duration_s: float = 60.0, rate_hz: float = 50.0, headers: dict | None = None) -> dict:
    """Run the load for ``duration_s`` seconds at ``rate_hz`` requests/s; return the figures."""
    with tempfile.TemporaryDirectory(prefix="evcbench-load-") as data_dir:
        proc, url = spawn_service(Path(data_dir), BENCH, Path(data_dir) / "serve.log")
        try:
            if headers is None:  # the service's own bootstrap admin token (written at start-up, mode 0600)
                headers = {"Authorization": f"Bearer {read_bootstrap_token(data_dir)}"}
            with httpx.Client(base_url=url, headers=headers, timeout=30) as client:
                return _measure(client, duration_s, rate_hz)
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()


def spawn_service(
    data_dir: Path,
    bench: str,
    log: Path,
    timeout_s: float = 120.0,
    seed: int = 1,
    extra_env: dict[str, str] | None = None,
    own_group: bool = False,
) -> tuple[subprocess.Popen, str]:
    """``evcbench serve`` on a free loopback port; returns (process, base URL) once /api/health answers
    (RuntimeError with the log's tail if it exits or stays silent). Also tests/support/live_server.py's.
    The service sees no EVCBENCH_* variable of this process, only those of ``extra_env``.
    ``own_group``: in a process group of its own (with its bench engine), as a shell starts `make run`."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("EVCBENCH_")}
    env["OPENBLAS_NUM_THREADS"] = "1"
    env.update(extra_env or {})
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "service.frontends.cli",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--data-dir",
            str(data_dir),
            "--bench",
            bench,
            "--seed",
            str(seed),
        ],
        cwd=ROOT,
        env=env,
        stdout=log.open("ab"),
        stderr=subprocess.STDOUT,
        start_new_session=own_group,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout_s
    # one client for the whole wait: each httpx.get builds a client, and its TLS context loads the
    # system's CA bundle (20 ms of CPU here), every 0.2 s beside a service that is starting
    with httpx.Client(timeout=1) as poll:
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise RuntimeError(f"the service exited with {proc.returncode}:\n{log.read_text()[-2000:]}")
            try:
                if poll.get(f"{url}/api/health").status_code == 200:
                    return proc, url
            except httpx.TransportError:
                pass
            time.sleep(0.2)
    proc.kill()
    raise RuntimeError(f"the service did not answer within {timeout_s:g} s")


def _measure(client: httpx.Client, duration_s: float, rate_hz: float) -> dict:
    dataset_id = _import_dataset(client)
    warm = _start_trajectory(client, cycles=20)
    _wait(client, warm, ("succeeded", "failed", "cancelled"), timeout_s=300)
    before = client.get("/api/bench").json()["timing"]
    # long enough to outlast the load: the measurement starts once the job runs
    job_id = _start_trajectory(client, cycles=int(math.ceil((duration_s + 2.0) * FREQUENCY_HZ)))
    _wait(client, job_id, ("running",), timeout_s=60)
    paths = [
        f"/api/jobs/{job_id}",
        "/api/bench",
        f"/api/datasets/{dataset_id}/data?max_points=1000",
        "/api/datasets",
        "/api/health",
    ]
    latencies_ms, errors, span_s = _fire(client, paths, duration_s, rate_hz)
    job = _wait(client, job_id, ("succeeded", "failed", "cancelled"), timeout_s=duration_s + 120)
    after = client.get("/api/bench").json()["timing"]
    lat = np.asarray(latencies_ms)
    result = job.get("result") or {}
    return {
        "duration_s": duration_s,
        "target_rate_hz": rate_hz,
        "requests": len(latencies_ms),
        "achieved_rate_hz": round(len(latencies_ms) / span_s, 2),
        "errors": errors,
        "p50_ms": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
        "p99_ms": round(float(np.percentile(lat, 99)), 2) if lat.size else None,
        "max_ms": round(float(lat.max()), 2) if lat.size else None,
        "job_overruns": after.get("overruns", 0) - before.get("overruns", 0),
        "job_periods": after.get("periods", 0) - before.get("periods", 0),
        "realtime": after.get("realtime", False),
        "job_state": job["state"],
        "job_error": job["error"],
        "job_rms_error_um": result.get("rms_error_um"),
        "endpoints": paths,
        "bench": BENCH,
        "cpu_count": os.cpu_count(),
    }


def _fire(client: httpx.Client, paths: list[str], duration_s: float, rate_hz: float) -> tuple[list[float], int, float]:
    """Open-loop load: request k leaves at t0 + k/rate_hz; returns (latencies ms of the answered
    requests, errors, span s from the first request out to the last answer in)."""
    n = int(round(duration_s * rate_hz))
    latencies: list[float] = []
    errors = [0]
    lock = threading.Lock()

    def one(path: str) -> None:
        t = time.perf_counter()
        try:
            ok = client.get(path).status_code < 400
        except httpx.HTTPError:
            ok = False
        elapsed_ms = (time.perf_counter() - t) * 1e3
        with lock:
            if ok:
                latencies.append(elapsed_ms)
            else:
                errors[0] += 1

    t0 = time.monotonic()
    with ThreadPoolExecutor(max_workers=8, thread_name_prefix="load") as pool:
        for k in range(n):
            wait = t0 + k / rate_hz - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            pool.submit(one, paths[k % len(paths)])
    span_s = time.monotonic() - t0  # the pool has closed: every answer is in
    return latencies, errors[0], span_s


def _import_dataset(client: httpx.Client) -> str:
    """A 2 s, 2 kHz single-axis loop (4000 rows) for the data endpoint to serve."""
    t = np.arange(4000) / 2000.0
    u = 60 - 60 * np.cos(2 * np.pi * t)
    rows = "\n".join(f"{a:.6f},{b:.4f},{b * 0.05:.5f}" for a, b in zip(t, u))
    r = client.post(
        "/api/datasets",
        files={"file": ("load.csv", f"t,u,x\n{rows}\n", "text/csv")},
        data={"axis": "y", "name": "load benchmark"},
    )
    r.raise_for_status()
    return r.json()["id"]


def _start_trajectory(client: httpx.Client, cycles: int) -> str:
    r = client.post("/api/trajectories", json={**ELLIPSE, "cycles": cycles, "name": "load benchmark"})
    r.raise_for_status()
    return r.json()["job_id"]


def _wait(client: httpx.Client, job_id: str, states: tuple[str, ...], timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/api/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        if job["state"] in ("succeeded", "failed", "cancelled"):
            raise RuntimeError(f"job {job_id} ended {job['state']} ({job['error']}) before reaching {states}")
        time.sleep(0.05)
    raise RuntimeError(f"job {job_id} did not reach {states} within {timeout_s:g} s")
