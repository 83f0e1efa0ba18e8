"""The job manager: states, progress, one bench owner at a time (FIFO), others beside it,
cancellation, failures, SSE, and recovery after a restart. No bench or HTTP needed."""

from __future__ import annotations

import asyncio
import json
import logging
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from service.runtime import jobs as jobs_module
from service.runtime.jobs import SHUTDOWN_LEFT, JobInterrupted, JobManager
from service.runtime.recovery import recover
from service.security import auth
from service.store import utc_now
from tests.support.api_client import job_running, wait_job

ROOT = Path(__file__).resolve().parents[2]


def test_bench_jobs_run_one_at_a_time_in_order_and_others_beside(store):
    manager = JobManager(store)
    active, peak, order, lock = [0], [0], [], threading.Lock()
    bench_free = threading.Event()

    def bench_job(name):
        def run(ctx):
            with lock:
                active[0] += 1
                peak[0] = max(peak[0], active[0])
                order.append(name)
            for k in range(5):
                ctx.progress((k + 1) / 5, f"{name} {k}")
                time.sleep(0.01)
            bench_free.wait(5)
            with lock:
                active[0] -= 1
            return {"name": name}

        return run

    try:
        ids = [manager.submit("sweep", {"n": k}, bench_job(f"b{k}"), needs_bench=True)["id"] for k in range(3)]
        wait_job(manager.get, ids[0], until=job_running())  # the bench thread has taken the first job
        side = manager.submit("identify", None, lambda ctx: {"beside": manager.running_bench_job}, needs_bench=False)
        # the identification finishes while the first bench job still holds the bench
        assert wait_job(manager.get, side["id"])["result"] == {"beside": ids[0]}
        assert [manager.get(i)["state"] for i in ids] == ["running", "queued", "queued"]
        bench_free.set()
        jobs = [wait_job(manager.get, i) for i in ids]
    finally:
        manager.shutdown()
    assert [j["state"] for j in jobs] == ["succeeded"] * 3 and order == ["b0", "b1", "b2"] and peak[0] == 1
    assert jobs[0]["progress"] == 1.0 and jobs[0]["result"] == {"name": "b0"} and jobs[0]["finished_at"]


def test_cancel_queued_and_running_jobs(store):
    manager = JobManager(store)
    started, answered = threading.Event(), threading.Event()

    def cancellable(ctx):
        ctx.progress(0.5, "working")
        started.set()
        while not ctx.cancelled:
            time.sleep(0.005)
        answered.wait(5)  # the job ends once the cancel has answered (else, on a busy machine, before)
        raise JobInterrupted("stopped on request: 12 samples kept", {"dataset_id": "ds_partial"})

    try:
        running = manager.submit("sweep", None, cancellable, needs_bench=True)
        queued = manager.submit("sweep", None, lambda ctx: {"ran": True}, needs_bench=True)
        assert started.wait(5)
        assert manager.cancel(queued["id"])["state"] == "cancelled"  # at once
        assert manager.cancel(running["id"])["message"] == "cancel requested"
        answered.set()
        job = wait_job(manager.get, running["id"])
        assert (job["state"], job["result"], job["error"]) == ("cancelled", {"dataset_id": "ds_partial"}, None)
        assert "12 samples kept" in job["message"]
        time.sleep(0.05)
        assert manager.get(queued["id"])["started_at"] is None  # it never ran
        assert manager.cancel(job["id"])["state"] == "cancelled"  # cancelling again changes nothing
    finally:
        manager.shutdown()


def test_failures_are_recorded_and_the_worker_lives_on(store):
    manager = JobManager(store)

    def broken(ctx):
        raise ValueError("u_y spans −3–130 V")

    try:
        failed = manager.submit("sweep", None, broken, needs_bench=True)
        after = manager.submit("sweep", None, lambda ctx: {"ok": True}, needs_bench=True)
        assert wait_job(manager.get, failed["id"])["error"] == "u_y spans −3–130 V"
        assert wait_job(manager.get, after["id"])["state"] == "succeeded"
    finally:
        manager.shutdown()


