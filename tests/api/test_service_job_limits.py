"""Bounded job queues (issue 15): bench jobs and compute jobs each wait in a queue of limited length;
one more submission is refused (QueueFull, HTTP 429 with Retry-After) and stores nothing."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from service.http.app import create_app
from service.runtime.jobs import JobManager, QueueFull
from service.runtime.settings import MAX_QUEUED_BENCH_JOBS, Settings
from tests.support.api_client import authed_client, job_running, wait_job

TINY_SWEEP = {"axes": ["y"], "frequencies_hz": [50.0], "cycles": 2, "settle_s": 0.0, "sample_rate_hz": 5000.0}


def test_each_queue_refuses_beyond_its_limit_and_stores_nothing(store):
    manager = JobManager(store, workers=1, max_queued_bench_jobs=2, max_queued_compute_jobs=1)
    bench_gate, compute_gate = threading.Event(), threading.Event()
    try:
        holder = manager.submit("sweep", None, lambda ctx: {"held": bench_gate.wait(10)}, needs_bench=True)
        wait_job(manager.get, holder["id"], until=job_running())
        queued = [manager.submit("sweep", {"k": k}, lambda ctx: {}, needs_bench=True)["id"] for k in range(2)]
        jobs_before = len(store.list_jobs(limit=None))
        with pytest.raises(QueueFull) as info:
            manager.submit("sweep", {"k": 2}, lambda ctx: {}, needs_bench=True)
        assert (info.value.queue, info.value.queued, info.value.limit) == ("bench", 2, 2)
        assert "2 bench jobs queued (limit 2)" in str(info.value)
        assert len(store.list_jobs(limit=None)) == jobs_before  # nothing stored for it

        # the compute queue is counted apart: one running, one queued, the next refused
        busy = manager.submit("identify", None, lambda ctx: {"held": compute_gate.wait(10)}, needs_bench=False)
        wait_job(manager.get, busy["id"], until=job_running())
        waiting = manager.submit("identify", None, lambda ctx: {}, needs_bench=False)
        with pytest.raises(QueueFull) as info:
            manager.submit("identify", None, lambda ctx: {}, needs_bench=False)
        assert (info.value.queue, info.value.queued, info.value.limit) == ("compute", 1, 1)

        # a cancelled queued job frees its place at once; drained queues take jobs again
        manager.cancel(queued[0])
        queued.append(manager.submit("sweep", {"k": 3}, lambda ctx: {}, needs_bench=True)["id"])
        bench_gate.set()
        compute_gate.set()
        assert [wait_job(manager.get, i)["state"] for i in queued[1:]] == ["succeeded", "succeeded"]
        assert wait_job(manager.get, waiting["id"])["state"] == "succeeded"
        again = [manager.submit("sweep", None, lambda ctx: {}, needs_bench=True)["id"] for _ in range(2)]
        assert [wait_job(manager.get, i)["state"] for i in again] == ["succeeded", "succeeded"]
    finally:
        bench_gate.set()
        compute_gate.set()
        manager.shutdown()


def test_concurrent_submissions_never_overfill_the_queue(store):
    manager = JobManager(store, max_queued_bench_jobs=16)
    gate = threading.Event()

    def submit(k: int) -> str:
        try:
            return manager.submit("sweep", {"k": k}, lambda ctx: {}, needs_bench=True)["state"]
        except QueueFull:
            return "refused"

    try:
        holder = manager.submit("sweep", None, lambda ctx: {"held": gate.wait(20)}, needs_bench=True)
        wait_job(manager.get, holder["id"], until=job_running())
        with ThreadPoolExecutor(8) as pool:  # 200 submissions from 8 threads at once
            states = list(pool.map(submit, range(200)))
        assert states.count("queued") == 16 and states.count("refused") == 184
        assert len(store.list_jobs(limit=None)) == 1 + 16
    finally:
        gate.set()
        manager.shutdown()


def test_a_full_bench_queue_answers_429_with_retry_after_and_accepts_again_once_drained(tmp_path):
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=1))) as http:
        jobs, store, gate = http.app.state.jobs, http.app.state.store, threading.Event()
        holder = jobs.submit("hold", None, lambda ctx: {"held": gate.wait(60)}, needs_bench=True)  # the bench is busy
        wait_job(jobs.get, holder["id"], until=job_running())
        try:
            accepted = []
            for _ in range(MAX_QUEUED_BENCH_JOBS):
                r = http.post("/api/sweeps", json=TINY_SWEEP)
                assert r.status_code == 202, r.text
                accepted.append(r.json()["job_id"])
            jobs_before, datasets_before = len(store.list_jobs(limit=None)), len(store.list_datasets())

            r = http.post("/api/sweeps", json=TINY_SWEEP)
            assert r.status_code == 429 and int(r.headers["Retry-After"]) > 0
            body = r.json()
            assert f"{MAX_QUEUED_BENCH_JOBS} bench jobs queued (limit {MAX_QUEUED_BENCH_JOBS})" in body["detail"]
            assert (body["queue"], body["queued"], body["limit"]) == ("bench", 16, 16)
            assert len(store.list_jobs(limit=None)) == jobs_before  # nothing stored ...
            assert len(store.list_datasets()) == datasets_before
            assert all(j["id"] in accepted + [holder["id"]] for j in http.get("/api/jobs").json())  # ... or listed
        finally:
            gate.set()
        for job_id in accepted:
            assert wait_job(http, job_id)["state"] == "succeeded"
        r = http.post("/api/sweeps", json=TINY_SWEEP)
        assert r.status_code == 202, r.text
        assert wait_job(http, r.json()["job_id"])["state"] == "succeeded"
