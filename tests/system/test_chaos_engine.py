"""Chaos (issue 42): the bench engine, the web process or both are killed or stopped, with the emulated
output stage in a process of its own, so that, as on real hardware, a dead engine leaves a voltage
held. Each case shows the outputs at 0 V, the job ended with its reason and its samples kept, the
store consistent, and the bench serving again after a reset; no log line shows a 500 or a traceback.

Deadlines: the supervisor alone (the stage's watchdog off) must have 0 V within ``SUPERVISOR_ZERO_S``
of a kill; the stage's watchdog within its timeout (it expires at its deadline, the last pet sent +
the timeout) plus ``WATCHDOG_SLACK_S``, for a pet the engine may stamp between the test's clock
reading and the signal. The figures themselves come from ``evcbench bench safety``."""

from __future__ import annotations

import os
import signal
import threading
import time

import httpx
import pytest

from tests.support.api_client import job_ended, job_running, wait_job
from tests.support.chaos import (
    SWEEP,
    TRAJECTORY,
    WATCHDOG_S,
    Stage,
    chaos_bench,
    engine_pid,
    health,
    log_problems,
    serve,
    serves_again,
    store_check,
    wait_restarted,
    wait_until,
)
from tests.support.live_server import evcbench

pytestmark = [pytest.mark.realtime, pytest.mark.slow, pytest.mark.xdist_group("chaos")]

#: 0 V after an engine's death, by the supervisor alone (s): the issue asks 0.5 s; twice that on a
#: loaded 2-core machine
SUPERVISOR_ZERO_S = 1.0
WATCHDOG_SLACK_S = 0.02


@pytest.fixture(scope="module")
def chaos(tmp_path_factory):
    """(stage, service, client, data dir, logs): one service on the chaos bench for the engine cases."""
    root = tmp_path_factory.mktemp("chaos")
    stage = Stage(root / "stage.log")
    bench = chaos_bench(root, stage)
    data_dir, log = root / "store", root / "serve.log"
    server = serve(data_dir, log, bench)
    http = httpx.Client(base_url=server.url, headers=server.headers, timeout=60)
    try:
        yield stage, server, http, data_dir, [log]
    finally:
        http.close()
        if server.proc.poll() is None:
            server.stop()
        stage.close()


def _start(http: httpx.Client, path: str, body: dict, stage: Stage) -> str:
    """Start a job and wait until it drives the outputs (the stage holds more than 1 V)."""
    r = http.post(path, json=body)
    assert r.status_code == 202, r.text
    job_id = r.json()["job_id"]
    wait_job(http, job_id, until=job_running(), timeout_s=120)
    wait_until(lambda: stage.held_v() > 1.0, 30, "the run drives the outputs")
    time.sleep(1.5)  # a few chunks of samples on disk
    return job_id


def _kill_engine(http: httpx.Client, sig: int = signal.SIGKILL) -> tuple[int, float]:
    pid = engine_pid(http)
    at = time.monotonic()
    os.kill(pid, sig)
    return pid, at


def _degraded(http: httpx.Client) -> dict:
    """/api/health is 503 degraded, a bench route 503 naming the engine, a new bench job refused."""
    r = wait_until(lambda: (h := health(http)).status_code == 503 and h, 10, "health says degraded")
    body = r.json()
    assert body["status"] == "degraded" and body["reason"], body
    bench = http.get("/api/bench")
    if bench.status_code == 503:  # a fast restart may already be back
        assert "engine" in bench.json()["detail"] and bench.json()["engine"] in ("restarting", "absent")
    sweep = http.post("/api/sweeps", json=SWEEP)
    assert sweep.status_code in (503, 409), sweep.text  # 409: already back, with the fault latched
    return body


