"""The composite model's inverse (``CompositeModel.inverse``, service.science.discovery.composite).

The model is x̂ = T(A(u)·c): play operators P(u) (weights ≥ 0), an offset and additive effect
columns (rate dependence, asymmetry, creep, cross-coupling, …), then the linear transforms T (delay,
flexure dynamics). Its inverse for a planned reference x_ref (µm):

1. **Transforms, per harmonic.** A planned reference starts and ends at rest with zero slope, so it is
   one period of a smooth periodic signal: its spectrum divided by T's frequency response at each
   bin gives the pre-transform target w = T⁻¹(x_ref) (µm). The delay is undone as an advance and the
   resonance as its exact inverse; bins above ``max_frequency_hz`` are left out (the reference has
   nothing there and 1/T grows as f² above the mode).
2. **Hysteresis and additive effects, by fixed point.** u₀ = PI⁻¹(w − offset); then
   u_{i+1} = PI⁻¹(w − offset − add(u_i)), with the additive columns evaluated on the previous answer
   (their weights are a small share of the output, so this contracts); the iterate with the smallest
   model residual ‖T(A(u)c) − x_ref‖ is kept.

Units: volts in, micrometres out, seconds and hertz for time and frequency.
"""
from __future__ import annotations

import numpy as np

from service.science.data.signals import drive_derivatives
from service.science.effects import EFFECTS
from service.science.effects.dynamics import digital_response
from service.science.fitting.metrics import rms
from service.science.models.inverse import numerical_inverse

FIXED_POINT_ITERATIONS = 6
#: the inner PI inverse's search range (V) when none is given: beyond the stack's rating (0–150 V on the
#: default bench), so that the safety check sees what the reference needs
COMPOSITE_LIMITS_V = (-60.0, 180.0)


def transform_response(model, frequency_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """The model's linear transforms (delay × dynamics) at ``frequency_hz`` (complex, unitless)."""
    h = np.ones(np.shape(frequency_hz), dtype=complex)
    theta = model.theta
    if "delay" in theta:
        h = h * np.exp(-2j * np.pi * frequency_hz * theta["delay"]["delay_s"])
    if "dynamics" in theta and theta["dynamics"].get("fn_hz", 1e12) < 0.5 * sample_rate_hz:
        h = h * digital_response(frequency_hz, sample_rate_hz, theta["dynamics"]["fn_hz"], theta["dynamics"]["zeta"])
    return h


def invert_transforms(model, x_um: np.ndarray, sample_rate_hz: float,
                      max_frequency_hz: float | None = None) -> np.ndarray:
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
        for b in EFFECTS[name].blocks(ctx):
            additive += b.columns @ model.coef[b.name]
    return ctx.p @ model.coef["weights_um_per_v"] + model.coef["offset_um"][0], additive


def composite_inverse(model, x_ref_um: np.ndarray, sample_rate_hz: float, iterations: int = FIXED_POINT_ITERATIONS,
                      u_limits_v=COMPOSITE_LIMITS_V) -> np.ndarray:
    """The drive (V) whose model output follows ``x_ref_um`` (see the module docstring), the inner PI
    inverse searched within ``u_limits_v`` (V)."""
    x = model.sign * np.asarray(x_ref_um, dtype=float)    # in the model's own direction (fitted to sign·x)
    x = model.undo_gauge(x)                                # what the flexure must do for the gauge to read it
    w = invert_transforms(model, x, sample_rate_hz)
    weights = model.coef["weights_um_per_v"]
    offset = float(model.coef["offset_um"][0])

    origin = model.u_origin_v       # the operators count from it: invert relative to it, answer in V

    def pi_inverse(target):
        limits = (u_limits_v[0] - origin, u_limits_v[1] - origin)
        return numerical_inverse(target, model.thresholds_v, weights, offset, u_limits_v=limits) + origin

    u = pi_inverse(w)
    if not any(EFFECTS[e].stage == "additive" for e in model.effects):
        return u
    best, best_err = u, np.inf
    for it in range(iterations):
        hysteresis, additive = _stack_um(model, u, sample_rate_hz)
        stack = model._transform((hysteresis + additive)[:, None], sample_rate_hz, model.theta)[:, 0]
        err = rms(stack - x)      # in the model's own direction, as x
        if err < best_err:
            best, best_err = u, err
        if it + 1 < iterations:
            u = pi_inverse(w - additive)
    return best
