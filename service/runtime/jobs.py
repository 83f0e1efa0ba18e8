"""Jobs: long work off the event loop, with progress, cancellation and bench ownership.

States: queued → running → succeeded | failed | cancelled (a queued job may go straight to
cancelled). Every job is persisted in the store; live progress is kept in memory and written
through at most every ``PERSIST_EVERY_S``. Jobs that need the bench run one at a time, in
submission order, on a single worker thread (that thread owns the bench); the others run on a
small thread pool beside it. In a lab (several services on one store) a manager runs, cancels and
overlays only its own jobs (``store.bench_id``); another bench's are shown as stored, and cancelling
one is refused with ``OtherBenchJob``. Each queue is bounded (``MAX_QUEUED_BENCH_JOBS``,
``MAX_QUEUED_COMPUTE_JOBS``): a submission beyond it raises ``QueueFull`` and stores nothing.
"""

from __future__ import annotations

import asyncio
import json
import logging
import queue
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from service.runtime.heap import freeze_heap
from service.runtime.priority import WORK_NICE, set_thread_nice
from service.runtime.settings import MAX_QUEUED_BENCH_JOBS, MAX_QUEUED_COMPUTE_JOBS, QUEUE_RETRY_AFTER_S
from service.store import TERMINAL_STATES, Store, clean_json, utc_now

log = logging.getLogger("evcbench.jobs")

PERSIST_EVERY_S = 0.5
#: The interpreter's thread switch interval (s) while a bench job runs: a thread waiting for the GIL
#: (the bench loop between two compiled periods) gets it within this, not within the default 5 ms.
BENCH_SWITCH_INTERVAL_S = 0.0005
SSE_POLL_S = 0.1
SSE_HEARTBEAT_S = 15.0
#: how long a stopping service waits for its running jobs (s), and how often it looks (s)
SHUTDOWN_WAIT_S, SHUTDOWN_POLL_S = 30.0, 0.05
#: a job the service stopped under, ended in the store so (service.runtime.recovery would say "interrupted")
SHUTDOWN_LEFT = "cancelled: the service stopped while it ran, and it did not reach a point where it could stop"
#: the job threads' names begin so
JOB_THREAD_PREFIX = "evc-job"
#: How often an open event stream re-checks its caller's token (s): a revoked token's stream ends.
SSE_RECHECK_S = 1.0


class JobInterrupted(Exception):
    """A job ended early but produced something (e.g. a partial dataset): ``result`` is kept.
    ``cancelled`` True: it was stopped on request (cancel, emergency stop, signal), not by a fault."""

    def __init__(self, reason: str, result: dict | None = None, cancelled: bool = False):
        super().__init__(reason)
        self.reason, self.result, self.cancelled = reason, result, cancelled


class QueueFull(Exception):
    """A job queue holds its limit of queued jobs; nothing was stored. ``queue`` is "bench" or
    "compute"; ``queued`` and ``limit`` count jobs; ``retry_after_s`` is a hint in seconds."""

    def __init__(self, queue_name: str, queued: int, limit: int, retry_after_s: float = QUEUE_RETRY_AFTER_S):
        super().__init__(
            f"the {queue_name} job queue is full: {queued} {queue_name} jobs queued (limit {limit}); "
            f"retry when one has started, or cancel one (DELETE /api/jobs/{{id}})"
        )
        self.queue, self.queued, self.limit, self.retry_after_s = queue_name, queued, limit, retry_after_s


class OtherBenchJob(Exception):
    """A job of another bench of the lab: only that bench's service (``url``) may cancel it."""

    field = "job_id"

    def __init__(self, job_id: str, bench_id: str, url: str | None):
        where = f" at {url}" if url else ""
        super().__init__(
            f"job {job_id} runs on bench {bench_id!r}; only that bench's service{where} "
            f"may cancel it (DELETE /api/jobs/{job_id} there)"
        )
        self.job_id, self.bench_id, self.url = job_id, bench_id, url


