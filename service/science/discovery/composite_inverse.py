"""The composite model's inverse (``CompositeModel.inverse``, service.science.discovery.composite).

The model is x̂ = T(A(u)·c): play operators P(u) (weights ≥ 0), an offset and additive effect
columns (rate dependence, asymmetry, creep, cross-coupling, …), then the linear transforms T (delay,
flexure dynamics). Its inverse for a planned reference x_ref (µm):

1. **Transforms, per harmonic.** A planned reference starts and ends at rest with zero slope, so it is
   one period of a smooth periodic signal: its spectrum divided by T's frequency response at each
   bin gives the pre-transform target w = T⁻¹(x_ref) (µm). The delay is undone as an advance and the
   resonance as its exact inverse; bins above ``max_frequency_hz`` are left out (the reference has
   nothing there and 1/T grows as f² above the mode).
2. **Hysteresis, additive effects and capacity operators, by a damped iteration on the model.**
   u₀ = PI⁻¹(w − offset). Then, as learning on the model offline, the PI's target is moved by the
   model's own pre-transform miss r_i = w − A(u_i)c, u_{i+1} = PI⁻¹(target_i + α r_i): with α = 1 this
   is the plain fixed point u_{i+1} = PI⁻¹(w − offset − add(u_i)). Where that does not contract (rate
   terms on du/dt and d²u/dt² at 100 Hz, the capacity's free-sign operators), α is halved until the
   model residual ‖T(A(u)c) − x_ref‖ falls, and grows back after a success; the iteration stops when
   the residual is below ``CONVERGED_SHARE`` of the reference's range or α gets too small; a step is
   only taken when it lowers the residual, so the last iterate is the best. What still misses is refused by the caller with its figure
   (service.science.control.session.converged_drive): a model whose output is not monotone in the
   drive has no inverse to find.
3. **Gauss–Newton on the reference's harmonics, where step 2 stalls.** Rate dependence's operator-rate
   terms (c_i·dP_i/dt, leads and lags of several ms at 100 Hz) give the stack a time-varying phase that
   no correction through PI⁻¹ follows: step 2 stops at 4–6 % of the range. The drive is then corrected
   by a few harmonics of the reference's fundamental (under its amplitude envelope, so the drive still
   starts and ends at rest), their Jacobian taken on the model by finite differences: on case 2's Z
   (seed 5) 5.9 % → 0.5 % in about 3 s.

Units: volts in, micrometres out, seconds and hertz for time and frequency.
"""

from __future__ import annotations

import numpy as np

from service.science.data.signals import drive_derivatives
from service.science.effects import EFFECTS
from service.science.fitting.metrics import rms
from service.science.models.inverse import numerical_inverse

#: the most model evaluations the damped iteration spends (each one PI inverse and one forward pass)
FIXED_POINT_ITERATIONS = 40
#: the residual (share of the reference's range, RMS) at which the iteration has converged
CONVERGED_SHARE = 1e-5
#: step 3 runs when step 2 leaves more than this share of the reference's range (RMS)
HARMONIC_REFINEMENT_SHARE = 0.01
#: the harmonics of the fundamental step 3 corrects, and its Gauss–Newton iterations
REFINEMENT_HARMONICS = 8
REFINEMENT_ITERATIONS = 6
#: the finite-difference step (V) of step 3's Jacobian
JACOBIAN_STEP_V = 0.2
#: the smallest step α tried before the iteration gives up (it halves after every failed step)
MIN_STEP = 1.0 / 64
#: the inner PI inverse's search range (V) when none is given: beyond the stack's rating (0–150 V on the
#: default bench), so that the safety check sees what the reference needs
COMPOSITE_LIMITS_V = (-60.0, 180.0)


