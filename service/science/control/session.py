"""One tracking experiment end to end: reference, safety checks, feedforward, ILC learning filter
(measured on the bench), the run, and the metrics. Used by the API, the report and the benchmark."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.bench import Bench
from service.science import paper
from service.science.control.demand import VOLTAGE_TOLERANCE_V, demand_refusal, predict_demand
from service.science.control.feedforward import INVERSE_TOLERANCE_SHARE, feedforward_v, inverse_miss_um
from service.science.control.ilc import HarmonicILC, frf_from_periods, multisine
from service.science.control.ilc_stability import (
    learning_diagnosis,
    measured_factor,
    prior_scale,
    scaled_response,
    trajectory_gain_um_per_v,
)
from service.science.control.loop import SETTLE_S, PIDGains, StopRequested, Tracker, TrackRecord
from service.science.control.periodic_inverse import periodic_drive_v
from service.science.control.safety import (
    ControlRefused,
    check_mode,
    check_stroke,
    check_trajectory,
    model_stroke_um,
)
from service.science.control.trajectory import Ellipse, Reference, reference
from service.science.data.units import fmt_nm
from service.science.fitting.metrics import rms

SAMPLE_RATE_HZ = 20_000.0
PAPER_PID = {axis: PIDGains(**gains) for axis, gains in paper.PID_GAINS.items()}
#: Gains chosen on the emulated default bench by a tracking scan (issue 6; kd damps the 291 Hz Z mode;
#: the paper's loop gain of ~4 V/µm × 0.09 µm/V makes that mode unstable here, and the divergence
#: watch trips it). The report's rows use them; a request's "tuned" preset is service.science.control.tuning's.
SCANNED_PID = {"y": PIDGains(kp=1.0, ki=300.0, kd=0.01, tf_s=2e-4), "z": PIDGains(kp=1.0, ki=300.0, kd=0.01, tf_s=2e-4)}
#: A gentler PID under ILC: it damps the flexure modes and rejects drift; the ILC does the tracking.
ILC_PID = {"y": PIDGains(kp=0.5, ki=300.0, kd=0.005, tf_s=2e-4), "z": PIDGains(kp=0.5, ki=300.0, kd=0.005, tf_s=2e-4)}


@dataclass
class Controller:
    """Feedforward models per axis (models of service.science.models.contract; None = no FF), PID gains per axis
    (None = no PID), ILC on/off with its gain, harmonics and the periods it may learn for."""

    feedforward: dict[str, object] = field(default_factory=dict)
    pid: dict[str, PIDGains] | None = None
    ilc: bool = False
    ilc_gain: float = 0.2
    ilc_harmonics: int = 20
    #: axis → the highest harmonic that axis learns (the robustness filter, ilc_stability.predict_learning); None: all
    ilc_axis_harmonics: dict | None = None
    #: the PID's choice and predicted margins (service.science.control.gains.choose_pid), for the result
    pid_report: dict | None = None
    #: the ILC's predicted convergence per axis (service.science.control.ilc_stability), for the result
    ilc_report: dict | None = None
    #: run a range beyond the stroke anyway (commands clamped at the axis's limits; the reason becomes a warning)
    allow_saturation: bool = False
    #: axis → the feedforward model's identified flexure mode (Hz, damping ratio) or None
    modes: dict = field(default_factory=dict)
    #: the axes whose feedforward inverts the identified mode (service.science.control.tuning.feedforward_inverts_mode):
    #: their drive's demand is predicted (service.science.control.demand) instead of the 0.5 × f_r rule
    mode_axes: frozenset = frozenset()
    #: per axis, the predicted demand of the planned drive (``AxisDemand.as_dict``), for the result
    demand: dict | None = None
    #: axis → the identified model's gain (µm/V) along the planned drive: the learning's prior, measured
    #: with a small probe, is scaled to it (ilc_stability.prior_scale); the κ applied, for the result
    trajectory_gain: dict | None = None
    ilc_gain_scale: dict | None = None
    #: (reference, feedforward V, warnings) as ``plan`` made them where the request was checked, so that
    #: the bench's process does not compute the drive again (seconds for a long run, the stop port waiting)
    planned: tuple[Reference, np.ndarray | None, list[str]] | None = None


def measure_response(
    bench: Bench,
    period: int,
    harmonics: int,
    bias_v: np.ndarray,
    centre_um: np.ndarray,
    mode: str,
    pid: dict[str, PIDGains] | None,
    amplitude_v: float = 10.0,
    periods: int = 16,
) -> tuple[np.ndarray, np.ndarray]:
    """G(k) (2, K+1) µm/V from the feedforward input to the gauges, and the noise variance σ² (2,) µm²
    of one period's normalised DFT per axis: a multisine on top of ``bias_v`` in the same loop (PID
    or not) that the ILC will learn in; reference held at ``centre_um``."""
    ramp = 4
    n = (ramp + periods) * period
    env = np.ones(n)
    w = 0.5 - 0.5 * np.cos(np.pi * np.arange(ramp * period) / (ramp * period))
    env[: ramp * period] = w
    ms = np.stack([multisine(period, harmonics, amplitude_v, seed=i) for i in range(2)], axis=1)
    inj = np.tile(ms, (ramp + periods, 1)) * env[:, None]
    u = env[:, None] * bias_v[None, :] + inj
    ref = Reference(
        x_um=env[:, None] * centre_um[None, :],
        envelope=env,
        sample_rate_hz=SAMPLE_RATE_HZ,
        period=period,
        ramp_periods=ramp,
        cycles=periods - ramp,
    )  # ramp in, no ramp out
    trip = np.array([[1e3, 1e9, 0.98 * bench.parts.sensors[a].range_um[1]] for a in bench.axes])
    rec = Tracker(bench, ref, u, mode=mode, pid=pid, trip=trip).run()
    if rec.stopped:  # an emergency stop or a signal: the tracking run must not start afterwards
        raise StopRequested(rec.stop_reason or "stopped on request")
    if rec.tripped:
        raise RuntimeError(f"response measurement stopped: {rec.tripped}")
    s = (ramp + 4) * period
    fits = [frf_from_periods(inj[s:, i], rec.x_um[s:n, i], period, harmonics) for i in range(2)]
    return np.stack([g for g, _ in fits]), np.array([var for _, var in fits])


def probe_amplitude_v(controller: Controller) -> float:
    """The peak (V) of the multisine that measures the learning's response: smaller under a PID."""
    return 10.0 if controller.pid is None else 4.0