def _ended_with(http: httpx.Client, job_id: str, words: str) -> dict:
    """The job failed naming ``words``, its samples kept as a partial dataset with the reason."""
    job = wait_job(http, job_id, until=job_ended, timeout_s=60)
    assert job["state"] == "failed" and words in job["error"], job
    dataset = http.get(f"/api/datasets/{job['result']['dataset_id']}").json()
    assert dataset["partial"] is True and words in dataset["partial_reason"] and dataset["samples"] > 20_000
    assert job["progress"] == pytest.approx(dataset["samples"] / job["params"]["samples"])  # the share it kept
    return job


def _clean(chaos) -> None:
    stage, server, http, data_dir, logs = chaos
    code, report = store_check(data_dir)
    assert code == 0, report
    assert log_problems(logs) == []


def _after_restart(chaos, old_pid: int, words: str) -> None:
    stage, server, http, data_dir, logs = chaos
    latched = wait_restarted(http, old_pid)["latched_fault"]
    assert latched.startswith("engine restarted: ") and words in latched and "outputs set to 0 V at" in latched
    assert http.post("/api/sweeps", json=SWEEP).status_code == 409  # latched: refused until the reset
    serves_again(http)
    _clean(chaos)


def test_sigkill_while_idle(chaos):
    stage, server, http, data_dir, logs = chaos
    stage.honour_watchdog(False)
    pid, _ = _kill_engine(http)
    assert "SIGKILL" in _degraded(http)["reason"]
    stop = http.post("/api/bench/stop")  # the emergency stop without an engine: what it could do
    assert stop.status_code == 200 and (stop.json()["engine_note"] or stop.json()["output_v"]), stop.text
    cli = evcbench(server, "stop")  # its stop port refuses (the engine is gone): the service's route
    assert cli.returncode == 0 and "stopped on the " in cli.stdout, cli.stdout + cli.stderr
    assert stage.held_v() < 0.01
    _after_restart(chaos, pid, "SIGKILL")


@pytest.mark.parametrize("kind", ["sweep", "trajectory"])
def test_sigkill_mid_run_zeroes_by_the_supervisor(chaos, kind):
    stage, server, http, data_dir, logs = chaos
    stage.honour_watchdog(False)  # the supervisor alone
    path, body = ("/api/sweeps", SWEEP) if kind == "sweep" else ("/api/trajectories", TRAJECTORY)
    job_id = _start(http, path, body, stage)
    pid, killed_at = _kill_engine(http)
    time.sleep(0.05)
    zero = stage.wait_zero(SUPERVISOR_ZERO_S + 1.0)
    assert zero["zero_since_monotonic_s"] - killed_at < SUPERVISOR_ZERO_S, zero
    assert any("written by the supervisor" in e[1] for e in zero["events"]), zero["events"]
    _degraded(http)
    job = wait_job(http, job_id, until=job_ended, timeout_s=60)
    assert job["state"] == "failed" and "SIGKILL" in job["error"], job
    dataset = http.get(f"/api/datasets/{job['result']['dataset_id']}").json()
    assert dataset["partial"] is True and "SIGKILL" in dataset["partial_reason"]
    planned = job["params"].get("samples")  # a sweep's plan; a trajectory's progress counts periods
    assert kind == "trajectory" or job["progress"] == pytest.approx(dataset["samples"] / planned), job
    _after_restart(chaos, pid, "SIGKILL")


def test_sigkill_during_a_stop(chaos):
    stage, server, http, data_dir, logs = chaos
    stage.honour_watchdog(False)
    job_id = _start(http, "/api/sweeps", SWEEP, stage)
    answers: list[httpx.Response] = []
    presser = threading.Thread(target=lambda: answers.append(http.post("/api/bench/stop")))
    presser.start()
    pid, killed_at = _kill_engine(http)
    presser.join(60)
    assert answers and answers[0].status_code == 200, answers
    stage.wait_zero(SUPERVISOR_ZERO_S + 1.0)
    job = wait_job(http, job_id, until=job_ended, timeout_s=60)
    assert job["state"] in ("cancelled", "failed") and job["result"]["partial"] is True, job
    _after_restart(chaos, pid, "SIGKILL")


