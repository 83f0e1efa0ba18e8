"""The web process's handle on the bench engine process (service.runtime.engine_process).

``open_engine(bench_name, seed)`` starts the engine process and returns an ``EngineBench``: the
same surface the service uses of ``drivers.bench.Bench`` (axes, limits and their checks, ``run``,
``execute``, ``stop``, ``request_stop``, ``describe``, ``output_v``, ``live.since``,
``clear_faults``, fault injection), but every call that touches the hardware crosses a pipe to the
engine, which owns it. Why a process (docs/architecture.md, "The safety path"): the bench loop, its
watchdog and the stop then share neither the interpreter lock nor the event loop with downloads,
imports and fits, so a busy request cannot delay a sample or a stop.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import time
from collections.abc import Callable, Mapping
from types import SimpleNamespace

import numpy as np

from drivers.bench import RUN_BLOCK_SAMPLES, STOPPED_ON_REQUEST, BenchRecord, RunInterrupted
from drivers.interfaces import DriverError
from drivers.limits import LimitsMixin
from service.runtime.engine_process import engine_main
from service.runtime.priority import SAFETY_NICE, set_thread_nice

log = logging.getLogger("evcbench.engine")

#: how often a plan's caller looks at its ``should_stop`` while no event arrives (s)
SHOULD_STOP_POLL_S = 0.05
#: how long the engine may take to open the bench and say it is ready (s): numba kernels may compile
START_TIMEOUT_S = 300.0


class EngineUnavailable(DriverError):
    """The engine process is gone or did not answer; the message says which."""


class _Channel:
    """One pipe with a lock: a request and its answer are never interleaved with another's."""

    def __init__(self, conn, name: str):
        self.conn, self.name, self.lock = conn, name, threading.Lock()

    def call(self, *message):
        with self.lock:
            try:
                self.conn.send(message)
                status, value = self.conn.recv()
            except (EOFError, OSError, BrokenPipeError) as exc:
                raise EngineUnavailable(f"the bench engine process is gone ({self.name}: {exc})") from None
        if status == "error":
            raise value
        return value


class _FaultView:
    """A fault the engine scheduled, as its ``Fault.as_dict()`` described it."""

    def __init__(self, described: dict):
        self._described = described

    def as_dict(self) -> dict:
        return dict(self._described)


class _RemoteFaults:
    """Fault injection in the engine's emulator, as ``drivers.emulated.faults.FaultInjector`` offers it."""

    def __init__(self, command: _Channel):
        self._command = command

    def add(self, kind: str, axis: str | None = None, after_s: float = 0.0) -> _FaultView:
        return _FaultView(self._command.call("faults_add", kind, axis, after_s))

    def list(self) -> list[dict]:
        return self._command.call("faults_list")["faults"]

    @property
    def transports(self) -> list[str]:
        return self._command.call("faults_list")["transports"]

    def clear(self) -> list[str]:
        return self._command.call("faults_clear")["notes"]


class _RemoteLive:
    def __init__(self, command: _Channel):
        self._command = command

    def since(self, cursor: int | None = None, max_points: int = 2000) -> dict:
        return self._command.call("live_since", cursor, max_points)


def _parts(facts: dict, command: _Channel) -> SimpleNamespace:
    """The static figures of the engine's parts, shaped as ``drivers.interfaces.BenchParts``."""
    axes = facts["axes"]
    return SimpleNamespace(
        backend=facts["backend"],
        config=facts["config"],
        resonance_hz=facts["resonance_hz"],
        ao_channel=facts["ao_channel"],
        ai_channel=facts["ai_channel"],
        amplifiers={
            a: SimpleNamespace(gain_v_per_v=facts["gain_v_per_v"][a], load_capacitance_f=facts["load_capacitance_f"][a])
            for a in axes
        },
        sensors={
            a: SimpleNamespace(scale_um_per_v=facts["scale_um_per_v"][a], range_um=facts["range_um"][a]) for a in axes
        },
        daq=SimpleNamespace(capabilities=facts["capabilities"], sample_rate_hz=facts["sample_rate_hz"]),
        world=SimpleNamespace(faults=_RemoteFaults(command)) if facts["emulated"] else None,
    )


#: the arrays of a BenchRecord that hold one value per sample, by field name
_ROW_FIELDS = ("u_cmd_v", "x_um", "extra")


def _rows_from(record: BenchRecord, start: int) -> dict[tuple[str, str], np.ndarray]:
    """The record's rows ``start:`` as ``{(field, name): values}``: views, and the pipe pickles
    only the rows a view shows."""
    return {(field, name): values[start:] for field in _ROW_FIELDS for name, values in getattr(record, field).items()}


