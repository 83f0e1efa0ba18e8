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
import signal
import threading
from multiprocessing.connection import Connection

from drivers.bench import Bench
from drivers.interfaces import DriverError
from service.runtime.engine_pipes import Outbox, picklable, serve_pipe
from service.runtime.engine_pulse import Pulse
from service.runtime.engine_stops import StopHold, Stopper, port_answer
from service.runtime.heap import freeze_heap
from service.runtime.priority import ENGINE_NICE, set_thread_nice
from service.runtime.stop_port import EMERGENCY_STOP, STOP_PATH, StopPort, StopTokens

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


def _exit_on_signal(sig: int, _frame) -> None:
    raise SystemExit(128 + sig)


def _arm_hardware_watchdog(bench: Bench, safe: dict) -> None:
    """Arm the DAQ's own watchdog (``[safety] hardware_watchdog_s``; 0: off) where the driver has
    one, after the compile (which holds the GIL for seconds: no pet could come). Noted in ``safe``."""
    arm = getattr(bench.parts.daq, "arm_watchdog", None)
    if arm is None or bench.safety.hardware_watchdog_s <= 0:
        safe["hardware_watchdog"] = None
        return
    try:
        safe["hardware_watchdog"] = arm(bench.safety.hardware_watchdog_s)
    except Exception as exc:  # noqa: BLE001 - the supervisor still guards; the note says so
        safe["hardware_watchdog"] = None
        safe["notes"].append(f"hardware watchdog not armed: {exc}")


def _open_at_zero(bench_name: str, seed: int | None, overrides: dict | None, plan_conn: Connection, restart: bool):
    """Open the bench output-first, its first act 0 V on every output with the amplifiers disabled,
    before any sensor opens (drivers.safe_state.SafeOpen); on failure tell the web process on
    ``plan_conn`` and return (None, None). Returns the bench and what was done (``zero_monotonic_s``:
    the 0 V write, ``order``: each step's ``time.monotonic()``, s). The amplifiers stay disabled
    after a ``restart`` (until the operator's reset), and are enabled again at the 0 V otherwise
    (the last step of ``order``); ``amplifiers_disabled`` says which, ``amplifiers_note`` why."""
    from drivers.factory import open_bench
    from drivers.safe_state import SafeOpen

    safe_open = SafeOpen()
    try:
        bench = open_bench(bench_name, seed=seed, overrides=overrides, safe_open=safe_open)
    except Exception as exc:  # noqa: BLE001 - the web process reports it and does not start
        if safe_open.order and safe_open.zero_monotonic_s is None:
            exc = DriverError(f"writing 0 V at start-up failed: {exc}")  # an engine without 0 V never serves
        plan_conn.send(("error", picklable(exc)))
        return None, None
    bench.last_zero_monotonic_s = safe_open.zero_monotonic_s
    if not restart:
        safe_open.amplifiers_enabled(bench.parts.amplifiers)
    safe = safe_open.as_dict()
    safe["amplifiers_disabled"] = restart
    safe["amplifiers_note"] = (
        "disabled until the operator's reset (POST /api/bench/reset): this engine replaced one that was lost"
        if restart
        else "enabled again at 0 V once every device was open: a first start has no fault to hold them for"
    )
    return bench, safe


