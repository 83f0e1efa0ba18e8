"""Safety checks before a trajectory runs: modes the backend can run, current, slew, resonance,
voltage and sensor range. Each refusal is a ``ControlRefused`` naming the field and the reason."""

from __future__ import annotations

import numpy as np

from drivers.bench import Bench
from drivers.interfaces import LimitError
from service.science.errors import FieldError

#: A hysteresis-only feedforward ignores the flexure's dynamic gain (+13 % at 100 Hz on Z), so a demand
#: up to this factor beyond the axis's voltage limit is clipped (feedback/ILC make up the rest); beyond it, refused.
VOLTAGE_MARGIN = 1.2


class ControlRefused(FieldError):
    """The request cannot run on this bench: ``field`` names the request field at fault (as data),
    ``reason`` (the FieldError's ``message``) says why."""

    @property
    def reason(self) -> str:
        return self.message


def stepping_hook(bench: Bench):
    """The DAQ's optional compiled stepping hook ``(step_fn, args, take_noise)``, or None."""
    hook = getattr(bench.parts.daq, "stepping_hook", None)
    return hook() if callable(hook) else None


def available_modes(bench: Bench) -> dict[str, str | None]:
    """Mode → None if offered, else the reason it is not."""
    caps = bench.parts.daq.capabilities
    pbp = None
    if not caps.point_by_point:
        pbp = caps.point_by_point_reason or "this DAQ has no point-by-point mode"
    elif not bench.compiled_stepping:
        pbp = "this DAQ offers no compiled stepping hook, so a 20 kHz per-sample loop cannot run in real time"
    return {"point_by_point": pbp, "buffered": None if caps.buffered else "this DAQ has no buffered streaming mode"}


def check_mode(bench: Bench, mode: str, pid: bool) -> None:
    """Refuse a mode the backend cannot run, and per-sample PID in buffered streaming."""
    modes = available_modes(bench)
    if mode not in modes:
        raise ControlRefused("mode", f"unknown mode {mode!r}; use point_by_point or buffered")
    if modes[mode] is not None:
        raise ControlRefused("mode", f"{mode} is not available on {bench.parts.backend}: {modes[mode]}")
    if mode == "buffered" and pid:
        raise ControlRefused(
            "controller.pid",
            "per-sample PID needs point-by-point mode: buffered streaming "
            "returns each measurement a block (one period or more) after the command left, so "
            "feedback every sample is impossible; use ilc (it learns between periods)",
        )


def check_trajectory(
    bench: Bench,
    x_ref_um: np.ndarray,
    u_ff_v: np.ndarray | None,
    frequency_hz: float,
    steady: slice = slice(None),
    mode_axes: frozenset = frozenset(),
) -> None:
    """Refuse a reference outside the sensor range, a feedforward beyond the axis's voltage limits
    (``bench.limits``, the stack's rating), or a drive whose
    current, slew or frequency the amplifier and flexure cannot take (Bench.check_sine, at the
    feedforward's Vpp or, without one, the full range). Voltages are checked over ``steady`` samples
    (the start ramp may ask for less than 0 V near 0 µm; the clamp holds it at 0 V). The axes of
    ``mode_axes`` have a feedforward that inverts their identified mode: their voltage, current and
    slew are judged on the drive itself (service.science.control.demand, then ``check_stroke``), not by
    the sine rule of thumb."""
    for i, axis in enumerate(bench.axes):
        field = f"{axis}_range_um"
        lo, hi = bench.parts.sensors[axis].range_um
        top = float(np.max(x_ref_um[:, i]))
        if not (top <= 0.95 * hi and float(np.min(x_ref_um[:, i])) >= lo):  # NaN fails too
            raise ControlRefused(field, f"{axis} reference reaches {top:.2f} µm; the gauge reads {lo:g}–{hi:g} µm")
        v_min, v_max = bench.limits[axis].v_min_v, bench.limits[axis].v_max_v
        vpp = v_max - v_min
        if axis in mode_axes and u_ff_v is not None:
            continue
        if u_ff_v is not None:
            u = u_ff_v[steady, i]
            slack = vpp * (VOLTAGE_MARGIN - 1)
            if np.max(u) > v_max + slack or np.min(u) < v_min - slack:
                raise ControlRefused(
                    field,
                    f"{axis} reference needs {np.min(u):.1f}–{np.max(u):.1f} V by the "
                    f"feedforward model; the actuator limit is {v_min:g}–{v_max:g} V",
                )
            vpp = max(float(np.ptp(u)), 1.0)
        try:
            bench.check_sine(axis, vpp, frequency_hz)
        except LimitError as exc:
            raise ControlRefused("frequency_hz", f"axis {axis}: {exc}") from None


