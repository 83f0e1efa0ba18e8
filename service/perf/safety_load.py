"""Benchmark: the emergency stop and a real-time sweep while others load the service.

    evcbench bench safety --json      (the ``under_load`` part)

A real ``evcbench serve`` (default_realtime bench, the engine in its own process) runs sweeps
while four clients download full-resolution datasets (streamed CSV) and one imports a ~50 MB CSV,
over and over. Meanwhile the emergency stop is pressed at random moments of a running sweep.
Figures, side by side in one run:

* ``stop``: request → 0 V at the actuator (the engine's 0 V write, ``time.monotonic`` seconds
  being one clock for every process of the machine) and request → answer, p50/p99/max in ms,
  with the same figures for the service idle; ``engine_zero_ms`` is the part inside the engine
  (the stop's receipt there → the 0 V write). ``stop_*`` is pressed on the engine's stop port, as
  the dashboard, the CLI and the Python client press it; ``stop_*_service_route`` on
  ``POST /api/bench/stop`` of the service's port, through the web process (presses alternate);
* ``sweep``: one 1/10/50/100 Hz sweep run to its end under the load: its state, watchdog trips and
  the emulated DAQ's real-time overruns;
* ``rss_mb``: peak resident memory of the web process and of the engine process.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np

from service.frontends.client import Client
from service.perf.service_load import spawn_service
from service.runtime.stop_port import STOP_PATH
from service.security.auth import read_bootstrap_token

SWEEP = {"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 5}
LONG_SWEEP = {"axes": ["y", "z"], "frequencies_hz": [1], "cycles": 30}
#: the stop is pressed this long (s, uniform) after the long sweep starts running
PRESS_WINDOW_S = (0.3, 1.8)
DOWNLOADERS = 4


def _wait(client: httpx.Client, job_id: str, states: tuple[str, ...], timeout_s: float = 300, driving=False) -> dict:
    """The job once its state is one of ``states`` (polled every 50 ms); ``driving``: a "running" job
    only once its progress is above 0, so the engine runs its plan. A job is "running" while the
    service still plans and hands the sweep over; on a loaded machine a stop pressed then found no
    plan at the engine to name (``cancelled_job_id`` None) and was counted as not landed, although
    the outputs were at 0 V."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/api/jobs/{job_id}").json()
        if job["state"] in states and not (driving and job["state"] == "running" and job["progress"] <= 0):
            return job
        time.sleep(0.05)
    raise TimeoutError(f"job {job_id} not {states} within {timeout_s} s")


def write_import_csv(path: Path, megabytes: float) -> Path:
    """A two-axis CSV (t,u_y,x_y,u_z,x_z) of about ``megabytes`` MB: a 5 Hz sine sampled at 20 kHz."""
    rows = int(megabytes * 1e6 / 60)
    t = np.arange(rows) / 20000.0
    u = 60 - 60 * np.cos(2 * np.pi * 5 * t)
    table = np.column_stack([t, u, u * 0.05, u, u * 0.077])
    np.savetxt(path, table, delimiter=",", fmt="%.9g", header="t,u_y,x_y,u_z,x_z", comments="")
    return path


def _start_load(url: str, token: str, dataset_id: str, csv_path: Path) -> list[subprocess.Popen]:
    """The four downloaders and the importer, each a process of its own like a real client (so this
    process, which presses the stop and times it, shares no interpreter lock with them); returns
    once the first downloaded bytes flow, so the stops are pressed under load."""
    env = {**os.environ, "EVCBENCH_TOKEN": token}
    cmd = [sys.executable, "-m", "service.perf.load_client"]
    procs = [
        subprocess.Popen([*cmd, "download", url, dataset_id], stdout=subprocess.PIPE, text=True, env=env)
        for _ in range(DOWNLOADERS)
    ]
    procs.append(subprocess.Popen([*cmd, "upload", url, str(csv_path)], stdout=subprocess.PIPE, text=True, env=env))
    procs[0].stdout.readline()  # "flowing" (or "" if the client died: its counts will say so)
    return procs


def _stop_load(procs: list[subprocess.Popen]) -> dict:
    """SIGTERM every client; sum the counts each prints as its last line."""
    for p in procs:
        p.terminate()
    counts = {"downloads": 0, "download_bytes": 0, "imports": 0, "import_status": set()}
    for p in procs:
        out, _ = p.communicate(timeout=300)
        lines = [line for line in out.splitlines() if line.startswith("{")]
        if not lines:
            raise RuntimeError(f"load client {p.args[3:]} ended with {p.returncode} and no counts")
        for key, value in json.loads(lines[-1]).items():
            counts[key] = counts[key] | set(value) if key == "import_status" else counts[key] + value
    return counts


def _press(
    client: httpx.Client, rng: random.Random, press: Callable[[], dict], window_s: tuple[float, float] = PRESS_WINDOW_S
) -> dict:
    """Start a long sweep, press the stop (``press``: through one door) at a random moment of it
    (``window_s``: seconds after it runs, uniform), return the figures."""
    job = client.post("/api/sweeps", json=LONG_SWEEP).json()
    _wait(client, job["job_id"], ("running", "succeeded", "failed", "cancelled"), driving=True)
    time.sleep(window_s[0] + (window_s[1] - window_s[0]) * rng.random())
    t_send = time.monotonic()
    answer = press()
    t_answer = time.monotonic()
    done = _wait(client, job["job_id"], ("succeeded", "failed", "cancelled"))
    zero = answer.get("zero_monotonic_s")
    return {
        "answer_ms": (t_answer - t_send) * 1e3,
        "zero_ms": (zero - t_send) * 1e3 if zero is not None else float("inf"),
        "engine_ms": float("inf") if answer.get("zero_after_request_ms") is None else answer["zero_after_request_ms"],
        "output_v_max": max(abs(v) for v in answer["output_v"].values()),
        "door": answer.get("door"),
        "job_state": done["state"],
        "cancelled": answer["cancelled_job_id"] == job["job_id"],
    }


