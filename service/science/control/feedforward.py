"""Inverse-model feedforward: identify hysteresis models on the bench by sine sweeps, invert them.

A feedforward model is any model of the contract (service.science.models.contract): its
``inverse`` gives the drive, its ``predict`` checks that the inverse converged, its
``stack_demand_um`` and ``judges_stroke`` serve the stroke check (service.science.control.safety).
"""

from __future__ import annotations

import numpy as np

from drivers.bench import Bench
from service.science.data.plans import SinePlan
from service.science.data.record import Record
from service.science.discovery.composite import fit_composite
from service.science.discovery.records import run_records
from service.science.fitting.metrics import rms
from service.science.models import PAPER_MODELS, HysteresisModel

SWEEP_FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)
#: the loops the paper identifies each of its models on: the static PI on the 1 Hz loop (eq. 9's QP),
#: the rate-dependent ones on all four
PAPER_LOOPS_HZ = {"static_pi": (1.0,), "dynamic_pi": SWEEP_FREQUENCIES_HZ, "grpi": SWEEP_FREQUENCIES_HZ}


def sine_loops(
    bench: Bench,
    axis: str,
    frequencies_hz=SWEEP_FREQUENCIES_HZ,
    cycles: int = 3,
    sample_rate_hz: float = 20_000.0,
    v_max: float = 120.0,
) -> list[Record]:
    """0–v_max biased sines on one axis, one bench run per frequency (each from rest)."""
    out = []
    for f in frequencies_hz:
        bench.check_sine(axis, v_max, f)
        n = int(round(cycles * sample_rate_hz / f))
        t = np.arange(n) / sample_rate_hz
        u = 0.5 * v_max * (1 - np.cos(2 * np.pi * f * t))
        rec = bench.run({axis: u}, sample_rate_hz)
        out.append(Record(u, rec.x_um[axis], sample_rate_hz, label=f"{axis} {f:g} Hz"))
    return out


def identify(bench: Bench, axis: str, kind: str = "dynamic_pi", **sweep) -> HysteresisModel:
    """Fit one of the paper's models on measured sweeps of the loops it is identified on
    (PAPER_LOOPS_HZ: the static PI on 1 Hz, the dynamic PI and GRPI on 1/10/50/100 Hz)."""
    if kind not in PAPER_MODELS:
        raise ValueError(f"kind: unknown model {kind!r}; use one of {', '.join(PAPER_MODELS)}")
    return PAPER_MODELS[kind]().fit(sine_loops(bench, axis, **{"frequencies_hz": PAPER_LOOPS_HZ[kind], **sweep}))


def feedforward_v(model, x_ref_um: np.ndarray, sample_rate_hz: float, v_limits=(-np.inf, np.inf)) -> np.ndarray:
    """The model's inverse for the reference (V), clipped to ``v_limits`` (V; none by default: the
    safety checks judge a demand beyond the actuator's limits)."""
    u = np.asarray(model.inverse(np.asarray(x_ref_um, dtype=float), sample_rate_hz=sample_rate_hz), dtype=float)
    if u.shape != np.shape(x_ref_um) or not np.all(np.isfinite(u)):
        raise ValueError("feedforward model returned a voltage of the wrong shape or non-finite values")
    return np.clip(u, *v_limits)


#: a feedforward drive whose model, run forward, misses the reference by more than this share of
#: the reference's range (RMS) is refused: the inverse did not converge
INVERSE_TOLERANCE_SHARE = 0.05


def inverse_miss_um(model, u_v: np.ndarray, x_ref_um: np.ndarray, sample_rate_hz: float, steady: slice) -> float:
    """RMS (µm) by which the model's own prediction of its feedforward drive ``u_v`` misses the
    reference over ``steady``: a check that the inverse converged. The paper's dynamic PI inverse
    does not at 50–100 Hz (its segment-switched weights make the answer step; see
    service/science/models/inverse.py)."""
    back = np.asarray(model.predict(np.asarray(u_v, dtype=float), sample_rate_hz=sample_rate_hz), dtype=float)
    return rms(back[steady] - np.asarray(x_ref_um)[steady])


#: the composite model used as feedforward: hysteresis + delay + flexure dynamics. On the default
#: bench (case 2, FF + tuned PID) adding asymmetry, creep or rate dependence to these made the
#: tracking worse (2.1 % → 2.2 %, 4.2 %, 11.9 %): their columns, fitted on sine sweeps, extrapolate
#: badly to the ellipse's minor loops, and the rate terms make the fixed point overshoot on Z.
COMPOSITE_EFFECTS = ("delay", "dynamics")


def sweep_record(bench: Bench, axis: str, frequencies_hz=SWEEP_FREQUENCIES_HZ, cycles: int = 5, v_range=(0.0, 120.0)):
    """One axis's sine sweep between ``v_range`` (V) at ``frequencies_hz``, ``cycles`` each, run on
    ``bench`` as one record (the discovery path: service.science.discovery.records.run_records)."""
    sweep = SinePlan(
        axes=(axis,),
        frequencies_hz=tuple(frequencies_hz),
        cycles=cycles,
        v_min=float(v_range[0]),
        v_max=float(v_range[1]),
    )
    return run_records(bench, sweep, f"{axis}:")[axis]


