"""The bench engine's own process: it owns the hardware, runs plans and answers the stop.

The web process (uvicorn, downloads, imports, fits) and this process share no interpreter lock
and no event loop, so nothing a request does can delay the real-time loop, the watchdog or the
emergency stop. Three pipes connect them, each served by its own thread here:

* **stop**: ``("stop", reason, wait_s)`` → the stop's figures; ``("request_stop", reason)``. Never
  queued behind anything: its thread does nothing else.
* **command**: short queries and settings (``describe``, ``output_v``, ``live_since``,
  ``clear_faults``, fault injection), answered at once.
* **plan**: ``("execute", plan, args)``: ``plan(bench, emit, *args)`` runs in this process's main
  thread; ``emit`` sends ``("event", payload)`` back; the answer is ``("done", result)`` or
  ``("error", exception)``. One plan at a time.

If the web process dies (kill -9 included), every pipe reaches end-of-file: this process drives the
outputs to 0 V, closes the bench and exits. It never imports FastAPI or the store.
"""
from __future__ import annotations

import logging
import os
import pickle
import signal
import threading
from multiprocessing.connection import Connection

from drivers.bench import Bench
from drivers.interfaces import DriverError
from service.runtime.priority import ENGINE_NICE, set_thread_nice

log = logging.getLogger("evcbench.engine")


def bench_facts(bench: Bench) -> dict:
    """What the web process needs to know of the bench without asking it: axes, limits, the parts'
    static figures (gains, scales, ranges, channels, capabilities), backend and configuration."""
    parts, daq = bench.parts, bench.parts.daq
    return {
        "axes": bench.axes, "limits": bench.limits, "safety": bench.safety,
        "backend": parts.backend, "config": parts.config, "resonance_hz": parts.resonance_hz,
        "ao_channel": parts.ao_channel, "ai_channel": parts.ai_channel,
        "gain_v_per_v": {a: amp.gain_v_per_v for a, amp in parts.amplifiers.items()},
        "load_capacitance_f": {a: amp.load_capacitance_f for a, amp in parts.amplifiers.items()},
        "scale_um_per_v": {a: s.scale_um_per_v for a, s in parts.sensors.items()},
        "range_um": {a: tuple(s.range_um) for a, s in parts.sensors.items()},
        "capabilities": daq.capabilities, "sample_rate_hz": daq.sample_rate_hz,
        "compiled_stepping": bench.compiled_stepping, "emulated": parts.world is not None,
        "pid": os.getpid(),
    }


def _stop_command(bench: Bench, message: tuple) -> dict:
    op, reason = message[0], message[1]
    if op == "request_stop":
        bench.request_stop(reason)
        return {"requested": True}
    bench.stop(reason, wait_s=message[2])
    return bench.last_stop


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
    "state": lambda bench: {"running": bench.running, "tripped": bench.tripped,
                            "interrupt_reason": bench.interrupt_reason()},
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


def _exit_on_signal(sig: int, _frame) -> None:
    raise SystemExit(128 + sig)


def engine_main(bench_name: str, seed: int | None, overrides: dict | None, stop_conn: Connection, command_conn: Connection,
                plan_conn: Connection) -> None:
    """The process's entry point: open the bench, say what it is, serve the three pipes until the
    web process closes them (or dies), then leave the outputs at 0 V."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s:     [bench engine] %(message)s")
    # The web process handles SIGINT/SIGTERM (safe_shutdown: stop, then close us). A SIGTERM sent to
    # this process alone still leaves through ``finally``: the outputs at 0 V.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_signal)
    set_thread_nice(ENGINE_NICE)      # before any thread starts: they inherit it (service.runtime.priority)
    from drivers.emulated import open_bench

    try:
        bench = open_bench(bench_name, seed=seed, overrides=overrides)
    except Exception as exc:  # noqa: BLE001 - the web process reports it and does not start
        plan_conn.send(("error", _picklable(exc)))
        return
    closing = threading.Event()

    def shut_down() -> None:
        if not closing.is_set():
            closing.set()
            bench.request_stop("the web process went away")

    for name, conn, handle in (
            ("evc-engine-stop", stop_conn, lambda m: _stop_command(bench, m)),
            ("evc-engine-command", command_conn, lambda m: COMMANDS[m[0]](bench, *m[1:]))):
        threading.Thread(target=_serve, args=(conn, handle, None, shut_down), name=name, daemon=True).start()
    plan_conn.send(("ready", bench_facts(bench)))
    send_lock = threading.Lock()

    def emit(*payload) -> None:
        with send_lock:
            plan_conn.send(("event", payload))

    try:
        while not closing.is_set():
            try:
                message = plan_conn.recv()
            except (EOFError, OSError):
                break
            if message[0] == "close":
                break
            _, plan, args = message
            try:
                reply = ("done", plan(bench, emit, *args))
            except Exception as exc:  # noqa: BLE001 - the job that sent the plan reports it
                reply = ("error", _picklable(exc))
            try:
                with send_lock:
                    plan_conn.send(reply)
            except (EOFError, OSError):
                break
    finally:
        bench.close()
        log.info("bench closed at 0 V")