def transform_response(model, frequency_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """The model's linear transforms (each one's ``response``: delay × dynamics) at ``frequency_hz``
    (complex, unitless); a transform without an inverse (``inverse = "none"``) is left out."""
    h = np.ones(np.shape(frequency_hz), dtype=complex)
    for name in model.transforms:
        if name in model.theta and EFFECTS[name].inverse == "response":
            h = h * EFFECTS[name].response(frequency_hz, sample_rate_hz, model.theta[name])
    return h


def invert_transforms(
    model, x_um: np.ndarray, sample_rate_hz: float, max_frequency_hz: float | None = None
) -> np.ndarray:
    """w (µm) with T(w) = x for a record that starts and ends at rest (spectral division)."""
    n = x_um.size
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    top = max_frequency_hz or 0.2 * sample_rate_hz
    X = np.fft.rfft(x_um)
    W = np.where(f <= top, X / transform_response(model, f, sample_rate_hz), 0.0)
    W[0] = X[0]
    return np.fft.irfft(W, n=n)


def _stack_um(model, u_v: np.ndarray, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(hysteresis + offset, additive effects) in µm before the transforms, for drive ``u_v`` (V),
    from one context (its play operators and derivatives computed once; other axis unknown)."""
    du, ddu = drive_derivatives(u_v, sample_rate_hz)
    ctx = model.context(u_v, sample_rate_hz, du, ddu)
    additive = np.zeros(u_v.size)
    for name in model.effects:
        if EFFECTS[name].inverse == "none":  # a feedforward leaves it out (its ``no_inverse`` says why)
            continue
        for b in EFFECTS[name].blocks(ctx):
            additive += b.columns @ model.coef[b.name]
    return ctx.p @ model.coef["weights_um_per_v"] + model.coef["offset_um"][0], additive


def composite_inverse(
    model,
    x_ref_um: np.ndarray,
    sample_rate_hz: float,
    iterations: int = FIXED_POINT_ITERATIONS,
    u_limits_v=COMPOSITE_LIMITS_V,
) -> np.ndarray:
    """The drive (V) whose model output follows ``x_ref_um`` (see the module docstring), the inner PI
    inverse searched within ``u_limits_v`` (V)."""
    x = model.sign * np.asarray(x_ref_um, dtype=float)  # in the model's own direction (fitted to sign·x)
    x = model.undo_gauge(x)  # what the flexure must do for the gauge to read it
    w = invert_transforms(model, x, sample_rate_hz)
    weights = model.coef["weights_um_per_v"]
    offset = float(model.coef["offset_um"][0])

    origin = model.u_origin_v  # the operators count from it: invert relative to it, answer in V

    def pi_inverse(target):
        limits = (u_limits_v[0] - origin, u_limits_v[1] - origin)
        return numerical_inverse(target, model.thresholds_v, weights, offset, u_limits_v=limits) + origin

    u = pi_inverse(w)
    if not any(EFFECTS[e].stage in ("additive", "capacity") for e in model.effects):
        return u

    def residual(u_v):
        """(pre-transform miss w − A(u)c (µm), post-transform RMS miss of x (µm))."""
        hysteresis, additive = _stack_um(model, u_v, sample_rate_hz)
        stack = hysteresis + additive
        return w - stack, rms(model._transform(stack[:, None], sample_rate_hz, model.theta)[:, 0] - x)

    target = w
    miss, err = residual(u)
    step, tolerance = 1.0, CONVERGED_SHARE * max(float(np.ptp(x)), 1e-12)
    for _ in range(iterations - 1):
        if err <= tolerance or step < MIN_STEP:
            break
        trial_target = target + step * miss
        trial = pi_inverse(trial_target)
        trial_miss, trial_err = residual(trial)
        if trial_err < err:
            target, u, miss, err = trial_target, trial, trial_miss, trial_err
            step = min(1.0, 2.0 * step)
        else:
            step *= 0.5
    if err > HARMONIC_REFINEMENT_SHARE * max(float(np.ptp(x)), 1e-12):
        u = refine_on_harmonics(model, u, np.asarray(x_ref_um, dtype=float), sample_rate_hz)
    return u  # every accepted step lowered the residual: the last is the best


def refine_on_harmonics(model, u_v: np.ndarray, x_ref_um: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Step 3 of the module docstring: Gauss–Newton on the model's miss ``predict(u) − x_ref`` (µm) over
    a basis of the reference's first REFINEMENT_HARMONICS harmonics (and a level) under the drive's
    amplitude envelope; each step halved until the miss falls. Returns the refined drive (V)."""
    n = x_ref_um.size
    spectrum = np.abs(np.fft.rfft(x_ref_um - x_ref_um.mean()))
    if n < 4 or not np.any(spectrum[1:]):
        return u_v
    f0_hz = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)[1 + int(np.argmax(spectrum[1:]))]
    period = max(int(round(sample_rate_hz / f0_hz)), 1)
    swing = np.abs(u_v - u_v[0])
    envelope = np.maximum.accumulate(swing) * np.maximum.accumulate(swing[::-1])[::-1]  # rises, holds, falls
    envelope = np.convolve(envelope, np.ones(period) / period, mode="same")
    if not np.any(envelope):
        return u_v
    envelope /= envelope.max()
    phase = 2 * np.pi * f0_hz * np.arange(n) / sample_rate_hz
    k = np.arange(1, REFINEMENT_HARMONICS + 1)
    basis = envelope[:, None] * np.column_stack([np.ones(n), np.cos(np.outer(phase, k)), np.sin(np.outer(phase, k))])

    def miss(u):
        return model.predict(u, sample_rate_hz=sample_rate_hz) - x_ref_um

    r = miss(u_v)
    for _ in range(REFINEMENT_ITERATIONS):
        jacobian = np.column_stack([(miss(u_v + JACOBIAN_STEP_V * b) - r) / JACOBIAN_STEP_V for b in basis.T])
        delta = basis @ np.linalg.lstsq(jacobian, -r, rcond=None)[0]
        alpha = 1.0
        while alpha >= MIN_STEP:
            trial = miss(u_v + alpha * delta)
            if trial @ trial < r @ r:
                u_v, r = u_v + alpha * delta, trial
                break
            alpha *= 0.5
        else:
            break
    return u_v