#: a feedforward demand this far (V) beyond the actuator range is within the model's error; beyond it,
#: the requested range is outside the stroke the axis can reach at this frequency
STROKE_TOLERANCE_V = 1.0


def model_stroke_um(model, sample_rate_hz: float, v_max: float) -> float:
    """The stack's displacement (µm) at ``v_max`` reached quasi-statically (0 → v_max in 0.5 s), as the
    feedforward model predicts it."""
    n = int(sample_rate_hz / 2)
    slow = 0.5 * v_max * (1 - np.cos(np.pi * np.arange(n) / n))
    return float(np.max(model.predict(slow, sample_rate_hz=sample_rate_hz)))


def _beyond_text(axis, range_um, frequency_hz, x_ref_um, u, model, sample_rate_hz, steady, v_min, v_max) -> str:
    """Why the feedforward demand ``u`` (V) leaves [``v_min``, ``v_max``], naming the end of the range
    (µm) that is beyond it: the top (the stroke at ``v_max``) or the bottom (below ``v_min``)."""
    lo, hi = range_um
    parts = []
    if np.max(u) > v_max + STROKE_TOLERANCE_V:
        need = float(np.max(model.stack_demand_um(x_ref_um, sample_rate_hz)[steady]))
        via = (
            f" (through the model's flexure dynamics, the stack must deliver {need:.2f} µm)"
            if model.judges_stroke
            else " (by a model without flexure dynamics, which overstates the voltage near a resonance)"
        )
        parts.append(
            f"the top end {hi:g} µm needs {np.max(u):.1f} V by the feedforward model{via}, above the axis's "
            f"{v_max:g} V limit; the axis reaches {model_stroke_um(model, sample_rate_hz, v_max):.2f} µm at "
            f"{v_max:g} V, so the range is beyond the stroke"
        )
    if np.min(u) < v_min - STROKE_TOLERANCE_V:
        parts.append(
            f"the bottom end {lo:g} µm needs {np.min(u):.1f} V by the feedforward model, below the axis's "
            f"{v_min:g} V limit: raise the range's minimum"
        )
    return f"{axis.upper()} {lo:g}–{hi:g} µm at {frequency_hz:g} Hz: " + "; ".join(parts)


def check_stroke(
    bench: Bench,
    ranges_um: dict,
    frequency_hz: float,
    x_ref_um: np.ndarray,
    u_ff_v: np.ndarray,
    models: dict,
    sample_rate_hz: float,
    steady: slice = slice(None),
) -> tuple[dict[str, str], list[str]]:
    """(refusals {axis: reason}, warnings): per axis, why a requested range lies beyond what the axis can reach
    within its actuator limits (``bench.limits``), judged by the feedforward model's demand over
    the ``steady`` samples.

    What the stack must deliver is the reference seen through the inverse of the model's linear
    transforms (``stack_demand_um``: a flexure mode above the drive frequency amplifies the
    fundamental, so the stack needs less than the reference). Only a model with those dynamics
    (``judges_stroke``) can judge that, so only its verdict is a refusal; a hysteresis-only model
    ignores the mode's gain (+13 % at 100 Hz on Z here) and its verdict is a warning."""
    refusals, warnings = {}, []
    for i, axis in enumerate(bench.axes):
        u = u_ff_v[steady, i]
        model = models.get(axis)
        v_min, v_max = bench.limits[axis].v_min_v, bench.limits[axis].v_max_v
        if model is None or (np.max(u) <= v_max + STROKE_TOLERANCE_V and np.min(u) >= v_min - STROKE_TOLERANCE_V):
            continue
        text = _beyond_text(
            axis, ranges_um[axis], frequency_hz, x_ref_um[:, i], u, model, sample_rate_hz, steady, v_min, v_max
        )
        if model.judges_stroke:
            refusals[axis] = text
        else:
            warnings.append(text)
    return refusals, warnings