def test_a_fault_of_the_service_is_said_as_one_and_its_traceback_logged(store):
    """A bug (not a refusal, not bad data) fails the job with its type and where the traceback is,
    not a bare "'NoneType' object has no attribute 'get'"; the log holds the traceback. (A handler
    on the jobs' logger itself: a service built by another test may stop its records propagating.)"""
    manager = JobManager(store)
    logged: list[logging.LogRecord] = []
    handler = logging.Handler(logging.ERROR)
    handler.emit = logged.append
    logger = logging.getLogger("evcbench.jobs")
    logger.addHandler(handler)

    def buggy(ctx):
        return None.get("x")

    try:
        failed = wait_job(manager.get, manager.submit("discover", None, buggy, needs_bench=False)["id"])
        assert failed["state"] == "failed"
        assert failed["error"].startswith("an internal error (AttributeError: 'NoneType' object has no attribute")
        assert "the service's log" in failed["error"]
        assert len(logged) == 1 and failed["id"] in logged[0].getMessage() and logged[0].exc_info[0] is AttributeError
    finally:
        logger.removeHandler(handler)
        manager.shutdown()


def test_sse_streams_progress_then_the_end(store):
    manager = JobManager(store)
    gate = threading.Event()
    carried = {k: threading.Event() for k in (1, 2, 3)}  # the stream has carried "step k"

    def job(ctx):
        gate.wait(5)
        for k in range(1, 4):
            ctx.progress(k / 4, f"step {k}")
            # the next step only once the stream showed this one: a busy machine cannot merge them
            if not carried[k].wait(30):
                raise RuntimeError(f"the stream never carried step {k}")
        return {"done": True}

    async def collect(job_id):
        events = []
        async for text in manager.events(job_id):
            events.append(text)
            if len(events) == 1:
                gate.set()
            for k, seen in carried.items():
                if f'"message": "step {k}"' in text:
                    seen.set()
        return events

    try:
        submitted = manager.submit("identify", None, job, needs_bench=False)
        events = asyncio.run(collect(submitted["id"]))
        assert events[-1].startswith("event: end\n") and '"state": "succeeded"' in events[-1]
        progress = [json.loads(e.split("data: ", 1)[1]) for e in events[:-1]]
        assert all(e.startswith("event: progress\n") for e in events[:-1])
        steps = [p["message"] for p in progress if p["message"].startswith("step")]
        assert [m for i, m in enumerate(steps) if i == 0 or steps[i - 1] != m] == ["step 1", "step 2", "step 3"]
        assert [p["progress"] for p in progress if p["message"] == "step 2"][0] == 0.5
        # subscribing after the end gives the end at once
        assert asyncio.run(collect(submitted["id"])) == [events[-1]]
    finally:
        manager.shutdown()


def test_sse_of_a_revoked_token_ends_with_an_error_while_the_job_goes_on(store, monkeypatch):
    monkeypatch.setattr(jobs_module, "SSE_RECHECK_S", 0.05)
    manager = JobManager(store)
    _, record = auth.issue(store, "watcher", "read", "cli")
    stop, checks = threading.Event(), []

    def long_job(ctx):
        k = 0
        while not stop.wait(0.01):
            k += 1
            ctx.progress(min(k / 10_000, 0.99), f"step {k}")
        return {"steps": k}

    def recheck():
        checks.append(threading.current_thread().name)
        return auth.still_valid(store, record)

    async def collect(job_id):
        events = []
        async for text in manager.events(job_id, recheck=recheck):
            events.append(text)
            if len(events) == 3:
                store.tokens.revoke(record["id"], utc_now())
        return events

    try:
        job_id = manager.submit("identify", None, long_job, needs_bench=False)["id"]
        events = asyncio.run(collect(job_id))
        assert events[-1].startswith("event: error\n")
        error = json.loads(events[-1].split("data: ", 1)[1])
        assert error["status"] == 401 and error["field"] == "authorization"
        assert error["detail"] == f"API token {record['id']} (watcher) has been revoked"
        assert all(e.startswith("event: progress\n") for e in events[:-1]) and len(events) >= 4
        assert manager.get(job_id)["state"] == "running"  # only the stream ended
        assert checks and threading.main_thread().name not in checks  # checked off the event loop's thread
    finally:
        stop.set()
        manager.shutdown()


