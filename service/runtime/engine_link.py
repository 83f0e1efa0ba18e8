"""One bench engine process as the web process holds it (service.runtime.engine): its pipes, its
facts and its pulse (``EngineLink``), how it is started and closed, and the error of every path
that finds it gone."""

from __future__ import annotations

import multiprocessing
import threading
import time
from dataclasses import dataclass

from drivers.interfaces import BenchLost, DriverError
from service.runtime.engine_process import engine_main

#: how long the engine may take to open the bench and say it is ready (s): numba kernels may compile
START_TIMEOUT_S = 300.0


class EngineUnavailable(BenchLost):
    """The bench engine process is gone, hung or restarting; the message says which and why. Every
    route answers it with 503 naming the engine (service/http/errors.py)."""


class BenchLatched(DriverError):
    """A restart's fault is latched: no bench job is taken until POST /api/bench/reset (409)."""


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


@dataclass
class EngineLink:
    """One engine process: its pipes, its facts and the heartbeat double its pulse writes."""

    process: multiprocessing.Process
    stop: _Channel
    command: _Channel
    plan: _Channel
    notice: object
    facts: dict
    heartbeat: object = None

    def heartbeat_age_s(self) -> float:
        """Seconds since the engine's pulse last beat (``time.monotonic()``, one clock per machine)."""
        return time.monotonic() - self.heartbeat.value if self.heartbeat is not None else 0.0


def close_link(link: EngineLink, timeout_s: float = 10.0) -> None:
    """Ask ``link``'s engine to close the bench at 0 V and exit; kill it if it does not."""
    try:
        with link.plan.lock:
            link.plan.conn.send(("close",))
    except (OSError, BrokenPipeError):
        pass
    link.process.join(timeout_s)
    if link.process.is_alive():
        link.process.kill()
        link.process.join(1.0)


def start_engine(
    bench_name: str,
    seed: int | None = None,
    overrides: dict | None = None,
    timeout_s: float = START_TIMEOUT_S,
    stop_address: tuple[str, int] | None = None,
    bench_id: str | None = None,
    restart: bool = False,
) -> EngineLink:
    """Start one bench engine process and wait until it has opened the bench at 0 V (``restart``:
    the supervisor's fresh engine, its amplifiers disabled until the reset)."""
    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: no inherited locks or threads
    pipes = [ctx.Pipe() for _ in range(3)] + [ctx.Pipe(duplex=False)]  # the last: notices, engine → here
    heartbeat = ctx.RawValue("d", time.monotonic())
    process = ctx.Process(
        target=engine_main,
        name="evc-bench-engine",
        args=(bench_name, seed, overrides, *(child for _, child in pipes), stop_address, bench_id, heartbeat, restart),
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
    return EngineLink(
        process,
        _Channel(stop_conn, "stop"),
        _Channel(command_conn, "command"),
        _Channel(plan_conn, "plan"),
        notice_conn,
        value,
        heartbeat,
    )