def run_buffered(bench, emit, u_v: Mapping[str, np.ndarray], sample_rate_hz: float, block_samples: int):
    """The plan behind ``EngineBench.run`` (runs in the engine): ``Bench.run``, sending each block's
    new rows as the event ``("block", start, rows, fraction)``. Returns what no event carried:
    ``(start, rows, sample_rate_hz, ending)``, ``ending`` None or ``(reason, stopped)`` of a
    RunInterrupted. Every row crosses the pipe once."""
    sent = 0

    def on_block(record: BenchRecord, fraction: float) -> None:
        nonlocal sent
        emit("block", sent, _rows_from(record, sent), fraction)
        sent = record.samples

    try:
        record, ending = bench.run(u_v, sample_rate_hz, block_samples=block_samples, on_block=on_block), None
    except RunInterrupted as exc:
        record, ending = exc.record, (exc.reason, exc.stopped)
    return sent, _rows_from(record, sent), record.sample_rate_hz, ending


class _Assembled:
    """A run's record put together in the web process from the rows the engine sends, in
    preallocated arrays (``n`` samples each), so each block costs O(block), never O(run)."""

    def __init__(self, n: int):
        self.n, self.done = n, 0
        self.arrays: dict[tuple[str, str], np.ndarray] = {}

    def add(self, start: int, rows: dict[tuple[str, str], np.ndarray]) -> None:
        for key, values in rows.items():
            if key not in self.arrays:
                self.arrays[key] = np.full(self.n, np.nan)
            self.arrays[key][start : start + len(values)] = values
            self.done = start + len(values)

    def record(self, sample_rate_hz: float, reason: str | None = None) -> BenchRecord:
        """The record so far (views); ``reason`` marks it partial."""
        fields = {field: {} for field in _ROW_FIELDS}
        for (field, name), values in self.arrays.items():
            fields[field][name] = values[: self.done]
        return BenchRecord(sample_rate_hz, partial=reason is not None, reason=reason, **fields)


