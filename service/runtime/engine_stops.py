"""The bench engine's stops (service.runtime.engine_process): every stop, from the stop pipe or the
stop port, one at a time; the hold that keeps plans from running until the web process has
cancelled the bench's jobs after a stop-port press; and the port's answer."""

from __future__ import annotations

import threading

from drivers.bench import Bench
from service.runtime.stop_port import zero_after_request_ms


class StopHold:
    """The stop port's presses the web process has not yet answered: while one is open the engine
    runs no plan, so no job queued behind the stopped one starts before the web process cancels it."""

    def __init__(self):
        self._lock = threading.Lock()
        self._open: set[int] = set()
        self._count = 0

    def press(self) -> int:
        with self._lock:
            self._count += 1
            self._open.add(self._count)
            return self._count

    def release(self, seq: int | None = None) -> None:
        """Close press ``seq`` (None: every one)."""
        with self._lock:
            if seq is None:
                self._open.clear()
            else:
                self._open.discard(seq)

    @property
    def active(self) -> bool:
        return bool(self._open)


#: jobs remembered as cancelled before their plan arrived (older ones are forgotten)
CANCELLED_KEPT = 64


class Stopper:
    """Every stop of this process, from the stop pipe or the stop port, one at a time: each reads
    the ``last_stop`` figures of its own stop. It also remembers the jobs cancelled before their
    plan reached this process (``cancel_plan``), so that the plan stops as it begins (``begin``)."""

    def __init__(self, bench: Bench):
        self.bench, self._lock = bench, threading.Lock()
        self.owner: str | None = None  # the job whose plan runs now
        self._cancelled: dict[str, str] = {}  # job id → reason, for plans yet to come

    def stop(self, reason: str, wait_s: float | None) -> dict:
        with self._lock:
            self.bench.stop(reason, wait_s=wait_s)
            return dict(self.bench.last_stop)

    def begin(self, owner: str | None) -> None:
        """A plan of job ``owner`` begins (inside its ``Bench.plan_scope``): stopped at once if its
        job was cancelled before it arrived."""
        with self._lock:
            self.owner = owner
            reason = self._cancelled.pop(owner, None) if owner is not None else None
        if reason is not None:
            self.bench.request_stop(reason)

    def end(self) -> None:
        with self._lock:
            self.owner = None

    def command(self, message: tuple) -> dict:
        """A stop-pipe message: ``("stop", reason, wait_s)``, ``("request_stop", reason)`` or
        ``("cancel_plan", job_id, reason)``: stop that job's plan now or, not begun yet, as it begins."""
        op = message[0]
        if op == "cancel_plan":
            job_id, reason = message[1], message[2]
            with self._lock:
                running = self.owner == job_id
                if not running:
                    self._cancelled[job_id] = reason
                    while len(self._cancelled) > CANCELLED_KEPT:
                        self._cancelled.pop(next(iter(self._cancelled)))
            if running:
                self.bench.request_stop(reason)
            return {"requested": True}
        if op == "request_stop":
            self.bench.request_stop(message[1])
            return {"requested": True}
        return self.stop(message[1], message[2])


def port_answer(figures: dict, owner: str | None) -> dict:
    """The stop port's answer: the REST route's fields, from what this process knows."""
    return {
        "stopped": True,
        "door": "stop port",
        "cancelled_job_id": owner,
        "cancelled_queued_job_ids": None,
        "queued_jobs": "the service cancels the bench jobs queued; the engine runs none until it has",
        "loop_answered": figures["loop_answered"],
        "output_v": figures["output_v"],
        "zero_after_request_ms": zero_after_request_ms(figures),
        "zero_monotonic_s": figures["zero_monotonic_s"],
    }
