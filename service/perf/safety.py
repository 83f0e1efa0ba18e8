"""Benchmark: how fast the bench reaches 0 V after a stop, a fault or a stalled loop.

    evcbench bench safety --json

Side by side, on the emulated default bench (latencies in emulated samples from the emulator's
output log, so the machine's speed does not enter; the watchdog's are wall-clock seconds):

* ``stop``: ``Bench.stop`` raised from another thread at a random moment of a buffered sweep (control
  period = one 2000-sample block) and of a point-by-point 100 Hz trajectory (period = 200 samples):
  ``samples_after_stop`` (stop flag up → 0 V write begins), in samples and in control periods.
* ``faults``: fault → 0 V write, in samples and control periods, for sensor dropout and saturation,
  amplifier over-current (sweep) and a sensor dropout in a trajectory.
* ``watchdog``: a stalled 100 Hz tracking loop (loop_stall) with ``[safety] watchdog_min_s`` at 0.1,
  0.25 and 1 s (4 periods = 40 ms, so the floor sets the timeout): measured last-write → 0 V time
  beside the configured timeout.
"""

from __future__ import annotations

import random
import threading
import time

import numpy as np

from drivers.bench import RUN_BLOCK_SAMPLES
from drivers.factory import open_bench
from drivers.record import RunInterrupted
from service.science.control.session import SAMPLE_RATE_HZ

FS = SAMPLE_RATE_HZ
BLOCK = RUN_BLOCK_SAMPLES  # a sweep's control period: one buffered block
TRAJECTORY_HZ = 100.0
PERIOD = round(FS / TRAJECTORY_HZ)  # a trajectory's control period: one ellipse period


def _sine(seconds: float, hz: float = 5.0) -> np.ndarray:
    t = np.arange(int(seconds * FS)) / FS
    return 60.0 - 60.0 * np.cos(2 * np.pi * hz * t)


def _sweep(bench, seconds: float) -> None:
    u = _sine(seconds)
    try:
        bench.run({"y": u, "z": u}, FS)
    except RunInterrupted:
        pass


def _trajectory(bench, cycles: int) -> None:
    from service.science.control.session import SCANNED_PID, Controller, track
    from service.science.control.trajectory import Ellipse

    track(bench, Ellipse((1, 6), (1, 11), 0.0, TRAJECTORY_HZ, cycles), Controller(pid=SCANNED_PID))


def _zero_after(world, t_s: float) -> float:
    """Emulated time the first 0 V write at or after ``t_s`` began."""
    return next(
        e["zero_from_t_s"]
        for e in world.output_log.entries()
        if e["event"] == "idle" and e["zero_from_t_s"] >= t_s - 1e-9
    )


def _stop_once(bench, run, period: int, rng: random.Random) -> dict:
    world, marks = bench.parts.world, []
    original = bench.request_stop

    def spy(reason="stopped on request"):
        marks.append(world.time_s)
        original(reason)

    bench.request_stop = spy
    try:
        worker = threading.Thread(target=run)
        worker.start()
        while not bench.running and worker.is_alive():
            time.sleep(0.001)
        time.sleep(0.05 + 0.15 * rng.random())
        t0 = time.perf_counter()
        answered = bench.stop("benchmark stop")
        wall_ms = (time.perf_counter() - t0) * 1e3
        worker.join()
    finally:
        del bench.request_stop
    samples = round((_zero_after(world, marks[0]) - marks[0]) * FS)
    return {"samples": samples, "periods": samples / period, "wall_ms": wall_ms, "answered": answered}


def _summary(runs: list[dict], period: int) -> dict:
    s = np.array([r["samples"] for r in runs])
    return {
        "control_period_samples": period,
        "runs": len(runs),
        "samples_after_stop_max": int(s.max()),
        "samples_after_stop_median": float(np.median(s)),
        "periods_max": float(s.max() / period),
        "stop_call_wall_ms_max": max(r["wall_ms"] for r in runs),
        "loop_answered": all(r["answered"] for r in runs),
    }


def stop_latency(repeats: int = 5) -> dict:
    rng = random.Random(0)
    bench = open_bench("default", seed=1)
    try:
        _trajectory(bench, 5)  # compile the point-by-point runner once, outside the measurement
        sweep = [_stop_once(bench, lambda: _sweep(bench, 60.0), BLOCK, rng) for _ in range(repeats)]
        traj = [_stop_once(bench, lambda: _trajectory(bench, 3000), PERIOD, rng) for _ in range(repeats)]
    finally:
        bench.close()
    return {"sweep": _summary(sweep, BLOCK), "trajectory_point_by_point": _summary(traj, PERIOD)}


def fault_latency() -> dict:
    out = {}
    cases = [
        ("sensor_dropout", "z", "sweep"),
        ("sensor_saturation", "y", "sweep"),
        ("amplifier_overcurrent", "y", "sweep"),
        ("sensor_dropout", "z", "trajectory"),
    ]
    for kind, axis, run in cases:
        bench = open_bench("default", seed=1)
        try:
            bench.parts.world.faults.add(kind, axis, 0.3137)
            if run == "sweep":
                _sweep(bench, 2.0)
            else:
                _trajectory(bench, 60)
            (fault,) = bench.parts.world.faults.list()
            samples = round((_zero_after(bench.parts.world, fault["world_t_s"]) - fault["world_t_s"]) * FS)
            period = BLOCK if run == "sweep" else PERIOD
            out[f"{kind}_{run}"] = {"samples": samples, "periods": samples / period, "control_period_samples": period}
        finally:
            bench.close()
    return out


def watchdog_latency() -> list[dict]:
    rows = []
    for configured_s in (0.1, 0.25, 1.0):
        bench = open_bench(
            "default",
            seed=1,
            overrides={"safety": {"watchdog_min_s": configured_s}, "faults": {"loop_stall": {"after_s": 0.3}}},
        )
        try:
            _trajectory(bench, 60)
            trip = bench.watchdog.last_trip
            rows.append(
                {
                    "watchdog_min_s": configured_s,
                    "periods": bench.safety.watchdog_periods,
                    "period_s": bench.watchdog.period_s,
                    "timeout_s": trip["timeout_s"],
                    "measured_s": trip["stalled_s"],
                    "ratio": trip["stalled_s"] / trip["timeout_s"],
                }
            )
        finally:
            bench.close()
    return rows


def run_safety_benchmark() -> dict:
    """Stop, fault and watchdog latencies side by side (see the module docstring), a dead or hung
    bench engine (service.perf.engine_death), then the stop and a sweep with the service under load
    (service.perf.safety_load)."""
    from service.perf.engine_death import run_engine_death_benchmark
    from service.perf.safety_load import run_safety_under_load

    return {
        "engine_death": run_engine_death_benchmark(),
        "stop": stop_latency(),
        "faults": fault_latency(),
        "watchdog": watchdog_latency(),
        "sample_rate_hz": FS,
        "under_load": run_safety_under_load(),
    }
