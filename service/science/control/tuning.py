"""Gains the service chooses: a PID per axis tuned on the plant identified on the bench, and the
same prediction for any gain set a user gives.

The plant (``plant_from_model``): the largest incremental slope of the identified feedforward
model's rising branch (µm/V: for a PI, its weight sum, reached once every operator moves), the
flexure's first mode (the bench's declared resonance, with the lighter of the model's identified
damping ratio and ``ASSUMED_DAMPING``) and the loop's delay
(``stability.loop_delay_s``). The largest slope is the safe choice: a smaller incremental gain
(after a reversal) lowers the loop gain, which these loops tolerate (``MIN_GAIN_MARGIN_DB``).

``tune`` minimises the tracking error left at the trajectory's frequency and its first harmonics
(the sensitivity |1/(1 + L)|), keeping the largest integral gain (against creep and drift) the
rest allows, subject to ``Targets``: phase margin, gain margin and delay margin (a multiple of the
loop's own delay), with the derivative filter fixed (``TF_S``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.science.control.safety import ControlRefused
from service.science.control.stability import (GRID_HZ, AxisPlant, LoopMargins, loop_delay_s, loop_margins,
                                               margins_of, pid_response, plant_response)

#: damping ratio assumed for a flexure mode no model has identified (lighter than typical: a safe guess)
ASSUMED_DAMPING = 0.02
#: derivative filter time constant (s) of tuned gains: a 0.8 kHz corner, below the 10 kHz Nyquist limit
TF_S = 2e-4
#: voltage (V) over which a model's rising branch is read for its largest slope (the paper's range)
SLOPE_SPAN_V = 120.0


@dataclass(frozen=True)
class Targets:
    """What a gain set must leave: phase margin (deg), gain margin (dB), delay margin as a multiple
    of the loop's delay."""

    phase_margin_deg: float = 60.0
    gain_margin_db: float = 6.0
    delay_margin_factor: float = 3.0

    def failures(self, m: LoopMargins) -> list[str]:
        """The margins ``m`` misses, in words (empty when it meets every target)."""
        out = []
        if not m.stable:
            out.append("closed loop unstable")
        if not m.phase_margin_deg >= self.phase_margin_deg:
            out.append(f"phase margin {m.phase_margin_deg:.1f}° < {self.phase_margin_deg:g}°")
        if not m.gain_margin_db >= self.gain_margin_db:
            out.append(f"gain margin {m.gain_margin_db:.1f} dB < {self.gain_margin_db:g} dB")
        need_s = self.delay_margin_factor * m.loop_delay_s
        if not m.delay_margin_s >= need_s:
            out.append(f"delay margin {m.delay_margin_s * 1e6:.0f} µs < {self.delay_margin_factor:g} × the loop's "
                       f"{m.loop_delay_s * 1e6:.0f} µs delay")
        return out

    def as_dict(self) -> dict:
        return {"phase_margin_deg": self.phase_margin_deg, "gain_margin_db": self.gain_margin_db,
                "delay_margin_factor": self.delay_margin_factor}


def largest_slope_um_per_v(model, sample_rate_hz: float, span_v: float = SLOPE_SPAN_V) -> float:
    """The largest incremental gain (µm/V) along the model's quasi-static rising branch 0 → ``span_v``
    (0.5 s raised-cosine ramp), read over 1 V steps."""
    n = int(sample_rate_hz / 2)
    u = 0.5 * span_v * (1 - np.cos(np.pi * np.arange(n) / n))
    x = np.asarray(model.predict(u, sample_rate_hz=sample_rate_hz), dtype=float)
    grid_v = np.arange(0.0, span_v * 0.999, 1.0)
    x_grid = np.interp(grid_v, u, x)
    return float(np.max(np.diff(x_grid)))


def identified_mode(model) -> tuple[float, float] | None:
    """(resonance Hz, damping ratio) of the model's identified flexure dynamics, or None."""
    try:
        theta = model.as_composite().theta
    except (AttributeError, NotImplementedError, ValueError):
        return None
    dyn = theta.get("dynamics") if isinstance(theta, dict) else None
    if not dyn or "fn_hz" not in dyn:
        return None
    return float(dyn["fn_hz"]), float(dyn["zeta"])


def plant_from_model(model, resonance_hz: float, delay_s: float, sample_rate_hz: float) -> AxisPlant:
    """The ``AxisPlant`` of one axis from its identified model (see the module doc). The mode is the
    bench's first resonance ``resonance_hz`` (the model's identified one where the bench declares
    none). Sweeps up to 100 Hz cannot pin the damping of a 290–480 Hz mode (seen identified at 0.005
    and at 0.17 on the same bench, whose true ratio is 0.04–0.05; tuning on 0.17 tripped the loop),
    so the damping is the lighter of the identified one and ``ASSUMED_DAMPING``."""
    mode = identified_mode(model)
    fn_hz = resonance_hz if np.isfinite(resonance_hz) or mode is None else mode[0]
    zeta = ASSUMED_DAMPING if mode is None else min(mode[1], ASSUMED_DAMPING)
    return AxisPlant(largest_slope_um_per_v(model, sample_rate_hz), fn_hz, zeta, delay_s)