def trajectory_gains(bench: Bench, ref: Reference, u_ff: np.ndarray, controller: Controller) -> dict:
    """axis → the identified model's gain (µm/V) along the planned drive (ilc_stability.trajectory_gain_um_per_v)."""
    return {
        axis: trajectory_gain_um_per_v(controller.feedforward[axis], u_ff[:, i], ref.steady, SAMPLE_RATE_HZ)
        for i, axis in enumerate(bench.axes)
        if controller.feedforward.get(axis) is not None
    }


def metrics(rec: TrackRecord, ref: Reference, v_limits: np.ndarray, eval_periods: int = 5) -> dict:
    """Max error per axis, RMS and relative error (max over axes of max|e| / reference p-p) over the
    last ``eval_periods`` steady periods; ``command_at_limit_pct``: the share of commands at the
    axes' voltage limits ``v_limits`` (2, 2) [[min, max] V per axis]."""
    end = (ref.ramp_periods + ref.cycles) * ref.period
    start = max(ref.ramp_periods * ref.period, end - eval_periods * ref.period)
    e = ref.x_um[start:end] - rec.x_um[start:end]
    pp = np.ptp(ref.steady_period(), axis=0)
    mx = np.max(np.abs(e), axis=0)
    return {
        "max_error_y_um": float(mx[0]),
        "max_error_z_um": float(mx[1]),
        "rms_error_um": rms(e),
        "rms_error_y_um": rms(e[:, 0]),
        "rms_error_z_um": rms(e[:, 1]),
        "relative_error_pct": float(100 * np.max(mx / pp)),
        "evaluated_periods": int((end - start) // ref.period),
        "command_max_v": {a: float(np.max(rec.u_v[start:end, i])) for i, a in enumerate("yz")},
        "command_at_limit_pct": float(
            100 * np.mean((rec.u_v[start:end] >= v_limits[:, 1] - 1e-3) | (rec.u_v[start:end] <= v_limits[:, 0] + 1e-3))
        ),
    }


#: why an inverse misses, unless the model says so itself (its ``inverse_advice``)
INVERSE_ADVICE = (
    "The model's output is not monotone in the drive along this reference (or jumps, as "
    "segment-switched rate terms do), so no drive makes it follow: refit without the effect that "
    "makes it so, or use hysteresis + delay + dynamics"
)


def converged_drive(model, axis: str, column: int, u_v: np.ndarray, ref: Reference, frequency_hz: float) -> np.ndarray:
    """The feedforward drive ``u_v`` (V) if the model itself says it follows the reference's
    ``axis`` (``ref.x_um``'s ``column``); else the periodic drive that does (service.science.control.periodic_inverse, for
    inverses that miss a fast reference, as the paper's dynamic PI does); refused (ControlRefused
    naming the feedforward model) if that misses too."""
    x_ref_um, steady = ref.x_um[:, column], ref.steady
    span = float(np.ptp(x_ref_um[steady]))
    miss = inverse_miss_um(model, u_v, x_ref_um, SAMPLE_RATE_HZ, steady)
    if miss <= INVERSE_TOLERANCE_SHARE * span:
        return u_v
    periodic = periodic_drive_v(model, u_v, x_ref_um, SAMPLE_RATE_HZ, ref.period, steady)
    periodic_miss = inverse_miss_um(model, periodic, x_ref_um, SAMPLE_RATE_HZ, steady)
    if periodic_miss <= INVERSE_TOLERANCE_SHARE * span:
        return periodic
    name = type(model).__name__
    raise ControlRefused(
        f"controller.feedforward_model_{axis}",
        (
            f"the {name} model's inverse does not converge at {frequency_hz:g} Hz: its own prediction of the "
            f"feedforward drive misses the {axis.upper()} reference by {fmt_nm(miss)} RMS, and by "
            f"{fmt_nm(periodic_miss)} RMS with the drive solved period by period "
            f"({100 * periodic_miss / span:.0f} % of its {span:.3g} µm range). "
            + getattr(model, "inverse_advice", INVERSE_ADVICE)
        ),
    )


def voltage_tolerance_v(bench: Bench, ref: Reference, controller: Controller, axis: str) -> float:
    """How far (V) the drive may leave ``axis``'s voltage limits before the demand check refuses it on
    ``frequency_hz``: VOLTAGE_TOLERANCE_V when the range fits the axis's quasi-static stroke (so it is the
    frequency that needs the voltage), inf when it does not (``check_stroke`` refuses the range) or when
    ``allow_saturation`` clamps it."""
    if controller.allow_saturation:
        return np.inf
    model = controller.feedforward[axis]
    top = float(np.max(ref.x_um[ref.steady, bench.axes.index(axis)]))
    return VOLTAGE_TOLERANCE_V if model_stroke_um(model, SAMPLE_RATE_HZ, bench.limits[axis].v_max_v) >= top else np.inf


def check_demand(bench: Bench, ref: Reference, u_ff: np.ndarray, frequency_hz: float, controller: Controller) -> None:
    """Predict the demand (service.science.control.demand) of the mode-inverting drive on each axis of
    ``controller.mode_axes`` into ``controller.demand``; refuse (``frequency_hz``) one beyond the
    amplifier's current or slew limits, or the voltage limits (unless ``allow_saturation``)."""
    demands = [
        predict_demand(
            axis,
            bench.limits[axis],
            ref.x_um[ref.steady, i],
            u_ff[ref.steady, i],
            controller.modes.get(axis),
            frequency_hz,
            ref.period,
            SAMPLE_RATE_HZ,
        )
        for i, axis in enumerate(bench.axes)
        if axis in controller.mode_axes
    ]
    controller.demand = {d.axis: d.as_dict() for d in demands}
    tolerance = {d.axis: voltage_tolerance_v(bench, ref, controller, d.axis) for d in demands}
    why = demand_refusal(demands, frequency_hz, tolerance)
    if why:
        raise ControlRefused("frequency_hz", why)


def plan(
    bench: Bench, ellipse: Ellipse, controller: Controller, mode: str, warnings: list[str] | None = None
) -> tuple[Reference, np.ndarray | None]:
    """Reference and feedforward (V), after every safety check (raises ControlRefused). A range beyond
    the stroke (by a feedforward model with flexure dynamics) is refused unless
    ``controller.allow_saturation``, when its reason is appended to ``warnings`` instead; a
    hysteresis-only model's verdict is always a warning (see safety.check_stroke)."""
    check_mode(bench, mode, controller.pid is not None)
    ref = reference(ellipse, SAMPLE_RATE_HZ)
    u_ff = None
    if any(m is not None for m in controller.feedforward.values()):
        u_ff = np.zeros_like(ref.x_um)
        steady = ref.steady
        for i, axis in enumerate(bench.axes):
            model = controller.feedforward.get(axis)
            if model is not None:
                u = feedforward_v(model, ref.x_um[:, i], SAMPLE_RATE_HZ, v_limits=(-np.inf, np.inf))
                u_ff[:, i] = converged_drive(model, axis, i, u, ref, ellipse.frequency_hz)
        check_trajectory(bench, ref.x_um, u_ff, ellipse.frequency_hz, steady=steady, mode_axes=controller.mode_axes)
        check_demand(bench, ref, u_ff, ellipse.frequency_hz, controller)
        reasons, soft = check_stroke(
            bench,
            {"y": ellipse.y_range_um, "z": ellipse.z_range_um},
            ellipse.frequency_hz,
            ref.x_um,
            u_ff,
            controller.feedforward,
            SAMPLE_RATE_HZ,
            steady=steady,
        )
        if reasons and not controller.allow_saturation:
            raise ControlRefused(
                f"{next(iter(reasons))}_range_um",
                "; ".join(reasons.values()) + " (set "
                "controller.allow_saturation to run it with the command clamped at the axis's voltage limits)",
            )
        if warnings is not None:
            warnings.extend([*reasons.values(), *soft])
        lims = [bench.limits[axis] for axis in bench.axes]
        u_ff = np.clip(u_ff, [lim.v_min_v for lim in lims], [lim.v_max_v for lim in lims])
    else:
        check_trajectory(bench, ref.x_um, None, ellipse.frequency_hz)
    return ref, u_ff


def track(
    bench: Bench,
    ellipse: Ellipse,
    controller: Controller,
    mode: str = "point_by_point",
    on_period: Callable[[int, TrackRecord], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[dict, TrackRecord, Reference]:
    """Run one experiment; returns (result dict, record, reference)."""
    if controller.planned is not None:
        ref, u_ff, said = controller.planned
        warnings = list(said)
    else:
        warnings = []
        ref, u_ff = plan(bench, ellipse, controller, mode, warnings)
    ilc = None
    if controller.ilc:
        steady = ref.steady_period()
        bias = np.mean(u_ff[ref.steady][: ref.period], axis=0) if u_ff is not None else np.full(2, 60.0)
        g, noise_var = measure_response(
            bench,
            ref.period,
            controller.ilc_harmonics,
            bias,
            steady.mean(axis=0),
            mode,
            controller.pid,
            amplitude_v=probe_amplitude_v(controller),
        )
        controller.ilc_gain_scale = {}
        for i, axis in enumerate(bench.axes):
            gain = (controller.trajectory_gain or {}).get(axis)
            if gain is not None:
                pid = None if controller.pid is None else controller.pid[axis]
                kappa = prior_scale(g[i], ellipse.frequency_hz, pid, gain, controller.modes.get(axis))
                g[i] = scaled_response(g[i], ellipse.frequency_hz, pid, kappa)
                controller.ilc_gain_scale[axis] = kappa
        tops = controller.ilc_axis_harmonics or {}
        ilc = HarmonicILC(
            g,
            ref.period,
            gain=controller.ilc_gain,
            noise_var_um2=noise_var,
            learned_harmonics=[tops.get(axis, controller.ilc_harmonics) for axis in bench.axes],
        )
    t0, c0 = time.perf_counter(), time.process_time()
    rec = Tracker(bench, ref, u_ff, mode=mode, pid=controller.pid, ilc=ilc).run(on_period, should_stop)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    result = {
        "mode": mode,
        "samples": rec.samples,
        "tripped": rec.tripped,
        "stopped": rec.stopped,
        "loop_wall_s": wall,
        "loop_realtime_factor": (rec.samples / ref.sample_rate_hz + SETTLE_S) / wall,
        "loop_cpu_s": cpu,
        "loop_cpu_realtime_factor": (rec.samples / ref.sample_rate_hz + SETTLE_S) / max(cpu, 1e-9),
        "error_per_period_um": rec.error_per_period_um,
        "ilc_stop_reason": rec.ilc_stop_reason,
        "reference_peak_to_peak_um": ellipse.peak_to_peak_um,
        "warnings": warnings,
        "pid": controller.pid_report,
        "ilc": controller.ilc_report,
        "demand": controller.demand,
    }
    if ilc is not None and controller.ilc_report is not None:
        result["ilc"] = {
            **controller.ilc_report,
            "prior_scale": controller.ilc_gain_scale,
            "measured_factor": measured_factor(rec.error_per_period_um),
        }
    if rec.tripped and ilc is not None:
        result["tripped"] = f"{rec.tripped}; {learning_diagnosis(ilc, controller.ilc_report)}"
    if rec.tripped is None and not rec.stopped:
        lims = np.array([[bench.limits[a].v_min_v, bench.limits[a].v_max_v] for a in bench.axes])
        result.update(metrics(rec, ref, lims))
    return result, rec, ref


def trace_arrays(rec: TrackRecord, sample_rate_hz: float, axes, start: int, stop: int) -> dict[str, np.ndarray]:
    """Rows ``start:stop`` of a tracking run as dataset columns: t_s, u_<axis>_v, x_<axis>_um, ref_<axis>_um."""
    arrays = {"t_s": np.arange(start, stop) / sample_rate_hz}
    for i, ax in enumerate(axes):
        arrays[f"u_{ax}_v"] = rec.u_v[start:stop, i].copy()
        arrays[f"x_{ax}_um"] = rec.x_um[start:stop, i].copy()
        arrays[f"ref_{ax}_um"] = rec.ref_um[start:stop, i].copy()
    return arrays


def track_plan(bench: Bench, emit, ellipse: Ellipse, controller: Controller, mode: str):
    """``track`` as a plan for ``Bench.execute`` (it runs where the bench is, possibly the engine
    process): after each period it emits ``(period, new trace rows, last error µm or None)``."""
    sent = 0

    def on_period(p: int, rec: TrackRecord) -> None:
        nonlocal sent
        last = rec.error_per_period_um[-1] if rec.error_per_period_um else None
        emit(p, trace_arrays(rec, SAMPLE_RATE_HZ, bench.axes, sent, rec.samples), last)
        sent = rec.samples

    return track(bench, ellipse, controller, mode, on_period=on_period)
