"""The bench engine's own process: it owns the hardware, runs plans and answers the stop.

The web process (uvicorn, downloads, imports, fits) and this process share no interpreter lock
and no event loop, so nothing a request does can delay the real-time loop, the watchdog or the
emergency stop. Three pipes connect them, each served by its own thread here:

* **stop**: ``("stop", reason, wait_s)`` → the stop's figures; ``("request_stop", reason)``;
  ``("cancel_plan", job_id, reason)``: that job's plan stops now, or as it begins if it has not yet. Never
  queued behind anything: its thread does nothing else.
* **command**: short queries and settings (``describe``, ``output_v``, ``live_since``,
  ``clear_faults``, fault injection), answered at once.
* **plan**: ``("execute", plan, args, owner)``: ``plan(bench, emit, *args)`` runs in this process's
  main thread for the job ``owner``; ``emit`` sends ``("event", payload)`` back; the answer is
  ``("done", result)`` or ``("error", exception)``. One plan at a time.
* **notice** (this process → the web process): ``("emergency_stop", seq, reason)`` after the stop
  port (service.runtime.stop_port) drove the outputs to 0 V. Until the web process answers
  ``release_hold(seq)`` on the command pipe, having cancelled the bench's jobs, no plan runs.

The stop port is the emergency stop's own door into this process: a socket served by a thread of
its own, so a stop pressed there waits for nothing the web process does.

If the web process dies (kill -9 included), every pipe reaches end-of-file: this process drives the
outputs to 0 V, closes the bench and exits. It never imports FastAPI or the store.
"""

from __future__ import annotations

import logging
import os
import pickle
import queue
import signal
import threading
import time
from multiprocessing.connection import Connection

from drivers.bench import Bench
from drivers.interfaces import DriverError
from service.runtime.heap import freeze_heap
from service.runtime.priority import ENGINE_NICE, set_thread_nice
from service.runtime.stop_port import EMERGENCY_STOP, STOP_PATH, StopPort, StopTokens, zero_after_request_ms

log = logging.getLogger("evcbench.engine")


def bench_facts(bench: Bench) -> dict:
    """What the web process needs to know of the bench without asking it: axes, limits, the parts'
    static figures (gains, scales, ranges, channels, capabilities), backend and configuration."""
    parts, daq = bench.parts, bench.parts.daq
    return {
        "axes": bench.axes,
        "limits": bench.limits,
        "safety": bench.safety,
        "backend": parts.backend,
        "config": parts.config,
        "resonance_hz": parts.resonance_hz,
        "ao_channel": parts.ao_channel,
        "ai_channel": parts.ai_channel,
        "gain_v_per_v": {a: amp.gain_v_per_v for a, amp in parts.amplifiers.items()},
        "load_capacitance_f": {a: amp.load_capacitance_f for a, amp in parts.amplifiers.items()},
        "scale_um_per_v": {a: s.scale_um_per_v for a, s in parts.sensors.items()},
        "range_um": {a: tuple(s.range_um) for a, s in parts.sensors.items()},
        "capabilities": daq.capabilities,
        "sample_rate_hz": daq.sample_rate_hz,
        "compiled_stepping": bench.compiled_stepping,
        "emulated": parts.world is not None,
        "pid": os.getpid(),
    }


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


class _Stopper:
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


def _faults(bench: Bench):
    world = bench.parts.world
    if world is None:
        raise LookupError(f"fault injection needs the emulated bench; this one is {bench.parts.backend}")
    return world.faults