@dataclass(frozen=True)
class Tuned:
    """Gains (kp V/µm, ki V/(µm·s), kd V·s/µm, tf_s s) and the margins they leave on the plant."""

    kp: float
    ki: float
    kd: float
    tf_s: float
    margins: LoopMargins


def _best_ki(plant: AxisPlant, targets: Targets, kp: float, kd: float, ki_grid: np.ndarray,
             f_hz: np.ndarray, g: np.ndarray) -> float:
    """The largest ki on ``ki_grid`` (rising) for which (kp, ki, kd) meets ``targets``; 0 if none."""
    base = pid_response(kp, 0.0, kd, TF_S, f_hz) * g
    integ = g / (2j * np.pi * f_hz)
    best = 0.0
    for ki in ki_grid:
        if targets.failures(margins_of(base + ki * integ, f_hz, plant.delay_s)):
            break
        best = float(ki)
    return best


#: the paper's trajectory frequency (Hz): "tuned" and a tuning without a stated frequency aim there
DESIGN_FREQUENCY_HZ = 100.0
#: harmonics of the trajectory frequency whose tracking error the tuning minimises (an ellipse is one
#: sine per axis: its error is mostly at the fundamental)
DESIGN_HARMONICS = 1
#: the search meets the targets by this much more (phase margin deg, gain margin dB, delay margin
#: factor) on its coarser grid, so that the answer meets them on the fine one
SEARCH_SLACK = (1.0, 0.3, 1.05)


def tune(plant: AxisPlant, targets: Targets = Targets(), frequency_hz: float = DESIGN_FREQUENCY_HZ) -> Tuned:
    """The PID meeting ``targets`` on ``plant`` that tracks a trajectory at ``frequency_hz`` best: the
    lowest worst-case sensitivity |1/(1 + L)| over its first DESIGN_HARMONICS harmonics, with the
    largest ki (integral action against creep and drift) that kp, kd leave. Coarse grid over kp and kd
    (ki by a rising scan), then a finer grid around the best. ValueError when no gain set meets them."""
    f_hz = GRID_HZ[::3]            # the search reads a coarser grid; the answer is checked on the fine one
    g = plant_response(plant, f_hz)
    strict = Targets(targets.phase_margin_deg + SEARCH_SLACK[0], targets.gain_margin_db + SEARCH_SLACK[1],
                     targets.delay_margin_factor * SEARCH_SLACK[2])
    band_hz = frequency_hz * np.arange(1, DESIGN_HARMONICS + 1)
    g_band = plant_response(plant, band_hz)
    scale = 1.0 / plant.gain_um_per_v            # gains in units of the plant's inverse gain
    best, best_s = (0.0, 0.0, 0.0), np.inf
    kp_grid = scale * np.logspace(-3, 1, 17)
    kd_grid = scale * np.concatenate(([0.0], np.logspace(-6, -3, 13)))
    ki_grid = scale * np.logspace(0, 5, 41)
    for _ in range(2):
        for kp in kp_grid:
            for kd in kd_grid:
                ki = _best_ki(plant, strict, kp, kd, ki_grid, f_hz, g)
                if ki == 0.0:
                    continue
                worst_s = float(np.max(np.abs(1.0 / (1.0 + pid_response(kp, ki, kd, TF_S, band_hz) * g_band))))
                if worst_s < best_s - 1e-9:
                    best, best_s = (float(kp), ki, float(kd)), worst_s
        kp0, ki0, kd0 = best
        if ki0 == 0.0:
            raise ValueError("no PID meets the targets on this plant: " + ", ".join(f"{k} {v}" for k, v in
                                                                                    targets.as_dict().items()))
        kp_grid = kp0 * np.logspace(-0.25, 0.25, 9)
        kd_grid = np.concatenate(([0.0], kd0 * np.logspace(-0.25, 0.25, 9))) if kd0 > 0 else kd_grid[:4]
        ki_grid = ki0 * np.logspace(-0.3, 0.3, 41)
    kp, ki, kd = best
    margins = loop_margins(kp, ki, kd, TF_S, plant)
    for _ in range(40):                 # the fine grid may see a sliver the coarse one did not: back off
        if not targets.failures(margins):
            return Tuned(kp, ki, kd, TF_S, margins)
        kp, ki, kd = 0.95 * kp, 0.95 * ki, 0.95 * kd
        margins = loop_margins(kp, ki, kd, TF_S, plant)
    raise ValueError(f"the tuned gains miss the targets on the fine grid: {', '.join(targets.failures(margins))}")


