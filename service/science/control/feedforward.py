"""Inverse-model feedforward: identify hysteresis models on the bench by sine sweeps, invert them.

Any object with ``inverse(x_ref_um, sample_rate_hz=...) -> u_v`` is a feedforward model.
"""
from __future__ import annotations

import numpy as np

from drivers.bench import Bench
from service.science.models import DynamicPI, Series, StaticPI

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


#: a feedforward drive whose model, run forward, misses the reference by more than this share of
#: the reference's range (RMS) is refused: the inverse did not converge
INVERSE_TOLERANCE_SHARE = 0.05


def inverse_miss_um(model, u_v: np.ndarray, x_ref_um: np.ndarray, sample_rate_hz: float,
                    steady: slice) -> float | None:
    """RMS (µm) by which the model's own prediction of its feedforward drive ``u_v`` misses the
    reference over ``steady`` (None if the model cannot predict): a check that the inverse converged.
    The paper's dynamic PI inverse does not at 50–100 Hz (its segment-switched weights make the
    answer step; see service/science/models/inverse.py)."""
    predict = getattr(model, "predict", None)
    if predict is None:
        return None
    back = np.asarray(predict(np.asarray(u_v, dtype=float), sample_rate_hz), dtype=float)
    return float(np.sqrt(np.mean((back[steady] - np.asarray(x_ref_um)[steady]) ** 2)))


#: the composite model used as feedforward: hysteresis + delay + flexure dynamics. On the default
#: bench (case 2, FF + tuned PID) adding asymmetry, creep or rate dependence to these made the
#: tracking worse (2.1 % → 2.2 %, 4.2 %, 11.9 %): their columns, fitted on sine sweeps, extrapolate
#: badly to the ellipse's minor loops, and the rate terms make the fixed point overshoot on Z.
COMPOSITE_EFFECTS = ("delay", "dynamics")


def identify_composite(bench: Bench, axis: str, effects=COMPOSITE_EFFECTS, frequencies_hz=SWEEP_FREQUENCIES_HZ,
                       cycles: int = 5, n_operators: int = 10, v_range=(0.0, 120.0)):
    """Fit a discovery composite model (hysteresis + ``effects``) on a 0–120 V sine sweep of one axis
    between ``v_range`` (V) run on ``bench`` (the discovery path: service.usecases.plans plan, service.science.discovery records and fit);
    returns it wrapped as a feedforward model."""
    from service.science.discovery.composite import fit_composite
    from service.science.discovery.records import _arrays, records_from_arrays
    from service.usecases.plans import SinePlan, plan_for_bench, trim_blocks

    planned = plan_for_bench(SinePlan(axes=(axis,), frequencies_hz=tuple(frequencies_hz), cycles=cycles,
                                           v_min=float(v_range[0]), v_max=float(v_range[1])), bench)
    rec = bench.run(planned.u_v, planned.sample_rate_hz)
    blocks = trim_blocks(planned.blocks, rec.samples, rec.sample_rate_hz)
    (record,) = records_from_arrays(_arrays(rec), rec.sample_rate_hz, blocks, (axis,), f"{axis}:")
    return as_feedforward(fit_composite([record], list(effects), n_operators))


def as_feedforward(model):
    """A stored model object as a feedforward model: composite models get their harmonic/fixed-point
    inverse (service.science.control.composite_ff); hysteresis models already have ``inverse``."""
    if getattr(model, "name", None) == "composite":
        from service.science.control.composite_ff import CompositeFeedforward

        return CompositeFeedforward(model)
    return model


def identify_composite_for(bench: Bench, ellipse, effects=COMPOSITE_EFFECTS, margin_v: float = 5.0,
                           sample_rate_hz: float = 20_000.0) -> dict:
    """Composite feedforward models per axis fitted on the voltages ``ellipse`` needs: a full-range
    (0–120 V) fit gives the drive span of the reference's steady part, then each axis is swept again
    over that span ± ``margin_v`` (V) and refitted. The stack's minor loops inside the span differ
    from the major loop's branches (Preisach memory), which a PI fitted on 0–120 V cannot capture."""
    from service.science.control.trajectory import reference

    ref = reference(ellipse, sample_rate_hz)
    steady = ref.steady
    out = {}
    for i, axis in enumerate(bench.axes):
        full = identify_composite(bench, axis, effects)
        u = full.inverse(ref.x_um[steady, i], sample_rate_hz=sample_rate_hz)
        span = (max(0.0, float(np.min(u)) - margin_v), min(120.0, float(np.max(u)) + margin_v))
        out[axis] = identify_composite(bench, axis, effects, v_range=span)
        out[axis].fit_range_v = span
    return out