@dataclass
class _Live:
    kind: str
    needs_bench: bool
    fn: Callable[[JobContext], dict]
    state: str = "queued"
    progress: float = 0.0
    message: str = "queued"
    version: int = 0
    persisted_at: float = 0.0
    cancel: threading.Event = field(default_factory=threading.Event)
    cancel_reason: str | None = None
    partial: dict | None = None  # the result so far, shown while the job runs (JobContext.progress)


class JobContext:
    """What a running job sees: its id, a progress reporter and the cancel flag."""

    def __init__(self, manager: JobManager, job_id: str):
        self._manager, self.job_id = manager, job_id

    def progress(self, fraction: float, message: str | None = None, partial: dict | None = None) -> None:
        """Report progress in 0..1 with an optional message (cheap; persisted at intervals).
        ``partial``: the result so far, shown as the job's ``result`` (GET and the event stream) until it
        ends (kept in memory only; the final result replaces it)."""
        self._manager._set_progress(self.job_id, fraction, message, partial)

    @property
    def cancelled(self) -> bool:
        live = self._manager._live.get(self.job_id)
        return live is None or live.cancel.is_set()


#: exceptions that only a fault in the service's code raises (a refusal, bad data, a driver's or the
#: store's trouble each have their own types, whose words are the job's error as they are)
FAULT_TYPES = (AttributeError, TypeError, NameError, IndexError, AssertionError, ZeroDivisionError)


def is_fault(exc: Exception) -> bool:
    """Whether ``exc`` is a fault of the service's code (a bare KeyError too; not a NotFoundError)."""
    return isinstance(exc, FAULT_TYPES) or type(exc) is KeyError


def failure_text(exc: Exception) -> str:
    """A failed job's ``error``: the exception's own words; for a fault of the service (``is_fault``),
    its type and words and where its traceback is (the service's log)."""
    if is_fault(exc):
        return f"an internal error ({type(exc).__name__}: {exc}); its traceback is in the service's log"
    return str(exc) or type(exc).__name__