#: "auto" on the default bench (seed 0), plant from the static PI identified on its 1 Hz 0–120 V loop
#: (service.science.control.feedforward.identify); tests/test_control_gains.py recomputes it
TUNED_PID = {"y": (0.6095, 252.6, 0.0, TF_S), "z": (0.4188, 121.5, 3.627e-4, TF_S)}
#: PID presets a request may name besides "auto" and explicit gains
PRESETS = ("auto", "tuned", "paper")


def bench_plants(bench, models: dict, sample_rate_hz: float) -> dict:
    """axis → ``AxisPlant`` from the axis's feedforward model (None without one), the bench's first
    resonance and the loop delay of a per-sample loop on its DAQ at ``sample_rate_hz``."""
    delay = loop_delay_s(sample_rate_hz, getattr(bench.parts.daq.capabilities, "latency_samples", 0))
    return {axis: (None if models.get(axis) is None else
                   plant_from_model(models[axis], bench.limits[axis].first_resonance_hz, delay, sample_rate_hz))
            for axis in bench.axes}


def choose_pid(spec, plants: dict, presets: dict, targets: Targets = Targets(), force: bool = False,
               frequency_hz: float = DESIGN_FREQUENCY_HZ, field: str = "controller.pid") -> tuple[dict, dict, list[str]]:
    """The gains per axis a request's ``spec`` names ("auto", a key of ``presets`` (axis → PIDGains-like),
    or axis → (kp, ki, kd, tf_s)), with their predicted margins on ``plants`` (axis → AxisPlant, or
    None where no identified model gives the plant); "auto" tunes for a trajectory at ``frequency_hz``.

    Returns (axis → (kp, ki, kd, tf_s), report, warnings); report = {"pid": spec name, "targets",
    "axes": {axis: {gains, "plant", "margins", "failures"}}}. Raises ControlRefused naming ``field``:
    "auto" without a plant; "paper" unless ``force`` (its predicted margins in the reason); any gain
    set predicted unstable unless ``force`` (the failing margin in the reason). A stable set that
    misses a target only warns."""
    name = spec if isinstance(spec, str) else "custom"
    gains, report, warnings, refusals = {}, {"pid": name, "targets": targets.as_dict(), "axes": {}}, [], []
    for axis, plant in plants.items():
        if name == "auto":
            if plant is None:
                raise ControlRefused(field, f'"auto" tunes on the plant identified on the bench: give '
                                     f"controller.feedforward_model_{axis} (its largest slope is the {axis.upper()} gain)")
            try:
                tuned = tune(plant, targets, frequency_hz)
            except ValueError as exc:
                raise ControlRefused(field, f"{axis.upper()}: {exc}") from None
            g = (tuned.kp, tuned.ki, tuned.kd, tuned.tf_s)
        else:
            p = presets[name][axis] if name in presets else spec[axis]
            g = (float(p[0]), float(p[1]), float(p[2]), float(p[3])) if isinstance(p, tuple) else (
                p.kp, p.ki, p.kd, p.tf_s)
        gains[axis] = g
        entry = {"kp": g[0], "ki": g[1], "kd": g[2], "tf_s": g[3], "plant": None, "margins": None, "failures": []}
        if plant is None:
            warnings.append(f"{axis.upper()} PID margins not predicted: no feedforward model gives the plant")
        else:
            margins = loop_margins(*g, plant)
            fails = targets.failures(margins)
            entry.update(plant=plant.as_dict(), margins=margins.as_dict(), failures=fails)
            said = (f"{axis.upper()} kp {g[0]:.4g} V/µm, ki {g[1]:.4g} V/(µm·s), kd {g[2]:.4g} V·s/µm: "
                    f"{'stable' if margins.stable else 'UNSTABLE'}, phase margin {margins.phase_margin_deg:.1f}°, gain "
                    f"margin {margins.gain_margin_db:.1f} dB, delay margin {margins.delay_margin_s * 1e6:.0f} µs "
                    f"(on {plant.gain_um_per_v:.3g} µm/V, {plant.resonance_hz:.1f} Hz ζ {plant.damping_ratio:.3g}, "
                    f"{plant.delay_s * 1e6:.0f} µs delay)")
            if name == "paper" or not margins.stable:
                refusals.append(said + (f"; fails: {', '.join(fails)}" if fails else ""))
            elif fails:
                warnings.append(said + f"; misses: {', '.join(fails)}")
        report["axes"][axis] = entry
    if name == "paper" and not force and not refusals:
        refusals.append("the paper's gains cannot be judged without a feedforward model per axis")
    if refusals and not force:
        why = ('the paper\'s gains (eq. 19 units) are refused: ' if name == "paper" else
               "these gains are predicted unstable: ")
        raise ControlRefused(field, why + "; ".join(refusals) + ' (use "auto", or set controller.force to run '
                             "them anyway; the divergence watch trips the run to 0 V)")
    warnings.extend(refusals)
    return gains, report, warnings