class EngineBench(LimitsMixin):
    """The bench as the web process sees it when the engine runs in its own process."""

    def __init__(self, process, stop_conn, command_conn, plan_conn, facts: dict, notice_conn=None):
        self._process = process
        self._stop = _Channel(stop_conn, "stop")
        self._command = _Channel(command_conn, "command")
        self._plan = _Channel(plan_conn, "plan")
        self._running = threading.Event()
        self.facts = facts
        self.axes: tuple[str, ...] = tuple(facts["axes"])
        self.limits = facts["limits"]
        self.safety = facts["safety"]
        self.parts = _parts(facts, self._command)
        self.live = _RemoteLive(self._command)
        self.last_stop: dict | None = None
        #: the job that owns the bench now (the app sets it: the stop port's answer names the job)
        self.run_owner: Callable[[], str | None] = lambda: None
        #: called with the reason after the stop port stopped the bench (the app cancels the jobs)
        self.on_port_stop: Callable[[str], None] | None = None
        if notice_conn is not None:
            threading.Thread(
                target=self._hear_notices, args=(notice_conn,), name="evc-engine-notice", daemon=True
            ).start()

    # ------------------------------------------------------------------ facts
    @property
    def engine_pid(self) -> int:
        return self._process.pid

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
        self.last_stop = self._stop.call("stop", reason, wait_s)
        return bool(self.last_stop["loop_answered"])

    def request_stop(self, reason: str = STOPPED_ON_REQUEST) -> None:
        self._stop.call("request_stop", reason)

    def cancel_plan(self, owner: str | None = None) -> None:
        """Stop the plan of job ``owner`` (sent with it): now if it runs, or as it begins if the engine
        has not started it yet (a plain stop request would be cleared by its start). A plan with
        no owner gets a plain stop request. An engine that is gone runs no plan: nothing to cancel
        (its job fails on its own call). The emergency stop, ``stop``, still raises: it must say so."""
        try:
            if owner is None:
                self.request_stop()
            else:
                self._stop.call("cancel_plan", owner, STOPPED_ON_REQUEST)
        except EngineUnavailable:
            log.info("cancel of %s: the bench engine is gone, it runs no plan", owner or "the running plan")

    @property
    def stop_port(self) -> int | None:
        """The engine's stop port (service.runtime.stop_port), None if it has none."""
        return self.facts.get("stop_port")

    def set_stop_tokens(self, by_digest: dict[str, tuple[str, str, str]], auth_off: bool) -> int:
        """Tell the stop port which tokens are valid: SHA-256 hex digest → (id, name, scope)."""
        return self._command.call("stop_tokens", by_digest, auth_off)

    def _hear_notices(self, conn) -> None:
        """The stop port's presses: the app's ``on_port_stop`` cancels the bench's jobs, then the
        engine may run plans again. Runs at the safety priority; ends with the engine."""
        set_thread_nice(SAFETY_NICE)
        while True:
            try:
                kind, seq, reason = conn.recv()
            except (EOFError, OSError):
                return
            try:
                if self.on_port_stop is not None:
                    self.on_port_stop(reason)
            except Exception:  # noqa: BLE001 - the hold is released all the same: the bench is at 0 V
                log.exception("cancelling the bench's jobs after a stop-port press failed")
            finally:
                try:
                    self._command.call("release_hold", seq)
                except EngineUnavailable:
                    return

    # ------------------------------------------------------------------ queries
    def describe(self) -> dict:
        return {
            **self._command.call("describe"),
            "engine": {"process": "separate", "pid": self.engine_pid, "stop_port": self.stop_port},
        }

    def output_v(self) -> dict[str, float]:
        return self._command.call("output_v")

    def fault_reason(self) -> str | None:
        return self._command.call("fault_reason")

    def interrupt_reason(self) -> str | None:
        return self._command.call("state")["interrupt_reason"]

    def clear_faults(self) -> dict:
        return self._command.call("clear_faults")

    # ------------------------------------------------------------------ plans
    def execute(
        self, plan: Callable, *args, on_event: Callable | None = None, should_stop: Callable[[], bool] | None = None
    ):
        """Run ``plan(bench, emit, *args)`` in the engine (``plan`` and ``args`` must pickle: a
        module-level function and plain data); ``on_event(*payload)`` gets each event here. A
        true ``should_stop()`` (looked at on every event and every 50 ms) asks the engine to stop."""
        with self._plan.lock:
            self._running.set()
            try:
                return self._execute_locked(plan, args, on_event, should_stop)
            finally:
                self._running.clear()

    def _execute_locked(self, plan, args, on_event, should_stop):
        conn, asked, owner = self._plan.conn, False, self.run_owner()
        try:
            conn.send(("execute", plan, args, owner))
            while True:
                if should_stop is not None and not asked and should_stop():
                    self.cancel_plan(owner)
                    asked = True
                if not conn.poll(SHOULD_STOP_POLL_S):
                    if not self._process.is_alive():
                        raise EngineUnavailable("the bench engine process died during the run")
                    continue
                kind, value = conn.recv()
                if kind == "event":
                    if on_event is not None:
                        on_event(*value)
                    continue
                if kind == "error":
                    raise value
                return value
        except (EOFError, OSError, BrokenPipeError) as exc:
            raise EngineUnavailable(f"the bench engine process is gone (plan: {exc})") from None

    def run(
        self,
        u_v: Mapping[str, np.ndarray],
        sample_rate_hz: float,
        *,
        block_samples: int = RUN_BLOCK_SAMPLES,
        on_block: Callable[[BenchRecord, float], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> BenchRecord:
        """``Bench.run`` in the engine: ``on_block`` sees the record so far here, as it would there."""
        self.check_waveform(u_v, sample_rate_hz)
        assembled = _Assembled(len(np.asarray(next(iter(u_v.values())))))

        def on_event(kind, start, rows, fraction) -> None:
            assembled.add(start, rows)
            if on_block is not None:
                on_block(assembled.record(sample_rate_hz), fraction)

        u_plain = {a: np.asarray(v, dtype=float) for a, v in u_v.items()}
        start, rows, actual_hz, ending = self.execute(
            run_buffered, u_plain, float(sample_rate_hz), int(block_samples), on_event=on_event, should_stop=should_stop
        )
        assembled.add(start, rows)
        if ending is None:
            return assembled.record(actual_hz)
        reason, stopped = ending
        raise RunInterrupted(reason, assembled.record(actual_hz, reason), stopped=stopped)

    # ------------------------------------------------------------------ life
    def close(self, timeout_s: float = 10.0) -> None:
        """Ask the engine to close the bench at 0 V and exit; kill it if it does not."""
        try:
            with self._plan.lock:
                self._plan.conn.send(("close",))
        except (OSError, BrokenPipeError):
            pass
        self._process.join(timeout_s)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(1.0)


def open_engine(
    bench_name: str,
    seed: int | None = None,
    overrides: dict | None = None,
    timeout_s: float = START_TIMEOUT_S,
    stop_address: tuple[str, int] | None = None,
    bench_id: str | None = None,
) -> EngineBench:
    """Start the bench engine process on ``bench_name`` (with configuration ``overrides``, as
    ``drivers.factory.open_bench`` takes them) and wait until it has opened the bench.
    ``stop_address`` (host, port; port 0: any free one) opens the engine's stop port there, for the
    bench ``bench_id`` (service.runtime.stop_port)."""
    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: no inherited locks or threads
    pipes = [ctx.Pipe() for _ in range(3)] + [ctx.Pipe(duplex=False)]  # the last: notices, engine → here
    process = ctx.Process(
        target=engine_main,
        name="evc-bench-engine",
        args=(bench_name, seed, overrides, *(child for _, child in pipes), stop_address, bench_id),
        daemon=True,
    )
    process.start()
    for _, child in pipes:
        child.close()
    stop_conn, command_conn, plan_conn, notice_conn = (parent for parent, _ in pipes)
    deadline = time.monotonic() + timeout_s
    while not plan_conn.poll(0.2):
        if not process.is_alive() or time.monotonic() > deadline:
            process.kill()
            raise EngineUnavailable(f"the bench engine process did not start (exit code {process.exitcode})")
    try:
        status, value = plan_conn.recv()
    except (EOFError, OSError):
        process.join(5.0)
        raise EngineUnavailable(
            f"the bench engine process exited while starting (exit code {process.exitcode})"
        ) from None
    if status == "error":
        process.join(5.0)
        raise value
    return EngineBench(process, stop_conn, command_conn, plan_conn, value, notice_conn)
