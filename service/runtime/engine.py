"""The web process's handle on the bench engine process (service.runtime.engine_process).

``open_engine(bench_name, seed)`` starts the engine process and returns an ``EngineBench``: the
same surface the service uses of ``drivers.bench.Bench`` (axes, limits and their checks, ``run``,
``execute``, ``stop``, ``request_stop``, ``describe``, ``output_v``, ``live.since``,
``clear_faults``, fault injection), but every call that touches the hardware crosses a pipe to the
engine, which owns it. Why a process (docs/architecture.md, "The safety path"): the bench loop, its
watchdog and the stop then share neither the interpreter lock nor the event loop with downloads,
imports and fits, so a busy request cannot delay a sample or a stop.

The ``EngineBench`` outlives its engine: the supervisor (service.runtime.supervisor) ``detach``es a
dead or hung engine and ``attach``es a fresh one. While none is attached every call raises
``EngineUnavailable`` with the reason (the routes answer 503 naming the engine), and after a
restart the fault stays latched (``latched``) until the operator's reset.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping

import numpy as np

from drivers.bench import RUN_BLOCK_SAMPLES, STOPPED_ON_REQUEST
from drivers.limits import LimitsMixin
from drivers.record import BenchRecord, RunInterrupted
from service.runtime.engine_link import (
    BenchLatched,
    EngineLink,
    EngineUnavailable,
    close_link,
    start_engine,
)
from service.runtime.engine_remote import Assembled, RemoteLive, parts_of, run_buffered
from service.runtime.priority import SAFETY_NICE, set_thread_nice

__all__ = [
    "BenchLatched",
    "EngineBench",
    "EngineLink",
    "EngineUnavailable",
    "open_engine",
    "start_engine",
    "run_buffered",
]

log = logging.getLogger("evcbench.engine")

#: how often a plan's caller looks at its ``should_stop`` while no event arrives (s)
SHOULD_STOP_POLL_S = 0.05
#: how long a call that found the engine gone waits for the supervisor's reason (s)
REASON_WAIT_S = 1.0


class _CurrentCommand:
    """The command pipe of whichever engine is attached now."""

    def __init__(self, bench: EngineBench):
        self._bench = bench

    def call(self, *message):
        return self._bench._link_or_raise().command.call(*message)


class EngineBench(LimitsMixin):
    """The bench as the web process sees it when the engine runs in its own process."""

    def __init__(self, link: EngineLink):
        self._link: EngineLink | None = None
        self._running = threading.Event()
        self._plan_lock = threading.Lock()
        self.absent_reason: str | None = None  # why no engine is attached (None: one is)
        self.restarting = False
        #: the latched restart fault ("engine restarted: …"), cleared by ``clear_faults`` (the reset)
        self.latched: str | None = None
        #: what was last done about the outputs without an engine (the supervisor's 0 V), in words
        self.zero_note: str | None = None
        self.last_stop: dict | None = None
        #: the job that owns the bench now (the app sets it: the stop port's answer names the job)
        self.run_owner: Callable[[], str | None] = lambda: None
        #: called with the reason after the stop port stopped the bench (the app cancels the jobs)
        self.on_port_stop: Callable[[str], None] | None = None
        #: called with the new stop port after an engine was attached (the app announces it)
        self.on_attach: Callable[[], None] | None = None
        self._command = _CurrentCommand(self)
        self.live = RemoteLive(self._command)
        self.attach(link)

    # ------------------------------------------------------------------ the engine's life
    def attach(self, link: EngineLink, latched: str | None = None) -> None:
        """Serve through ``link`` from now on; ``latched`` (a restart's fault) stays until the reset."""
        facts = link.facts
        self.facts = facts
        self.axes: tuple[str, ...] = tuple(facts["axes"])
        self.limits = facts["limits"]
        self.safety = facts["safety"]
        self.parts = parts_of(facts, self._command)
        if latched is not None:
            self.latched = latched
        self._link, self.absent_reason, self.restarting = link, None, False
        if link.notice is not None:
            threading.Thread(target=self._hear_notices, args=(link,), name="evc-engine-notice", daemon=True).start()
        if self.on_attach is not None:
            self.on_attach()

    def detach(self, reason: str) -> EngineLink | None:
        """No engine from now on (``reason`` in words); returns the link that was attached."""
        link, self._link = self._link, None
        self.absent_reason, self.restarting, self.zero_note = reason, True, None
        return link

    @property
    def link(self) -> EngineLink | None:
        return self._link

    @property
    def engine_state(self) -> str:
        """ "running" (an engine is attached), "restarting" or "absent" (none is)."""
        if self._link is not None:
            return "running"
        return "restarting" if self.restarting else "absent"

    def _link_or_raise(self) -> EngineLink:
        link = self._link
        if link is None:
            raise EngineUnavailable(f"the bench engine is {self.engine_state}: {self.absent_reason}")
        return link

    def admit_job(self) -> None:
        """A bench job's admission: EngineUnavailable without an engine, BenchLatched while a
        restart's fault awaits the reset."""
        self._link_or_raise()
        if self.latched is not None:
            raise BenchLatched(f"{self.latched}; POST /api/bench/reset before the bench runs again")

    def _gone(self, link: EngineLink, what: str) -> EngineUnavailable:
        """The error of a call that found ``link``'s engine gone, with the supervisor's reason when it
        gives one within ``REASON_WAIT_S``."""
        deadline = time.monotonic() + REASON_WAIT_S
        while self._link is link and time.monotonic() < deadline:
            time.sleep(0.01)
        if self._link is not link and self.absent_reason:
            return EngineUnavailable(f"{what} ({self.absent_reason})")
        return EngineUnavailable(f"{what}: the bench engine process is gone (exit code {link.process.exitcode})")

    # ------------------------------------------------------------------ facts
    @property
    def engine_pid(self) -> int | None:
        link = self._link
        return None if link is None else link.process.pid

    @property
    def sample_rate_hz(self) -> float:
        return self.facts["sample_rate_hz"]

    @property
    def supports_point_by_point(self) -> bool:
        return self.facts["capabilities"].point_by_point

    @property
    def compiled_stepping(self) -> bool:
        return self.facts["compiled_stepping"]

    @property
    def running(self) -> bool:
        return self._running.is_set()

    @property
    def tripped(self) -> str | None:
        return self._command.call("state")["tripped"]

    # ------------------------------------------------------------------ the safety path
    def stop(self, reason: str = "emergency stop", wait_s: float | None = None) -> bool:
        """Emergency stop in the engine (``Bench.stop``): True if a running loop answered.
        ``last_stop`` has the figures, ``time.monotonic()`` seconds comparable across processes."""
        self.last_stop = self._link_or_raise().stop.call("stop", reason, wait_s)
        return bool(self.last_stop["loop_answered"])

    def request_stop(self, reason: str = STOPPED_ON_REQUEST) -> None:
        self._link_or_raise().stop.call("request_stop", reason)

    def cancel_plan(self, owner: str | None = None) -> None:
        """Stop the plan of job ``owner`` (sent with it): now if it runs, or as it begins if the engine
        has not started it yet (a plain stop request would be cleared by its start). A plan with
        no owner gets a plain stop request. An engine that is gone runs no plan: nothing to cancel
        (its job fails on its own call). The emergency stop, ``stop``, still raises: it must say so."""
        try:
            if owner is None:
                self.request_stop()
            else:
                self._link_or_raise().stop.call("cancel_plan", owner, STOPPED_ON_REQUEST)
        except EngineUnavailable:
            log.info("cancel of %s: the bench engine is gone, it runs no plan", owner or "the running plan")

    @property
    def stop_port(self) -> int | None:
        """The engine's stop port (service.runtime.stop_port), None if it has none."""
        return self.facts.get("stop_port")

    def set_stop_tokens(self, by_digest: dict[str, tuple[str, str, str]], auth_off: bool) -> int:
        """Tell the stop port which tokens are valid: SHA-256 hex digest → (id, name, scope)."""
        return self._command.call("stop_tokens", by_digest, auth_off)

    def _hear_notices(self, link: EngineLink) -> None:
        """The stop port's presses: the app's ``on_port_stop`` cancels the bench's jobs, then the
        engine may run plans again. Runs at the safety priority; ends with the engine."""
        set_thread_nice(SAFETY_NICE)
        while True:
            try:
                kind, seq, reason = link.notice.recv()
            except (EOFError, OSError):
                return
            try:
                if self.on_port_stop is not None:
                    self.on_port_stop(reason)
            except Exception:  # noqa: BLE001 - the hold is released all the same: the bench is at 0 V
                log.exception("cancelling the bench's jobs after a stop-port press failed")
            finally:
                try:
                    link.command.call("release_hold", seq)
                except EngineUnavailable:
                    return

    # ------------------------------------------------------------------ queries
    def describe(self) -> dict:
        link = self._link_or_raise()
        return {
            **link.command.call("describe"),
            "engine": self.engine_facts(),
        }

    def engine_facts(self) -> dict:
        """The engine process as GET /api/bench shows it: state, pid, stop port, the restart fault."""
        return {
            "process": "separate",
            "state": self.engine_state,
            "pid": self.engine_pid,
            "stop_port": self.stop_port if self._link is not None else None,
            "reason": self.absent_reason,
            "latched_fault": self.latched,
            "safe_start": self.facts.get("safe_start"),
        }

    def output_v(self) -> dict[str, float]:
        return self._command.call("output_v")

    def fault_reason(self) -> str | None:
        return self.latched or self._command.call("fault_reason")

    def interrupt_reason(self) -> str | None:
        return self._command.call("state")["interrupt_reason"]

    def clear_faults(self) -> dict:
        """The operator's reset (POST /api/bench/reset): the engine's faults and the restart latch."""
        out = self._command.call("clear_faults")
        if self.latched is not None:
            out = {**out, "cleared": [self.latched, *out["cleared"]]}
            self.latched = None
        return out

    # ------------------------------------------------------------------ plans
    def execute(
        self, plan: Callable, *args, on_event: Callable | None = None, should_stop: Callable[[], bool] | None = None
    ):
        """Run ``plan(bench, emit, *args)`` in the engine (``plan`` and ``args`` must pickle: a
        module-level function and plain data); ``on_event(*payload)`` gets each event here. A
        true ``should_stop()`` (looked at on every event and every 50 ms) asks the engine to stop.
        Refused while a restart's fault is latched (``latched``)."""
        with self._plan_lock:
            link = self._link_or_raise()
            if self.latched is not None:
                raise BenchLatched(f"{self.latched}; POST /api/bench/reset before the bench runs again")
            self._running.set()
            try:
                with link.plan.lock:
                    return self._execute_locked(link, plan, args, on_event, should_stop)
            finally:
                self._running.clear()

    def _execute_locked(self, link: EngineLink, plan, args, on_event, should_stop):
        conn, asked, owner = link.plan.conn, False, self.run_owner()
        try:
            conn.send(("execute", plan, args, owner))
            while True:
                if should_stop is not None and not asked and should_stop():
                    self.cancel_plan(owner)
                    asked = True
                if not conn.poll(SHOULD_STOP_POLL_S):
                    if not link.process.is_alive() or self._link is not link:
                        raise self._gone(link, "the bench engine was lost during the run")
                    continue
                kind, value = conn.recv()
                if kind == "event":
                    if on_event is not None:
                        on_event(*value)
                    continue
                if kind == "error":
                    raise value
                return value
        except (EOFError, OSError, BrokenPipeError):
            raise self._gone(link, "the bench engine was lost during the run") from None

    def run(
        self,
        u_v: Mapping[str, np.ndarray],
        sample_rate_hz: float,
        *,
        block_samples: int = RUN_BLOCK_SAMPLES,
        on_block: Callable[[BenchRecord, float], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> BenchRecord:
        """``Bench.run`` in the engine: ``on_block`` sees the record so far here, as it would there.
        An engine that dies during the run ends it as RunInterrupted with the record so far."""
        self.check_waveform(u_v, sample_rate_hz)
        assembled = Assembled(len(np.asarray(next(iter(u_v.values())))))

        def on_event(kind, start, rows, fraction) -> None:
            assembled.add(start, rows)
            if on_block is not None:
                on_block(assembled.record(sample_rate_hz), fraction)

        u_plain = {a: np.asarray(v, dtype=float) for a, v in u_v.items()}
        try:
            start, rows, actual_hz, ending = self.execute(
                run_buffered,
                u_plain,
                float(sample_rate_hz),
                int(block_samples),
                on_event=on_event,
                should_stop=should_stop,
            )
        except EngineUnavailable as exc:
            if not assembled.done:
                raise
            raise RunInterrupted(str(exc), assembled.record(sample_rate_hz, str(exc))) from None
        assembled.add(start, rows)
        if ending is None:
            return assembled.record(actual_hz)
        reason, stopped = ending
        raise RunInterrupted(reason, assembled.record(actual_hz, reason), stopped=stopped)

    # ------------------------------------------------------------------ life
    def close(self, timeout_s: float = 10.0) -> None:
        """Ask the engine to close the bench at 0 V and exit; kill it if it does not."""
        link = self._link
        if link is not None:
            close_link(link, timeout_s)


def open_engine(bench_name: str, **options) -> EngineBench:
    """Start the bench engine process on ``bench_name`` and wait until it has opened the bench: the
    options are ``start_engine``'s (seed, configuration ``overrides`` as ``drivers.factory.open_bench``
    takes them, ``timeout_s``, ``stop_address`` (host, port; port 0: any free one) for the engine's
    stop port, and ``bench_id``)."""
    return EngineBench(start_engine(bench_name, **options))
