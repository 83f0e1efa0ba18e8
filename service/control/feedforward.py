"""Inverse-model feedforward: identify hysteresis models on the bench by sine sweeps, invert them.

Any object with ``inverse(x_ref_um, sample_rate_hz=...) -> u_v`` is a feedforward model.
"""
from __future__ import annotations

import numpy as np

from drivers.bench import Bench
from service.hysteresis import DynamicPI, Series, StaticPI

SWEEP_FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)


def sweep_series(bench: Bench, axis: str, frequencies_hz=SWEEP_FREQUENCIES_HZ, cycles: int = 3,
                 sample_rate_hz: float = 20_000.0, v_max: float = 120.0) -> list[Series]:
    """0–v_max biased sines on one axis, one bench run per frequency (each from rest)."""
    out = []
    for f in frequencies_hz:
        bench.check_sine(axis, v_max, f)
        n = int(round(cycles * sample_rate_hz / f))
        t = np.arange(n) / sample_rate_hz
        u = 0.5 * v_max * (1 - np.cos(2 * np.pi * f * t))
        rec = bench.run({axis: u}, sample_rate_hz)
        out.append(Series(u, rec.x_um[axis], sample_rate_hz, label=f"{axis} {f:g} Hz"))
    return out


def identify(bench: Bench, axis: str, kind: str = "dynamic_pi", **sweep) -> StaticPI | DynamicPI:
    """Fit a static PI (1 Hz loop) or dynamic PI (1/10/50/100 Hz loops) on measured sweeps."""
    if kind == "static_pi":
        return StaticPI().fit(sweep_series(bench, axis, **{"frequencies_hz": (1.0,), **sweep}))
    series = sweep_series(bench, axis, **sweep)
    if kind == "dynamic_pi":
        return DynamicPI().fit(series)
    raise ValueError(f"kind: unknown model {kind!r}; use 'static_pi' or 'dynamic_pi'")


def feedforward_v(model, x_ref_um: np.ndarray, sample_rate_hz: float, v_limits=(0.0, 120.0)) -> np.ndarray:
    """The model's inverse for the reference (V), clipped to the actuator range; 0 V where x_ref = 0."""
    u = np.asarray(model.inverse(np.asarray(x_ref_um, dtype=float), sample_rate_hz=sample_rate_hz), dtype=float)
    if u.shape != np.shape(x_ref_um) or not np.all(np.isfinite(u)):
        raise ValueError("feedforward model returned a voltage of the wrong shape or non-finite values")
    return np.clip(u, *v_limits)