COMMANDS = {
    "describe": lambda bench: bench.describe(),
    "output_v": lambda bench: bench.output_v(),
    "fault_reason": lambda bench: bench.fault_reason(),
    "clear_faults": lambda bench: bench.clear_faults(),
    "live_since": lambda bench, since, max_points: bench.live.since(since, max_points),
    "faults_add": lambda bench, *args: _faults(bench).add(*args).as_dict(),
    "faults_list": lambda bench: {"faults": _faults(bench).list(), "transports": sorted(_faults(bench).transports)},
    "faults_clear": lambda bench: {"cleared": len(_faults(bench).list()), "notes": _faults(bench).clear()},
    "state": lambda bench: {
        "running": bench.running,
        "tripped": bench.tripped,
        "interrupt_reason": bench.interrupt_reason(),
    },
}


def _picklable(exc: BaseException) -> BaseException:
    """The exception itself if it survives a pickle round trip, else a DriverError saying what it was."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception may fail to rebuild on the other side
        return DriverError(f"{type(exc).__name__}: {exc}")


def _serve(conn: Connection, handle, lock: threading.Lock | None, on_eof) -> None:
    """Answer each message on ``conn`` with ``("ok", value)`` or ``("error", exception)``."""
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            on_eof()
            return
        try:
            reply = ("ok", handle(message))
        except Exception as exc:  # noqa: BLE001 - the caller gets it; the engine lives on
            reply = ("error", _picklable(exc))
        try:
            if lock is None:
                conn.send(reply)
            else:
                with lock:
                    conn.send(reply)
        except (EOFError, OSError):
            on_eof()
            return


class _Outbox:
    """The plan pipe's sending side, on a thread of its own: a plan's ``emit`` never blocks its
    loop when the web process is slow to read (its socket buffer full while it collects garbage,
    say); events and the answer leave in the order they were put."""

    def __init__(self, conn: Connection, on_eof):
        self._conn, self._on_eof = conn, on_eof
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._count_lock = threading.Lock()
        self._unsent, self._waiting_since = 0, 0.0
        self._thread = threading.Thread(target=self._send_all, name="evc-engine-outbox", daemon=True)
        self._thread.start()

    def put(self, message: tuple) -> None:
        with self._count_lock:
            if self._unsent == 0:
                self._waiting_since = time.monotonic()  # the clock starts with the first unsent message
            self._unsent += 1
        self._queue.put(message)

    def unsent_for_s(self) -> float:
        """While messages wait: how long since the reader last took one (or since the first of them
        was put, if later), in s; 0 when none waits. A reader that takes nothing makes it grow."""
        with self._count_lock:
            return time.monotonic() - self._waiting_since if self._unsent else 0.0

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what is queued, then stop."""
        self._queue.put(None)
        self._thread.join(timeout_s)

    def _send_all(self) -> None:
        while (message := self._queue.get()) is not None:
            try:
                self._conn.send(message)
            except (EOFError, OSError):
                self._on_eof()
                return
            with self._count_lock:
                self._unsent -= 1
                self._waiting_since = time.monotonic()  # the reader took one just now


def _exit_on_signal(sig: int, _frame) -> None:
    raise SystemExit(128 + sig)


def _port_answer(figures: dict, owner: str | None) -> dict:
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