def _stats(values: list[float]) -> dict:
    a = np.asarray(values, dtype=float)
    return {
        "p50": round(float(np.percentile(a, 50)), 2),
        "p99": round(float(np.percentile(a, 99)), 2),
        "max": round(float(a.max()), 2),
        "n": int(a.size),
    }


def _summary(presses: list[dict]) -> dict:
    landed = [p["output_v_max"] < 0.05 and p["cancelled"] and p["job_state"] == "cancelled" for p in presses]
    return {
        "zero_ms": _stats([p["zero_ms"] for p in presses]),
        "answer_ms": _stats([p["answer_ms"] for p in presses]),
        "engine_zero_ms": _stats([p["engine_ms"] for p in presses]),
        "doors": sorted({p["door"] for p in presses}),
        "every_stop_landed": all(landed),
        "not_landed": [p for p, ok in zip(presses, landed) if not ok],
    }


def peak_rss_mb(pid: int) -> float:
    """VmHWM of a process (MB): its peak resident set so far."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def run_safety_under_load(
    presses: int = 10,
    import_mb: float = 50.0,
    seed: int = 0,
    sweep: dict | None = None,
    press_window_s: tuple[float, float] = PRESS_WINDOW_S,
) -> dict:
    """The figures above, from one service started for this run (see the module docstring).
    ``sweep``: the body of the sweep that seeds the downloads and runs under load (default ``SWEEP``);
    ``press_window_s``: when the stop is pressed in each long sweep (s after it runs)."""
    sweep = SWEEP if sweep is None else sweep
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="evc-safety-") as tmp:
        tmp = Path(tmp)
        proc, url = spawn_service(tmp / "data", "default_realtime", tmp / "service.log")
        try:
            token = read_bootstrap_token(tmp / "data")
            headers = {"Authorization": f"Bearer {token}"}
            with (
                httpx.Client(base_url=url, headers=headers, timeout=600) as client,
                Client(url, token=token, data_dir=tmp / "data") as user,
            ):
                engine = client.get("/api/bench").json()["engine"]
                # the stop port as the CLI and scripts press it (Client.stop_bench: the port it reads
                # from <data dir>/stop_port.json, ?bench_id=, the fallback), and the service's route
                assert user.prepare_stop() is not None, "the service announced no stop port"
                doors = {"stop_port": user.stop_bench, "service_route": lambda: client.post(STOP_PATH).json()}
                seeded = client.post("/api/sweeps", json=sweep).json()
                dataset_id = _wait(client, seeded["job_id"], ("succeeded",))["result"]["dataset_id"]
                idle = {
                    door: [_press(client, rng, press, press_window_s) for _ in range(max(3, presses // 3))]
                    for door, press in doors.items()
                }
                csv_path = write_import_csv(tmp / "load.csv", import_mb)
                load = _start_load(url, token, dataset_id, csv_path)
                try:
                    time.sleep(2.0)
                    loaded = {door: [] for door in doors}
                    for _ in range(presses):  # the two doors alternate: the same load for both
                        for door, press in doors.items():
                            loaded[door].append(_press(client, rng, press, press_window_s))
                    before = client.get("/api/bench").json()
                    job = client.post("/api/sweeps", json=sweep).json()
                    swept = _wait(client, job["job_id"], ("succeeded", "failed", "cancelled"))
                    after = client.get("/api/bench").json()
                finally:
                    counts = _stop_load(load)
                trip = after["safety"].get("watchdog_last_trip")
                return {
                    "stop_idle": _summary(idle["stop_port"]),
                    "stop_under_load": _summary(loaded["stop_port"]),
                    "stop_idle_service_route": _summary(idle["service_route"]),
                    "stop_under_load_service_route": _summary(loaded["service_route"]),
                    "sweep_under_load": {
                        "state": swept["state"],
                        "error": swept["error"],
                        "watchdog_trips": int(trip is not None and trip != before["safety"].get("watchdog_last_trip")),
                        "overruns": after["timing"].get("overruns", 0) - before["timing"].get("overruns", 0),
                        "periods": after["timing"].get("periods", 0) - before["timing"].get("periods", 0),
                    },
                    "load": {
                        "downloaders": DOWNLOADERS,
                        "downloads_completed": counts["downloads"],
                        "download_mb": round(counts["download_bytes"] / 1e6, 1),
                        "import_mb": round(csv_path.stat().st_size / 1e6, 1),
                        "imports_completed": counts["imports"],
                        "import_status": sorted(counts["import_status"]),
                    },
                    "rss_mb": {"web": round(peak_rss_mb(proc.pid), 1), "engine": round(peak_rss_mb(engine["pid"]), 1)},
                }
        finally:
            proc.terminate()
            proc.wait(60)