def identify_composite(
    bench: Bench,
    axis: str,
    effects=COMPOSITE_EFFECTS,
    frequencies_hz=SWEEP_FREQUENCIES_HZ,
    cycles: int = 5,
    n_operators: int = 10,
    v_range=(0.0, 120.0),
):
    """Fit a discovery composite model (hysteresis + ``effects``) on ``sweep_record`` of one axis
    (the paper's 0–120 V by default)."""
    return fit_composite([sweep_record(bench, axis, frequencies_hz, cycles, v_range)], list(effects), n_operators)


#: the margin (V) a span sweep adds on each side of the drive a trajectory needs
SPAN_MARGIN_V = 5.0


def drive_span_v(
    model,
    x_ref_um: np.ndarray,
    sample_rate_hz: float,
    limits_v: tuple[float, float],
    margin_v: float = SPAN_MARGIN_V,
    steady: slice = slice(None),
) -> tuple[float, float]:
    """(min, max) V of the model's feedforward drive for the planned reference ``x_ref_um`` (from rest
    to rest, as the run drives it) over its ``steady`` samples, widened by ``margin_v`` on each side
    and kept within ``limits_v`` (the axis's hard limits): the span to sweep so that a model fitted on
    it knows the minor loops the trajectory runs. The inverse is taken over the whole planned
    reference: its steady part alone starts mid-stroke, which the inverse's spectral division of the
    mode and its hysteresis state from rest read as a jump (at 200 Hz on Z: 5–136 V for a 26–90 V drive)."""
    u = np.asarray(model.inverse(np.asarray(x_ref_um, dtype=float), sample_rate_hz=sample_rate_hz), dtype=float)
    u = u[steady]
    return max(limits_v[0], float(np.min(u)) - margin_v), min(limits_v[1], float(np.max(u)) + margin_v)


def identify_composite_for(
    bench: Bench, ellipse, effects=COMPOSITE_EFFECTS, margin_v: float = SPAN_MARGIN_V, sample_rate_hz: float = 20_000.0
) -> dict:
    """Composite feedforward models per axis fitted on the voltages ``ellipse`` needs: a full-range
    (0–120 V) fit gives the drive span of the reference's steady part, then each axis is swept again
    over that span ± ``margin_v`` (V) and refitted (each model's ``fit_range_v`` says the span). The
    stack's minor loops inside the span differ from the major loop's branches (Preisach memory),
    which a PI fitted on 0–120 V cannot capture."""
    from service.science.control.trajectory import reference

    ref = reference(ellipse, sample_rate_hz)
    steady = ref.steady
    out = {}
    for i, axis in enumerate(bench.axes):
        full = identify_composite(bench, axis, effects)
        lim = bench.limits[axis]
        span = drive_span_v(full, ref.x_um[:, i], sample_rate_hz, (lim.v_min_v, lim.v_max_v), margin_v, steady)
        out[axis] = identify_composite(bench, axis, effects, v_range=span)
        out[axis].fit_range_v = span
    return out


#: a trained block knows a trajectory's loop when each of its turning points (the drive's min and max)
#: lies within this fraction of the trajectory's swing of the trajectory's own. Preisach memory: a loop's
#: branches are set by its turning points, and a fit sees only the loops it is given.
TURNING_POINT_TOLERANCE = 0.25


def untrained_turning_points(loops_v, axis: str, needed_v: tuple[float, float]) -> str | None:
    """Why a model trained on ``loops_v`` (``trained_loops_v``) extrapolates a trajectory's loop on
    ``axis``, or None.

    ``needed_v``: (min, max) V of the trajectory's drive. A trained loop covers it when its min and max
    each lie within TURNING_POINT_TOLERANCE × the trajectory's swing of the trajectory's. The message
    names the closest trained loop and the way to identify on the span."""
    lo, hi = needed_v
    needed_pp = hi - lo
    if not loops_v or needed_pp <= 0:
        return None
    distance = [max(abs(a - lo), abs(b - hi)) for a, b in loops_v]
    if min(distance) <= TURNING_POINT_TOLERANCE * needed_pp:
        return None
    a, b = loops_v[int(np.argmin(distance))]
    return (
        f"{axis.upper()}: this trajectory drives {lo:.0f}–{hi:.0f} V, but the feedforward model was fitted on "
        f"loops whose turning points are {min(distance):.0f} V or more away from those (closest "
        f"{a:.0f}–{b:.0f} V). A piezo's minor loops depend on their turning points, so this one is "
        f"extrapolated: identify on the sweeps POST /api/trajectories/span-sweeps offers (the Trajectories "
        f'page\'s "Prepare the models it needs")'
    )
