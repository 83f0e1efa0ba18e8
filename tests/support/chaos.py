"""The chaos suite's pieces: the emulated output stage in a process of its own (as real hardware
holds its outputs when the host process dies), a bench configuration that drives it, and a
service on that bench with the clock readings the cases compare (``time.monotonic()``: the stage,
the service and the test share CLOCK_MONOTONIC)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import httpx

from drivers.emulated.output_stage import ZERO_V, OutputStageLink
from tests.support.live_server import ROOT, Server

#: the chaos bench's DAQ watchdog timeout (s; [safety] hardware_watchdog_s): shorter than the 1 s
#: SIGSTOP case, so that case shows the hardware zeroing the outputs while the engine is stopped
WATCHDOG_S = 0.5
SWEEP = {"axes": ["y", "z"], "frequencies_hz": [1.0], "cycles": 60, "sample_rate_hz": 20_000.0}
SHORT_SWEEP = {"axes": ["y"], "frequencies_hz": [5.0], "cycles": 2, "sample_rate_hz": 20_000.0}
TRAJECTORY = {
    "shape": "ellipse",
    "y_range_um": [1, 5],
    "z_range_um": [1, 9],
    "inclination_deg": 20,
    "frequency_hz": 100,
    "cycles": 6000,
    # a PID alone (no feed-forward model on a fresh store): it drives the stage
    "controller": {"pid": {"kp_y": 1, "ki_y": 300, "kd_y": 0.01, "kp_z": 1, "ki_z": 300, "kd_z": 0.01, "tf_s": 2e-4}},
}


class Stage:
    """``python -m drivers.emulated.output_stage`` as a process; ``state()`` reads what it holds."""

    def __init__(self, log: Path):
        self.log = log.open("ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.emulated.output_stage"],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
        )
        self.address = self.proc.stdout.readline().strip()
        self.link = OutputStageLink(self.address)

    def state(self) -> dict:
        for attempt in range(5):  # UDP on loopback under load: an answer may come late
            try:
                return self.link.call("state")
            except TimeoutError:
                if attempt == 4:
                    raise
        raise AssertionError("unreachable")

    def honour_watchdog(self, on: bool) -> None:
        """A DAQ with (True) or without (False) a watchdog timer, from now on."""
        assert self.link.call("honour", on=on)["honoured"] is on

    def held_v(self) -> float:
        """The largest output the stage holds now (V, actuator volts or DAQ volts)."""
        s = self.state()
        return max(abs(v) for v in s["amplifier_v"] + s["daq_ao_v"])

    def wait_zero(self, timeout_s: float) -> dict:
        """The state once every output is below ``ZERO_V`` (AssertionError after ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while True:
            s = self.state()
            if s["zero_since_monotonic_s"] is not None:
                return s
            assert time.monotonic() < deadline, f"the outputs still hold {s['amplifier_v']} V: {s}"
            time.sleep(0.005)

    def close(self) -> None:
        self.link.close()
        self.proc.kill()
        self.proc.wait(10)
        self.log.close()


def chaos_bench(directory: Path, stage: Stage) -> Path:
    """A bench TOML: the real-time default bench driving ``stage``, its watchdog at ``WATCHDOG_S``; the
    loop's own watchdog as configured (1 s: a process stopped whole does not trip it, drivers/watchdog.py)."""
    path = directory / "chaos_bench.toml"
    path.write_text(
        f'extends = "{ROOT / "fixtures" / "benches" / "default_realtime.toml"}"\nname = "chaos"\n'
        f'[emulator]\noutput_stage = "{stage.address}"\n'
        f"[safety]\nhardware_watchdog_s = {WATCHDOG_S}\n"
    )
    return path


def serve(data_dir: Path, log: Path, bench: Path) -> Server:
    return Server(data_dir, log, bench=str(bench), env={"EVCBENCH_BENCH_ID": "chaos"})


def engine_pid(http: httpx.Client) -> int:
    return http.get("/api/bench").json()["engine"]["pid"]


def wait_until(predicate, timeout_s: float, what: str, poll_s: float = 0.02):
    """``predicate()``'s first true value (AssertionError naming ``what`` after ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s:g} s"
        time.sleep(poll_s)


def health(http: httpx.Client) -> httpx.Response:
    return http.get("/api/health")


def wait_restarted(http: httpx.Client, old_pid: int, timeout_s: float = 120.0) -> dict:
    """The health once a fresh engine (not ``old_pid``) is attached with its fault latched."""

    def back():
        r = health(http)
        if r.status_code != 200 or not r.json().get("latched_fault"):
            return None
        return r.json() if engine_pid(http) != old_pid else None

    return wait_until(back, timeout_s, "a fresh engine with the fault latched")


def store_check(data_dir: Path) -> tuple[int, dict]:
    """``evcbench store check --json`` on a store whose service runs."""
    proc = subprocess.run(
        [sys.executable, "-m", "service.frontends.cli", "store", "check", "--data-dir", str(data_dir), "--json"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    return proc.returncode, json.loads(proc.stdout)


def serves_again(http: httpx.Client) -> dict:
    """Reset (200), then a short sweep that succeeds: the job."""
    from tests.support.api_client import wait_job

    r = http.post("/api/bench/reset")
    assert r.status_code == 200, r.text
    assert health(http).json()["latched_fault"] is None
    r = http.post("/api/sweeps", json=SHORT_SWEEP)
    assert r.status_code == 202, r.text
    job = wait_job(http, r.json()["job_id"], timeout_s=120)
    assert job["state"] == "succeeded", job
    return job


def log_problems(logs: list[Path]) -> list[str]:
    """Lines of the service logs that show an HTTP 500 or a traceback."""
    bad = []
    for log in logs:
        for line in log.read_text(errors="replace").splitlines():
            if "Traceback" in line or '" 500 ' in line or "Internal Server Error" in line:
                bad.append(f"{log.name}: {line}")
    return bad


__all__ = ["ZERO_V", "Stage", "chaos_bench", "serve", "engine_pid", "wait_until", "health", "wait_restarted"]
