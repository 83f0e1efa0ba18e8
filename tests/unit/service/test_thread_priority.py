"""Each kind of thread of the service sets its own scheduling priority (service.runtime.priority):
bulk downloads and imports below any program, job threads as any program even when a raised thread
(the stop's, cancelling a job) creates them, the emergency stop's thread above both (where the
kernel allows raising)."""

from __future__ import annotations

import os
import threading

from service.runtime.jobs import JobManager
from service.runtime.priority import BULK_NICE, SAFETY_NICE, WORK_NICE, set_thread_nice


def _own_nice() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def _in_thread(fn):
    out = {}
    thread = threading.Thread(target=lambda: out.setdefault("value", fn()))
    thread.start()
    thread.join(30)
    return out["value"]


def _may_raise() -> bool:
    return _in_thread(lambda: set_thread_nice(-1))


def test_bulk_threads_run_below_every_program():
    from service.runtime.bulk import _POOL

    assert _POOL.submit(_own_nice).result(30) == BULK_NICE


def test_the_stop_thread_runs_above_jobs_where_the_kernel_allows():
    from service.http.bench import _STOP_EXECUTOR

    expected = SAFETY_NICE if _may_raise() else _in_thread(_own_nice)
    assert _STOP_EXECUTOR.submit(_own_nice).result(30) == expected


def test_job_threads_made_by_a_raised_thread_run_as_any_program(store):
    def from_a_raised_thread():
        raised = set_thread_nice(SAFETY_NICE)
        jobs = JobManager(store)
        try:
            job_nice = jobs._pool.submit(_own_nice).result(30)
        finally:
            jobs.shutdown()
        return raised, _own_nice(), job_nice

    raised, creator_nice, job_nice = _in_thread(from_a_raised_thread)
    assert job_nice == WORK_NICE
    if raised:  # root or CAP_SYS_NICE: the job thread did not inherit its creator's −5
        assert creator_nice == SAFETY_NICE