def engine_main(
    bench_name: str,
    seed: int | None,
    overrides: dict | None,
    stop_conn: Connection,
    command_conn: Connection,
    plan_conn: Connection,
    notice_conn: Connection | None = None,
    stop_address: tuple[str, int] | None = None,
    bench_id: str | None = None,
) -> None:
    """The process's entry point: open the bench (and the stop port on ``stop_address``, if given),
    say what it is, serve the pipes until the web process closes them (or dies), then leave the
    outputs at 0 V."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s:     [bench engine] %(message)s")
    # The web process handles SIGINT/SIGTERM (safe_shutdown: stop, then close us). A SIGTERM sent to
    # this process alone still leaves through ``finally``: the outputs at 0 V.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_signal)
    set_thread_nice(ENGINE_NICE)  # before any thread starts: they inherit it (service.runtime.priority)
    from drivers.factory import open_bench

    try:
        bench = open_bench(bench_name, seed=seed, overrides=overrides)
    except Exception as exc:  # noqa: BLE001 - the web process reports it and does not start
        plan_conn.send(("error", _picklable(exc)))
        return
    from service.science.control.loop import compile_runner

    compile_runner(bench)  # now, not in a run: compiling holds the GIL for seconds
    closing, hold, stopper, tokens = threading.Event(), StopHold(), _Stopper(bench), StopTokens()
    notice_lock = threading.Lock()

    def press_from_port() -> dict:
        running = stopper.owner  # read first: the plan ends, and forgets it, as the loop stops
        figures = stopper.stop(EMERGENCY_STOP, None)  # 0 V first, then everything else
        seq = hold.press()
        try:
            with notice_lock:
                notice_conn.send(("emergency_stop", seq, EMERGENCY_STOP))
        except (OSError, AttributeError):
            pass  # no web process to tell: the hold stays, nothing runs
        log.warning("emergency stop on the stop port: outputs at 0 V, job %s stopped", running)
        return _port_answer(figures, running)

    port = None
    if stop_address is not None:
        try:
            port = StopPort(*stop_address, press=press_from_port, tokens=tokens, bench_id=bench_id).start()
            log.info("emergency stop port: POST http://%s:%d%s", port.host, port.port, STOP_PATH)
        except OSError as exc:
            bench.close()
            plan_conn.send(
                ("error", DriverError(f"the stop port could not listen on {stop_address[0]}:{stop_address[1]}: {exc}"))
            )
            return

    def shut_down() -> None:
        if not closing.is_set():
            closing.set()
            bench.request_stop("the web process went away")

    def clear_faults() -> dict:
        hold.release()  # a reset with the outputs at 0 V also ends a stale hold
        return bench.clear_faults()

    commands = {
        **COMMANDS,
        "clear_faults": lambda _bench: clear_faults(),
        "release_hold": lambda _bench, seq: hold.release(seq),
        "stop_tokens": lambda _bench, by_digest, auth_off: tokens.replace(by_digest, auth_off),
    }
    for name, conn, handle in (
        ("evc-engine-stop", stop_conn, stopper.command),
        ("evc-engine-command", command_conn, lambda m: commands[m[0]](bench, *m[1:])),
    ):
        threading.Thread(target=_serve, args=(conn, handle, None, shut_down), name=name, daemon=True).start()
    plan_conn.send(("ready", {**bench_facts(bench), "stop_port": None if port is None else port.port}))
    outbox = _Outbox(plan_conn, shut_down)  # from here on the only sender on the plan pipe

    def emit(*payload) -> None:
        outbox.put(("event", payload))
        unread_s = outbox.unsent_for_s()
        if unread_s > bench.safety.unread_limit_s and bench.interrupt_reason() is None:
            bench.request_stop(
                f"the service took none of the run's samples for {unread_s:.1f} s (limit "
                f"{bench.safety.unread_limit_s:g} s, [safety] unread_limit_s): stopped at 0 V"
            )

    try:
        while not closing.is_set():
            try:
                message = plan_conn.recv()
            except (EOFError, OSError):
                break
            if message[0] == "close":
                break
            _, plan, args, job_id = message
            freeze_heap()  # no full collection of the engine's heap stalls the run
            try:
                with bench.plan_scope():  # a stop from here on holds for the whole plan
                    stopper.begin(job_id)  # ... and one for this job that came before it
                    if hold.active:
                        raise DriverError(
                            f"{EMERGENCY_STOP} pressed on the stop port: no run starts until the "
                            "service has cancelled the bench's jobs"
                        )
                    reply = ("done", plan(bench, emit, *args))
            except Exception as exc:  # noqa: BLE001 - the job that sent the plan reports it
                reply = ("error", _picklable(exc))
            finally:
                stopper.end()
            outbox.put(reply)  # after the plan's events, in order
    finally:
        outbox.close()
        if port is not None:
            port.close()
        bench.close()
        log.info("bench closed at 0 V")