class JobManager:
    """Runs, tracks and cancels jobs. ``on_cancel_bench(job_id)`` is called to stop a running bench
    job's plan (``Bench.cancel_plan``); ``bench_gate()`` raises to refuse a bench job (no engine).
    At most ``max_queued_bench_jobs`` bench jobs and ``max_queued_compute_jobs`` other jobs wait
    (running ones are not counted)."""

    def __init__(
        self,
        store: Store,
        on_cancel_bench: Callable[[str], None] | None = None,
        workers: int = 2,
        max_queued_bench_jobs: int = MAX_QUEUED_BENCH_JOBS,
        max_queued_compute_jobs: int = MAX_QUEUED_COMPUTE_JOBS,
        bench_gate: Callable[[], None] | None = None,
    ):
        self.store = store
        self._bench_gate = bench_gate
        self._on_cancel_bench = on_cancel_bench
        self._live: dict[str, _Live] = {}
        self._lock = threading.Lock()
        self.queue_limits = {True: int(max_queued_bench_jobs), False: int(max_queued_compute_jobs)}
        self._reserved = {True: 0, False: 0}  # places taken by submissions whose row is being written
        self._bench_queue: queue.Queue[str | None] = queue.Queue()
        # job threads run as any program even when a raised thread (the stop's, cancelling) starts them
        at_work = {"initializer": set_thread_nice, "initargs": (WORK_NICE,)}
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=JOB_THREAD_PREFIX, **at_work)
        self._persister = ThreadPoolExecutor(max_workers=1, thread_name_prefix="evc-progress", **at_work)
        self._bench_thread = threading.Thread(target=self._bench_worker, name="evc-bench-owner", daemon=True)
        self._running_bench_job: str | None = None
        self._closed = False  # jobs a previous process left unfinished: service.runtime.recovery, before this
        self._bench_thread.start()

    # ------------------------------------------------------------------ public
    def submit(self, kind: str, params: dict | None, fn: Callable[[JobContext], dict], needs_bench: bool) -> dict:
        """Queue a job; ``fn(ctx)`` returns the result dict. Returns the stored job record.
        QueueFull (nothing stored) if its queue already holds its limit of queued jobs."""
        if self._closed:
            raise RuntimeError("the service is shutting down; no new jobs")
        if needs_bench and self._bench_gate is not None:
            self._bench_gate()  # no engine: refused (EngineUnavailable, 503), nothing stored
        with self._lock:
            queued = self._reserved[needs_bench] + sum(
                1 for live in self._live.values() if live.needs_bench == needs_bench and live.state == "queued"
            )
            limit = self.queue_limits[needs_bench]
            if queued >= limit:
                raise QueueFull("bench" if needs_bench else "compute", queued, limit)
            self._reserved[needs_bench] += 1
        row = None
        try:
            row = self.store.add_job(kind, params, needs_bench)
        finally:
            with self._lock:  # the reserved place becomes the job's (or is given back on a failed write)
                self._reserved[needs_bench] -= 1
                if row is not None:
                    self._live[row["id"]] = _Live(kind=kind, needs_bench=needs_bench, fn=fn)
        if needs_bench:
            self._bench_queue.put(row["id"])
        else:
            self._pool.submit(self._run, row["id"])
        return self.get(row["id"])

    def get(self, job_id: str) -> dict:
        """The job as the API shows it (live progress overlaid on the stored record)."""
        return self._overlay(self.store.get_job(job_id))

    def list(self, limit: int = 100, bench_id: str | None = None, **filters: str | None) -> list[dict]:
        """The newest ``limit`` jobs (of every bench; ``bench_id``: that bench's), newest first;
        ``filters``: ``kind``, ``state`` and ``model_id`` as Store.list_jobs reads them."""
        return [self._overlay(row) for row in self.store.list_jobs(limit, bench_id=bench_id, **filters)]

    def _overlay(self, row: dict) -> dict:
        live = self._live.get(row["id"])
        if live is not None and row["state"] not in TERMINAL_STATES:
            row.update(state=live.state, progress=live.progress, message=live.message)
            if live.partial is not None:
                row["result"] = live.partial
        return _public(row)

    def cancel(self, job_id: str, reason: str | None = None) -> dict:
        """Cancel: a queued job at once; a running one is asked to stop (its state follows).
        ``reason`` (e.g. "emergency stop") becomes the job's message if the job gives none."""
        row = self.store.get_job(job_id)
        live = self._live.get(job_id)
        owner = row.get("bench_id")
        if live is None and owner is not None and owner != self.store.bench_id and row["state"] not in TERMINAL_STATES:
            bench = self.store.benches.get(owner)
            raise OtherBenchJob(job_id, owner, bench["url"] if bench else None)
        if row["state"] in TERMINAL_STATES or live is None:
            return self.get(job_id)
        with self._lock:
            live.cancel_reason = live.cancel_reason or reason
            live.cancel.set()
            if live.state == "queued":
                self._finish(job_id, "cancelled", message=reason or "cancelled before it started")
                return self.get(job_id)
        if live.needs_bench and self._on_cancel_bench is not None and self._running_bench_job == job_id:
            self._on_cancel_bench(job_id)  # besides the job's own cancel flag, for jobs that poll only the bench
        self._set_progress(job_id, live.progress, "cancel requested")
        return self.get(job_id)

    def bench_jobs(self) -> list[str]:
        """Ids of the bench jobs running or waiting for the bench now (empty: the bench is free)."""
        with self._lock:
            return [i for i, live in self._live.items() if live.needs_bench and live.state in ("queued", "running")]

    @property
    def running_bench_job(self) -> str | None:
        """The id of the job that owns the bench now, or None."""
        return self._running_bench_job

    def cancel_running_bench_job(self, reason: str | None = None) -> str | None:
        """Cancel whichever job owns the bench now; returns its id (None if the bench is idle)."""
        job_id = self._running_bench_job
        if job_id is not None:
            self.cancel(job_id, reason)
        return job_id

    def cancel_queued_bench_jobs(self, reason: str | None = None) -> list[str]:
        """Cancel every bench job still waiting for the bench (an emergency stop keeps it still)."""
        with self._lock:
            ids = [i for i, live in self._live.items() if live.needs_bench and live.state == "queued"]
        for job_id in ids:
            self.cancel(job_id, reason)
        return ids

    async def events(self, job_id: str, recheck: Callable[[], str | None] | None = None) -> AsyncIterator[str]:
        """Server-sent events: a ``progress`` event on every change, then ``end`` with the final job.

        ``recheck`` (if given) is called off the event loop about every ``SSE_RECHECK_S``; when it
        returns a reason (the caller's token was revoked), the stream ends with an ``error`` event
        whose data is ``{"detail": reason, "field": "authorization", "status": 401}``."""
        self.store.get_job(job_id)  # NotFoundError before the stream starts
        seen, last, last_sent = -1, None, time.monotonic()
        checked = time.monotonic()
        while True:
            if recheck is not None and time.monotonic() - checked >= SSE_RECHECK_S:
                reason = await asyncio.to_thread(recheck)
                checked = time.monotonic()
                if reason is not None:
                    yield _sse("error", {"detail": reason, "field": "authorization", "status": 401})
                    return
            live = self._live.get(job_id)
            version = None if live is None else live.version  # None: finished, read the store
            if version is None or version != seen:
                seen, job = version, await asyncio.to_thread(self.get, job_id)
                if job["state"] in TERMINAL_STATES:
                    yield _sse("end", job)
                    return
                if job != last:
                    yield _sse("progress", job)
                    last, last_sent = job, time.monotonic()
            if time.monotonic() - last_sent > SSE_HEARTBEAT_S:
                yield ": heartbeat\n\n"
                last_sent = time.monotonic()
            await asyncio.sleep(SSE_POLL_S)

    def shutdown(self, timeout_s: float = SHUTDOWN_WAIT_S) -> list[str]:
        """Stop taking jobs, cancel the queued ones, ask the running ones to stop, and wait for them at
        most ``timeout_s`` (s). A job still running then (a discover or identify fit stops at its next
        solve, service.science.interrupt; other work sees its cancel only between its steps) is ended
        in the store as cancelled, SHUTDOWN_LEFT; its thread is left to the process's exit (``serve``
        does not wait for it). Returns the ids of the jobs left so."""
        self._closed = True
        deadline = time.monotonic() + timeout_s
        if running := self._unfinished(("running",)):
            log.warning("service stopping: waiting at most %g s for job(s) %s to stop", timeout_s, running)
        for job_id in self._unfinished(("queued", "running")):
            self.cancel(job_id)
        self._bench_queue.put(None)
        self._bench_thread.join(max(0.0, deadline - time.monotonic()))
        self._pool.shutdown(wait=False, cancel_futures=True)
        while self._unfinished(("running",)) and time.monotonic() < deadline:
            time.sleep(SHUTDOWN_POLL_S)
        left = self._unfinished(("running",))
        for job_id in left:
            with self._lock:
                if job_id in self._live:
                    self._finish(job_id, "cancelled", message=SHUTDOWN_LEFT)
        if left:
            log.warning("service stopping: job(s) %s did not stop within %g s; ended as cancelled", left, timeout_s)
        self._persister.shutdown(wait=True)
        return left

    def job_threads_alive(self) -> bool:
        """Whether a job's thread is still at work (after ``shutdown``: one that did not stop in time)."""
        return any(t.name.startswith(JOB_THREAD_PREFIX) and t.is_alive() for t in threading.enumerate())

    def _unfinished(self, states: tuple[str, ...]) -> list[str]:
        with self._lock:
            return [i for i, live in self._live.items() if live.state in states]

    # ------------------------------------------------------------------ workers
    def _bench_worker(self) -> None:
        while True:
            job_id = self._bench_queue.get()
            if job_id is None:
                return
            self._running_bench_job = job_id
            freeze_heap()
            previous_s = sys.getswitchinterval()
            sys.setswitchinterval(min(previous_s, BENCH_SWITCH_INTERVAL_S))
            try:
                self._run(job_id)
            finally:
                sys.setswitchinterval(previous_s)
                self._running_bench_job = None

    def _run(self, job_id: str) -> None:
        live = self._live.get(job_id)
        with self._lock:
            if live is None or live.state != "queued" or live.cancel.is_set():
                return
            live.state, live.message, live.version = "running", "running", live.version + 1
        self.store.update_job(job_id, state="running", message="running", started_at=utc_now())
        try:
            result = live.fn(JobContext(self, job_id))
        except JobInterrupted as exc:
            state = "cancelled" if live.cancel.is_set() or exc.cancelled else "failed"
            self._finish(
                job_id, state, result=exc.result, message=exc.reason, error=None if state == "cancelled" else exc.reason
            )
        except Exception as exc:  # the job's failure is its result; the worker lives on
            if live.cancel.is_set():  # cancelled while it failed (an emergency stop's hold): cancelled
                self._finish(job_id, "cancelled", message=live.cancel_reason or "cancelled")
            else:
                if is_fault(exc):  # logged first: the error that points to the log is read after it
                    log.error("job %s failed", job_id, exc_info=exc)
                self._finish(job_id, "failed", message="failed", error=failure_text(exc))
        else:
            if live.cancel.is_set() and not result:
                self._finish(job_id, "cancelled", message=live.cancel_reason or "cancelled")
            else:
                self._finish(job_id, "succeeded", result=result, progress=1.0, message="done")

    def _set_progress(self, job_id: str, fraction: float, message: str | None, partial: dict | None = None) -> None:
        live = self._live.get(job_id)
        if live is None:  # finished meanwhile
            return
        live.progress = float(min(max(fraction, 0.0), 1.0))
        if message is not None:
            live.message = message
        if partial is not None:
            live.partial = clean_json(partial)
        live.version += 1
        now = time.monotonic()
        if now - live.persisted_at >= PERSIST_EVERY_S:  # written by another thread: a bench loop never
            live.persisted_at = now  # waits for the database (a WAL checkpoint may fsync)
            self._persister.submit(self.store.update_progress, job_id, live.progress, live.message)

    def _finish(
        self,
        job_id: str,
        state: str,
        *,
        result: dict | None = None,
        error: str | None = None,
        message: str | None = None,
        progress: float | None = None,
    ) -> None:
        live = self._live[job_id]
        fields = {"state": state, "finished_at": utc_now(), "message": message or state, "error": error}
        if result is not None:
            fields["result"] = clean_json(result)
        if progress is not None:
            live.progress = progress
        fields["progress"] = live.progress  # the last reported, not the last persisted (every PERSIST_EVERY_S)
        self.store.update_job(job_id, **fields)
        live.state, live.message = state, fields["message"]
        live.version += 1
        self._live.pop(job_id, None)  # the store has it all now; frees the job's closure and its arrays


def _public(row: dict) -> dict:
    keys = (
        "id",
        "kind",
        "state",
        "progress",
        "message",
        "result",
        "error",
        "params",
        "created_at",
        "started_at",
        "finished_at",
        "bench_id",
    )
    return {k: row.get(k) for k in keys}


def _sse(event: str, data: dict) -> str:
    return f"event: {event}\ndata: {json.dumps(data)}\n\n"