def test_sigstop_1s_the_hardware_watchdog_zeroes_and_the_engine_lives_on(chaos):
    stage, server, http, data_dir, logs = chaos
    stage.honour_watchdog(True)
    job_id = _start(http, "/api/sweeps", SWEEP, stage)
    pid, stopped_at = _kill_engine(http, signal.SIGSTOP)
    try:
        zero = stage.wait_zero(WATCHDOG_S + 1.0)  # nobody writes: the engine is stopped
        assert zero["zero_since_monotonic_s"] - stopped_at < WATCHDOG_S + WATCHDOG_SLACK_S, zero
        assert zero["watchdog"]["expired"] and "by itself" in zero["watchdog"]["expired"]
        time.sleep(max(0.0, 1.0 - (time.monotonic() - stopped_at)))
    finally:
        os.kill(pid, signal.SIGCONT)
    _ended_with(http, job_id, "DAQ watchdog expired")  # the device's expiry: the loop's own did not trip
    assert engine_pid(http) == pid and health(http).status_code == 200  # 1 s is below the hang limit
    serves_again(http)
    _clean(chaos)


def test_sigstop_10s_the_supervisor_kills_the_hung_engine(chaos):
    stage, server, http, data_dir, logs = chaos
    stage.honour_watchdog(True)
    job_id = _start(http, "/api/sweeps", SWEEP, stage)
    pid, stopped_at = _kill_engine(http, signal.SIGSTOP)
    zero = stage.wait_zero(WATCHDOG_S + 1.0)
    assert zero["zero_since_monotonic_s"] - stopped_at < WATCHDOG_S + WATCHDOG_SLACK_S, zero
    body = _degraded(http)  # the supervisor calls it hung (2 s without a heartbeat) before 10 s pass
    assert "hung" in body["reason"] and time.monotonic() - stopped_at < 10.0, body
    _ended_with(http, job_id, "hung")
    _after_restart(chaos, pid, "hung")


def test_sigkill_the_web_process_then_both(tmp_path):
    """The web process killed mid-sweep: its engine writes 0 V and exits. Then both killed mid-sweep:
    only the stage's watchdog can zero the outputs. Each restart recovers the job as partial."""
    stage = Stage(tmp_path / "stage.log")
    bench = chaos_bench(tmp_path, stage)
    data_dir, logs = tmp_path / "store", []
    try:
        for case, honour in (("web", False), ("both", True)):
            logs.append(tmp_path / f"serve-{case}.log")
            server = serve(data_dir, logs[-1], bench)
            stage.honour_watchdog(honour)
            with httpx.Client(base_url=server.url, headers=server.headers, timeout=60) as http:
                job_id = _start(http, "/api/sweeps", SWEEP, stage)
                pid = engine_pid(http)
            killed_at = time.monotonic()
            server.proc.kill()
            if case == "both":
                os.kill(pid, signal.SIGKILL)
            server.proc.wait(30)
            zero = stage.wait_zero(5.0)
            limit_s = WATCHDOG_S + WATCHDOG_SLACK_S if case == "both" else 5.0
            assert zero["zero_since_monotonic_s"] - killed_at < limit_s, zero
            if case == "both":
                assert zero["watchdog"]["expired"], zero
            wait_until(lambda pid=pid: not os.path.exists(f"/proc/{pid}"), 30, "the engine exits")
            logs.append(tmp_path / f"serve-{case}-after.log")
            server = serve(data_dir, logs[-1], bench)
            with httpx.Client(base_url=server.url, headers=server.headers, timeout=60) as http:
                job = wait_job(http, job_id, until=job_ended, timeout_s=30)
                assert job["state"] == "failed" and job["error"] == "interrupted by restart", job
                assert job["result"]["partial"] is True
                assert health(http).json()["status"] == "ok"
                serves_again(http)
                code, report = store_check(data_dir)
                assert code == 0, report
            assert server.stop()
        assert log_problems(logs) == []
    finally:
        stage.close()
