"""Speed of the emulated two-axis chain, measured side by side in one run.

- point: a compiled loop that steps the world one sample at a time, each AO sample computed
  from the previous AI sample (causal PI control of both axes), as a real-time target or the
  compiled closed-loop runner would;
- buffered: ``EmulatedDaq.write_read`` on whole blocks (what ``Bench.run`` does);
- point_python: ``EmulatedDaq.step`` called from Python once per sample.

Numba compilation is excluded (one warm-up call); each figure is the best of a few repeats.
``families`` repeats the compiled modes with each hysteresis family switched in on the same bench.
"""

from __future__ import annotations

import time

import numpy as np

REALTIME_RATE_HZ = 20000.0


def _best(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _compiled_modes(bench: str, overrides: dict | None, ref: np.ndarray, ao: np.ndarray, repeats: int):
    """(bench, best closed-loop seconds, best buffered seconds) on a fresh bench."""
    from drivers.factory import open_bench

    b = open_bench(bench, seed=0, overrides=overrides)
    world, daq = b.parts.world, b.parts.daq
    daq.configure(REALTIME_RATE_HZ)
    world.closed_loop(ref[:100], 0.5, 2000.0)  # compile/warm up
    daq.write_read(ao[:100])
    daq.step([0.0, 0.0])
    daq.write_idle()
    t_point = _best(lambda: world.closed_loop(ref, 0.5, 2000.0), repeats)
    daq.write_idle()
    t_buf = _best(lambda: daq.write_read(ao), repeats)
    daq.write_idle()
    return b, t_point, t_buf


def run_emulator_benchmark(seconds: float = 2.0, bench: str = "default", repeats: int = 3) -> dict:
    """Samples per second of the emulator at 20 kHz for ``seconds`` of emulated time per mode."""
    from drivers.emulated.kernels import FAMILIES

    n = max(int(seconds * REALTIME_RATE_HZ), 100)
    t = np.arange(n) / REALTIME_RATE_HZ
    ref = np.column_stack([3.0 - 2.5 * np.cos(2 * np.pi * 100 * t), 4.5 - 4.0 * np.sin(2 * np.pi * 100 * t)])
    ao = np.column_stack([3.0 - 3.0 * np.cos(2 * np.pi * 100 * t)] * 2)  # 0–120 V at the actuator
    b, t_point, t_buf = _compiled_modes(bench, None, ref, ao, repeats)
    daq = b.parts.daq
    family = b.parts.config["axes"]["y"]["piezo"]["hysteresis"].get("family", "preisach")
    families = {
        family: {
            "realtime_factor_point": n / t_point / REALTIME_RATE_HZ,
            "realtime_factor_buffered": n / t_buf / REALTIME_RATE_HZ,
        }
    }
    for other in FAMILIES:
        if other not in families:
            fb, tp, tb = _compiled_modes(bench, {"axes.*.piezo.hysteresis.family": other}, ref, ao, repeats)
            fb.close()
            families[other] = {
                "realtime_factor_point": n / tp / REALTIME_RATE_HZ,
                "realtime_factor_buffered": n / tb / REALTIME_RATE_HZ,
            }
    n_py = min(n, 20000)
    rows = ao[:n_py].tolist()

    def python_steps():
        step = daq.step
        for row in rows:
            step(row)

    t_py = _best(python_steps, max(1, repeats - 1))
    b.close()
    sps_point = n / t_point
    return {
        "bench": bench,
        "sample_rate_hz": REALTIME_RATE_HZ,
        "samples": n,
        "samples_per_s_point": sps_point,
        "samples_per_s_buffered": n / t_buf,
        "samples_per_s_point_python": n_py / t_py,
        "realtime_factor_point": sps_point / REALTIME_RATE_HZ,
        "realtime_factor_buffered": n / t_buf / REALTIME_RATE_HZ,
        "realtime_factor_point_python": n_py / t_py / REALTIME_RATE_HZ,
        "buffered_over_point": (n / t_buf) / sps_point,
        "point_over_point_python": sps_point / (n_py / t_py),
        "families": {f: {k: round(v, 2) for k, v in fig.items()} for f, fig in families.items()},
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run_emulator_benchmark(), indent=2))