def test_restart_marks_unfinished_jobs_failed_and_shutdown_cancels_queued(store):
    store.add_job("sweep", None, needs_bench=True)  # left "queued" by a process that died
    assert len(recover(store)["failed_jobs"]) == 1  # what the app runs at start-up, before the manager
    manager = JobManager(store)
    gate = threading.Event()
    try:
        assert manager.list()[0]["state"] == "failed"
        assert manager.list()[0]["error"] == "interrupted by restart"
        blocking = manager.submit("sweep", None, lambda ctx: {"gate": gate.wait(5)}, needs_bench=True)
        waiting = manager.submit("sweep", None, lambda ctx: {"ran": True}, needs_bench=True)
        threading.Timer(0.2, gate.set).start()
    finally:
        manager.shutdown()
    assert store.get_job(waiting["id"])["state"] == "cancelled"
    assert store.get_job(blocking["id"])["state"] in ("succeeded", "cancelled")
    with pytest.raises(RuntimeError, match="shutting down"):
        manager.submit("sweep", None, lambda ctx: {}, needs_bench=True)


def test_a_running_job_shows_its_result_so_far_and_the_bench_jobs_are_listed(store):
    """``ctx.progress(..., partial=...)`` (the discover job's steps so far) is the job's ``result``
    while it runs, and the final result replaces it; ``bench_jobs`` names what holds the bench."""
    manager = JobManager(store)
    reported, finish, bench_free = threading.Event(), threading.Event(), threading.Event()

    def stepping(ctx):
        ctx.progress(0.5, "step 0", partial={"steps": [{"step": 0, "validation_rms_um": 0.05}]})
        reported.set()
        finish.wait(5)
        return {"steps": [{"step": 0}, {"step": 1}]}

    try:
        assert manager.bench_jobs() == []
        holder = manager.submit("sweep", None, lambda ctx: {"held": bench_free.wait(5)}, needs_bench=True)["id"]
        job_id = manager.submit("discover", None, stepping, needs_bench=False)["id"]
        assert reported.wait(5)
        running = manager.get(job_id)
        assert running["state"] == "running" and running["message"] == "step 0"
        assert running["result"] == {"steps": [{"step": 0, "validation_rms_um": 0.05}]}
        assert manager.bench_jobs() == [holder]
        finish.set()
        bench_free.set()
        done = wait_job(manager.get, job_id)
        wait_job(manager.get, holder)
        assert done["result"] == {"steps": [{"step": 0}, {"step": 1}]} and manager.bench_jobs() == []
    finally:
        finish.set()
        bench_free.set()
        manager.shutdown()


def test_a_job_that_does_not_stop_is_ended_and_never_holds_the_process(store, tmp_path):
    """A fit sees its cancel only between steps (one can take minutes): shutdown waits for it at most
    its timeout, ends it in the store as cancelled (SHUTDOWN_LEFT), and ``serve``'s exit does not wait
    for its thread (a walk's service sat minutes in "Waiting for application shutdown", Ctrl-C ignored)."""
    release = threading.Event()
    manager = JobManager(store)
    try:
        stubborn = manager.submit("discover", None, lambda ctx: {"released": release.wait(60)}, needs_bench=False)
        wait_job(manager.get, stubborn["id"], until=job_running())
        left = manager.shutdown(timeout_s=0.3)
        assert left == [stubborn["id"]] and not release.is_set()  # returned while the job was still at work
        row = store.get_job(stubborn["id"])
        assert row["state"] == "cancelled" and row["message"] == SHUTDOWN_LEFT, row
        assert manager.job_threads_alive()
    finally:
        release.set()

    # the same in a process of its own, through serve's exit: it ends though its job never would
    program = tmp_path / "stubborn.py"
    program.write_text(
        "import threading, sys\n"
        "from service.frontends.cli import exit_if_work_is_left\n"
        "from service.runtime.jobs import JobManager\n"
        "from service.store import Store\n"
        f"store = Store('sqlite:///{tmp_path}/p.db', {str(tmp_path)!r})\n"
        "manager = JobManager(store)\n"
        "started = threading.Event()\n"
        "job = manager.submit('discover', None, lambda ctx: (started.set(), threading.Event().wait(3600)), needs_bench=False)\n"
        "started.wait(30)\n"
        "print(manager.shutdown(timeout_s=0.2) == [job['id']], flush=True)\n"
        "store.close()\n"
        "exit_if_work_is_left(manager)\n"
        "sys.exit(3)  # not reached: the exit above does not wait for the job\n"
    )
    done = subprocess.run([sys.executable, str(program)], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.strip() == "True", done.stderr[-2000:]