class _Engine:
    """One engine's parts once the bench is open: the stopper, the stop port's hold and tokens,
    and what the web process is told."""

    def __init__(self, bench: Bench, notice_conn: Connection | None):
        self.bench, self.notice_conn = bench, notice_conn
        self.closing, self.hold, self.stopper, self.tokens = (
            threading.Event(),
            StopHold(),
            Stopper(bench),
            StopTokens(),
        )
        self.notice_lock = threading.Lock()
        self.port: StopPort | None = None

    def press_from_port(self) -> dict:
        """A press of the stop port: 0 V first, then the hold, then the web process is told."""
        running = self.stopper.owner  # read first: the plan ends, and forgets it, as the loop stops
        figures = self.stopper.stop(EMERGENCY_STOP, None)
        seq = self.hold.press()
        try:
            with self.notice_lock:
                self.notice_conn.send(("emergency_stop", seq, EMERGENCY_STOP))
        except (OSError, AttributeError):
            pass  # no web process to tell: the hold stays, nothing runs
        log.warning("emergency stop on the stop port: outputs at 0 V, job %s stopped", running)
        return port_answer(figures, running)

    def open_stop_port(self, stop_address: tuple[str, int] | None, bench_id: str | None) -> None:
        """Listen on ``stop_address`` (None: no port). Raises DriverError naming the address."""
        if stop_address is None:
            return
        try:
            self.port = StopPort(*stop_address, press=self.press_from_port, tokens=self.tokens, bench_id=bench_id)
            self.port.start()
        except OSError as exc:
            raise DriverError(f"the stop port could not listen on {stop_address[0]}:{stop_address[1]}: {exc}") from None
        log.info("emergency stop port: POST http://%s:%d%s", self.port.host, self.port.port, STOP_PATH)

    def shut_down(self) -> None:
        if not self.closing.is_set():
            self.closing.set()
            self.bench.request_stop("the web process went away")

    def clear_faults(self) -> dict:
        """The operator's reset: a stale hold ends and amplifiers disabled at start-up are enabled
        again, all with the outputs at 0 V."""
        self.hold.release()
        out = self.bench.clear_faults()
        for amp in self.bench.parts.amplifiers.values():
            amp.enable()
        clear = getattr(self.bench.parts.daq, "clear_watchdog", None)
        if clear is not None:
            clear()
        return out

    def serve_pipes(self, stop_conn: Connection, command_conn: Connection) -> None:
        """The stop and command pipes, each on a thread of its own."""
        commands = {
            **COMMANDS,
            "clear_faults": lambda _bench: self.clear_faults(),
            "release_hold": lambda _bench, seq: self.hold.release(seq),
            "stop_tokens": lambda _bench, by_digest, auth_off: self.tokens.replace(by_digest, auth_off),
        }
        for name, conn, handle in (
            ("evc-engine-stop", stop_conn, self.stopper.command),
            ("evc-engine-command", command_conn, lambda m: commands[m[0]](self.bench, *m[1:])),
        ):
            threading.Thread(
                target=serve_pipe, args=(conn, handle, None, self.shut_down), name=name, daemon=True
            ).start()

    def serve_plans(self, plan_conn: Connection) -> None:
        """Run the plans the web process sends, one at a time, until it closes the pipe."""
        outbox = Outbox(plan_conn, self.shut_down)  # from here on the only sender on the plan pipe
        emit = self._emitter(outbox)
        try:
            while not self.closing.is_set():
                try:
                    message = plan_conn.recv()
                except (EOFError, OSError):
                    break
                if message[0] == "close":
                    break
                _, plan, args, job_id = message
                outbox.put(self._run_plan(plan, args, job_id, emit))  # after the plan's events, in order
        finally:
            outbox.close()

    def _emitter(self, outbox: Outbox):
        bench = self.bench

        def emit(*payload) -> None:
            outbox.put(("event", payload))
            unread_s = outbox.unsent_for_s()
            if unread_s > bench.safety.unread_limit_s and bench.interrupt_reason() is None:
                bench.request_stop(
                    f"the service took none of the run's samples for {unread_s:.1f} s (limit "
                    f"{bench.safety.unread_limit_s:g} s, [safety] unread_limit_s): stopped at 0 V"
                )

        return emit

    def _run_plan(self, plan, args, job_id: str | None, emit) -> tuple:
        freeze_heap()  # no full collection of the engine's heap stalls the run
        try:
            with self.bench.plan_scope():  # a stop from here on holds for the whole plan
                self.stopper.begin(job_id)  # ... and one for this job that came before it
                if self.hold.active:
                    raise DriverError(
                        f"{EMERGENCY_STOP} pressed on the stop port: no run starts until the "
                        "service has cancelled the bench's jobs"
                    )
                return ("done", plan(self.bench, emit, *args))
        except Exception as exc:  # noqa: BLE001 - the job that sent the plan reports it
            return ("error", picklable(exc))
        finally:
            self.stopper.end()

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
        self.bench.close()
        log.info("bench closed at 0 V")


def _quiet_signals() -> None:
    """The web process handles SIGINT/SIGTERM (safe_shutdown: stop, then close us). A SIGTERM sent
    to this process alone still leaves through ``finally``: the outputs at 0 V."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_signal)


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
    heartbeat=None,
    restart: bool = False,
) -> None:
    """The process's entry point: open the bench at 0 V (``_open_at_zero``, its first act), start the
    pulse (``heartbeat``: the shared double the supervisor reads), open the stop port on
    ``stop_address`` (if given), say what it is, serve the pipes until the web process closes them
    (or dies), then leave the outputs at 0 V. ``restart``: the supervisor's fresh engine, whose
    amplifiers stay disabled until the reset."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s:     [bench engine] %(message)s")
    _quiet_signals()
    set_thread_nice(ENGINE_NICE)  # before any thread starts: they inherit it (service.runtime.priority)
    bench, safe = _open_at_zero(bench_name, seed, overrides, plan_conn, restart)
    if bench is None:
        return
    pulse = Pulse(bench, heartbeat).start()  # beats from here on (the supervisor reads them once ready)
    from service.science.control.loop import compile_runner

    compile_runner(bench)  # now, not in a run: compiling holds the GIL for seconds
    _arm_hardware_watchdog(bench, safe)
    if safe["hardware_watchdog"] is not None:
        pulse.pet_from_now()
    engine = _Engine(bench, notice_conn)
    try:
        engine.open_stop_port(stop_address, bench_id)
    except DriverError as exc:
        pulse.close()
        bench.close()
        plan_conn.send(("error", exc))
        return
    engine.serve_pipes(stop_conn, command_conn)
    stop_port = None if engine.port is None else engine.port.port
    pulse.beat()  # fresh as the supervisor starts reading it (the compile may have starved the thread)
    plan_conn.send(("ready", {**bench_facts(bench), "stop_port": stop_port, "safe_start": safe}))
    try:
        engine.serve_plans(plan_conn)
    finally:
        pulse.close()
        engine.close()
