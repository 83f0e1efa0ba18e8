"""Benchmark: a dead or hung bench engine, from its death to 0 V at the outputs and to a fresh engine.

    evcbench bench engine_death --json      (also part of ``evcbench bench safety``)

The emulated output stage runs in a process of its own (drivers/emulated/output_stage.py), so a
dead engine leaves its last voltage held, as on hardware. Each kill happens during a buffered
real-time sweep that drives the outputs (the stage holds > 1 V); the engine is then either
SIGKILLed (``dead``) or SIGSTOPped (``hung``: the supervisor kills it after ``HANG_LIMIT_S``
without a heartbeat), with the stage's watchdog (``WATCHDOG_S``) honoured or not (the supervisor
alone). Per case and ``kills`` times:

* ``engine_death_to_zero_ms``: the kill (or stop) → every output below 10 mV at the stage, read on
  the stage's clock (``time.monotonic()``: CLOCK_MONOTONIC, shared by the processes);
* ``engine_restart_s``: the kill → a fresh engine attached (its fault latched);
* ``zeroed_by``: what drove the outputs to 0 V (the stage's watchdog or the supervisor);
* ``stage_noticed_late_ms_max``: how late the stage's process noticed its watchdog's deadline at
  worst (its outputs read 0 V from the deadline on; drivers/emulated/output_stage.py).

``pulse_gap_ms``: the engine's heartbeat age seen every 5 ms by the web process while sweeps run
(the figure the hang limit is chosen against).
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from drivers.emulated.output_stage import OutputStageLink
from drivers.interfaces import BenchLost
from drivers.record import RunInterrupted
from drivers.safe_state import zero_outputs
from service.runtime.engine import EngineBench, start_engine
from service.runtime.supervisor import HANG_LIMIT_S, Supervisor

#: the stage's watchdog timeout in this benchmark (s; [safety] hardware_watchdog_s)
WATCHDOG_S = 0.5
KILLS = 10


def _drive(bench: EngineBench) -> None:
    fs = bench.sample_rate_hz
    t = np.arange(int(60 * fs)) / fs
    u = 60.0 - 60.0 * np.cos(2 * np.pi * 1.0 * t)
    try:
        bench.run({"y": u, "z": u}, fs)
    except (RunInterrupted, BenchLost):
        pass


def _wait(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.002)
    return value


class _Rig:
    """The stage process, an engine on a bench that drives it, and the supervisor."""

    def __init__(self):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.emulated.output_stage"], stdout=subprocess.PIPE, text=True
        )
        address = self.proc.stdout.readline().strip()
        self.stage = OutputStageLink(address)
        overrides = {
            "emulator": {"output_stage": address},
            "safety": {"hardware_watchdog_s": WATCHDOG_S},
        }

        def start(restart: bool = False):
            return start_engine("default_realtime", seed=1, overrides=overrides, restart=restart)

        self.bench = EngineBench(start())
        self.supervisor = Supervisor(
            self.bench, lambda: start(restart=True), zero=lambda: zero_outputs(self.bench.facts["config"])
        ).start()
        self.gaps: list[float] = []

    def state(self) -> dict:
        for _ in range(5):
            try:
                return self.stage.call("state")
            except TimeoutError:
                continue
        raise TimeoutError("the output stage does not answer")

    def held_v(self) -> float:
        s = self.state()
        return max(abs(v) for v in s["amplifier_v"] + s["daq_ao_v"])

    def once(self, mode: str, watchdog: bool, rng: random.Random) -> dict:
        self.stage.call("honour", on=watchdog)
        self.bench.clear_faults()  # the operator's reset after the last restart
        worker = threading.Thread(target=_drive, args=(self.bench,), daemon=True)
        worker.start()
        _wait(lambda: self.held_v() > 1.0, 60, "the sweep drives the outputs")
        link = self.bench.link
        until = time.monotonic() + 0.3 + 0.4 * rng.random()
        while time.monotonic() < until:
            self.gaps.append(link.heartbeat_age_s())
            time.sleep(0.005)
        restarts = len(self.supervisor.restarts)
        killed_s = time.monotonic()
        os.kill(link.process.pid, signal.SIGKILL if mode == "dead" else signal.SIGSTOP)
        zero = _wait(lambda: (s := self.state())["zero_since_monotonic_s"] and s, 30, "0 V at the stage")
        _wait(lambda: len(self.supervisor.restarts) > restarts, 120, "a fresh engine")
        worker.join(30)
        figures = self.supervisor.restarts[-1]
        expired = zero["watchdog"]["expired_at_monotonic_s"]
        by_watchdog = expired is not None and expired <= zero["zero_since_monotonic_s"]
        return {
            "engine_death_to_zero_ms": (zero["zero_since_monotonic_s"] - killed_s) * 1e3,
            "engine_restart_s": figures["ready_monotonic_s"] - killed_s,
            "zeroed_by": "watchdog" if by_watchdog else "supervisor",
            # how late the stage's process noticed its expiry (the emulation's, not the device's)
            "stage_noticed_late_ms": zero["watchdog"]["acted_late_s"] * 1e3 if by_watchdog else None,
        }

    def close(self) -> None:
        self.supervisor.close()
        self.bench.close()
        self.stage.close()
        self.proc.kill()
        self.proc.wait(10)


def _summary(rows: list[dict]) -> dict:
    z = np.array([r["engine_death_to_zero_ms"] for r in rows])
    r = np.array([r["engine_restart_s"] for r in rows])
    late = [row["stage_noticed_late_ms"] for row in rows if row["stage_noticed_late_ms"] is not None]
    return {
        "kills": len(rows),
        "engine_death_to_zero_ms": {"median": float(np.median(z)), "max": float(z.max()), "min": float(z.min())},
        "engine_restart_s": {"median": float(np.median(r)), "max": float(r.max()), "min": float(r.min())},
        "zeroed_by": sorted({row["zeroed_by"] for row in rows}),
        "stage_noticed_late_ms_max": max(late, default=None),
    }


def run_engine_death_benchmark(kills: int = KILLS) -> dict:
    """``kills`` deaths of each kind (dead, hung) with and without the stage's watchdog."""
    rng = random.Random(0)
    rig = _Rig()
    out: dict = {"watchdog_s": WATCHDOG_S, "hang_limit_s": HANG_LIMIT_S, "cases": {}}
    try:
        for mode in ("dead", "hung"):
            for watchdog in (True, False):
                rows = [rig.once(mode, watchdog, rng) for _ in range(kills)]
                name = f"{mode}_{'with_hardware_watchdog' if watchdog else 'supervisor_alone'}"
                out["cases"][name] = _summary(rows)
        gaps = np.array(rig.gaps) * 1e3
        out["pulse_gap_ms"] = {
            "samples": len(gaps),
            "p99": float(np.percentile(gaps, 99)),
            "max": float(gaps.max()),
        }
    finally:
        rig.close()
    return out
