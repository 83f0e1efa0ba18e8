"""The bench engine's supervisor, a thread of the web process: a dead or hung engine never leaves
the hardware driven, and the service never pretends it has an engine.

It watches the attached engine (``EngineBench.link``):

- **dead**: its process exited (the process sentinel: seen at once);
- **hung**: its pulse (service.runtime.engine_pulse, a beat every 50 ms) is older than
  ``HANG_LIMIT_S``; the engine is killed (SIGKILL also ends a stopped process).

Then, in this order: the engine is detached (every bench call and route answers 503 naming the
engine and the reason; /api/health says ``degraded``); the outputs are driven to 0 V from here
where the hardware lets another process do it (``zero``: drivers.safe_state.zero_outputs); the
bench jobs queued are cancelled with the reason, while the running one fails on its own call with
the same reason (a sweep keeps its samples as a partial dataset); a fresh engine is started, whose
first act is 0 V on every output with the amplifiers disabled, before any sensor opens
(engine_process._open_at_zero, drivers.safe_state.SafeOpen); and it
is attached with the fault latched: "engine restarted: <reason>, outputs set to 0 V at <time>",
which refuses every run until POST /api/bench/reset.

``HANG_LIMIT_S`` comes from measured pulse gaps (docs/architecture.md, "Supervision"): on the
loaded 2-core test machine the longest gap between beats was well under a second; the limit is
several times that, so load alone never reads as a hang.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from multiprocessing.connection import wait

from service.runtime.engine import EngineBench, EngineLink

log = logging.getLogger("evcbench.supervisor")

#: an engine whose pulse is older than this is hung (s)
HANG_LIMIT_S = 2.0
#: how often the supervisor looks at the pulse (s); a death is seen at once
WATCH_POLL_S = 0.05
#: waits between failed starts of a fresh engine (s), the last repeated
START_BACKOFF_S = (0.5, 2.0, 5.0, 10.0)
#: an engine that left on SIGTERM may be part of the service's own shut-down: wait this long for it (s)
SHUTDOWN_GRACE_S = 1.0


def wall_time(monotonic_s: float) -> str:
    """A ``time.monotonic()`` moment as UTC ISO time to the millisecond."""
    at = time.time() - (time.monotonic() - monotonic_s)
    return datetime.fromtimestamp(at, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def exit_reason(exitcode: int | None) -> str:
    """Why the engine process ended, in words."""
    if exitcode is None:
        return "the bench engine process ended"
    if exitcode < 0:
        try:
            return f"the bench engine process was killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"the bench engine process was killed by signal {-exitcode}"
    return f"the bench engine process exited with code {exitcode}"


class Supervisor:
    """Watches ``bench``'s engine; ``start()`` makes a fresh ``EngineLink``, ``zero()`` drives the
    outputs to 0 V from this process (returns notes in words), ``on_lost(reason)`` cancels the
    bench's queued jobs. ``restarts`` keeps each restart's figures (monotonic seconds)."""

    def __init__(
        self,
        bench: EngineBench,
        start: Callable[[], EngineLink],
        zero: Callable[[], list[str]] | None = None,
        on_lost: Callable[[str], None] | None = None,
        hang_limit_s: float = HANG_LIMIT_S,
    ):
        self.bench, self._start, self._zero, self._on_lost = bench, start, zero, on_lost
        self.hang_limit_s = float(hang_limit_s)
        self.restarts: list[dict] = []
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="evc-engine-supervisor", daemon=True)

    def start(self) -> Supervisor:
        self._thread.start()
        return self

    def stand_down(self) -> None:
        """The service is shutting down (a signal): an engine that exits now is not restarted."""
        self._closing.set()

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop watching (the service shuts down: the engine it closes is not restarted)."""
        self._closing.set()
        self._thread.join(timeout_s)

    # ------------------------------------------------------------------ watching
    def _watch(self) -> None:
        while not self._closing.is_set():
            link = self.bench.link
            if link is None:
                self._closing.wait(WATCH_POLL_S)
                continue
            reason = self._check(link)
            if reason is not None and not self._closing.is_set():
                self._recover(link, reason)

    def _check(self, link: EngineLink) -> str | None:
        """Why ``link``'s engine must be replaced, or None (after at most ``WATCH_POLL_S``)."""
        if wait([link.process.sentinel], WATCH_POLL_S):
            link.process.join(1.0)  # reaped: its exit code is known
            code = link.process.exitcode
            if code == 128 + signal.SIGTERM and self._closing.wait(SHUTDOWN_GRACE_S):
                return None  # the service's own shut-down: nothing to restart
            return exit_reason(code)
        age_s = link.heartbeat_age_s()
        if age_s > self.hang_limit_s:
            return f"the bench engine hung: no heartbeat for {age_s:.1f} s (limit {self.hang_limit_s:g} s)"
        return None

    # ------------------------------------------------------------------ recovering
    def _recover(self, link: EngineLink, reason: str) -> None:
        """Detach, kill, zero, cancel, start afresh and latch the fault."""
        figures = {"reason": reason, "detected_monotonic_s": time.monotonic()}
        log.error("%s: restarting it; outputs to 0 V first", reason)
        self.bench.detach(reason)
        if link.process.is_alive():
            link.process.kill()
        link.process.join(5.0)
        figures["killed_monotonic_s"] = time.monotonic()
        figures["zero_notes"] = self._zero_here()
        if figures["zero_notes"] is not None:
            figures["supervisor_zero_monotonic_s"] = at = time.monotonic()
            self.bench.zero_note = f"the supervisor wrote 0 V at {wall_time(at)} ({'; '.join(figures['zero_notes'])})"
        if self._on_lost is not None:
            try:
                self._on_lost(f"engine lost: {reason}")
            except Exception as exc:  # noqa: BLE001 - the restart goes on; the log says what failed
                log.error("cancelling the bench's queued jobs failed: %s", exc)
        fresh = self._start_fresh()
        if fresh is None:
            return
        zero_s = figures.get("supervisor_zero_monotonic_s") or fresh.facts["safe_start"]["zero_monotonic_s"]
        figures["engine_zero_monotonic_s"] = fresh.facts["safe_start"]["zero_monotonic_s"]
        figures["ready_monotonic_s"] = time.monotonic()
        fault = f"engine restarted: {reason}, outputs set to 0 V at {wall_time(zero_s)}"
        self.bench.zero_note = f"a fresh engine set 0 V at {wall_time(figures['engine_zero_monotonic_s'])}"
        self.bench.attach(fresh, latched=fault)
        self.restarts.append(figures)
        log.error("%s (pid %d); POST /api/bench/reset to run again", fault, fresh.process.pid)

    def _zero_here(self) -> list[str] | None:
        """0 V from this process where the hardware allows; the notes, or None if nothing was done."""
        if self._zero is None:
            return None
        try:
            notes = self._zero()
        except Exception as exc:  # noqa: BLE001 - the fresh engine writes 0 V as its first act anyway
            log.error("writing 0 V from the web process failed: %s", exc)
            return None
        for note in notes:
            log.warning("supervisor: %s", note)
        written = [n for n in notes if "not written" not in n]
        return notes if written else None

    def _start_fresh(self) -> EngineLink | None:
        """A fresh engine, trying again after ``START_BACKOFF_S`` while it fails; None if closing."""
        attempt = 0
        while not self._closing.is_set():
            try:
                return self._start()
            except Exception as exc:  # noqa: BLE001 - the reason stays visible; the next try follows
                wait_s = START_BACKOFF_S[min(attempt, len(START_BACKOFF_S) - 1)]
                attempt += 1
                self.bench.absent_reason = f"{self.bench.absent_reason.split('; ')[0]}; fresh engine failed: {exc}"
                log.error("a fresh bench engine did not start (%s); again in %g s", exc, wait_s)
                self._closing.wait(wait_s)
        return None


def supervise(bench, jobs) -> Supervisor | None:
    """Start the supervisor of ``bench`` (an ``EngineBench`` opened by the app, which gives it
    ``start_again``) with the job manager ``jobs``; None for a bench in this process."""
    start = getattr(bench, "start_again", None)
    if start is None:
        return None
    from drivers.safe_state import zero_outputs

    return Supervisor(
        bench,
        lambda: start(restart=True),
        zero=lambda: zero_outputs(bench.facts["config"]),
        on_lost=jobs.cancel_queued_bench_jobs,
    ).start()
