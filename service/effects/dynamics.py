"""Dynamics: a flexure resonance after the hysteresis — every column passes through
ωn²/(s² + 2ζωn s + ωn²) (unit DC gain, bilinear with prewarping at fn). fn (Hz) and ζ come
from a grid search refined locally; the weights stay linear."""
from __future__ import annotations

import numpy as np
from scipy.signal import bilinear, lfilter

from service.effects.base import Effect

#: flexure resonances are lightly damped; a heavily damped 2nd-order lag would only mimic a delay
ZETAS = (0.01, 0.03, 0.1, 0.3)
MAX_ZETA = 0.5


def resonance_filter(columns: np.ndarray, fs_hz: float, fn_hz: float, zeta: float) -> np.ndarray:
    wn = 2.0 * fs_hz * np.tan(np.pi * fn_hz / fs_hz)  # prewarped
    b, a = bilinear([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn], fs_hz)
    y0 = columns[:1]
    return lfilter(b, a, columns - y0, axis=0) + y0


class Dynamics(Effect):
    name = "dynamics"
    stage = "transform"
    signature = ("the residual grows steeply with drive frequency (about as f²) and is in phase with "
                 "the acceleration of the output: a resonance above the drive band")

    def grid(self, fs_hz, min_period_s, max_frequency_hz):
        lo, hi = 1.5 * max_frequency_hz, 0.3 * fs_hz
        return [{"fn_hz": float(f), "zeta": z} for f in np.logspace(np.log10(lo), np.log10(hi), 14) for z in ZETAS]

    def apply(self, columns, fs_hz, theta):
        return resonance_filter(columns, fs_hz, theta["fn_hz"], theta["zeta"])

    def refine(self, theta, cost):
        best, best_cost = dict(theta), cost(theta)
        for factor in (1.08, 1.025):
            for _ in range(2):
                improved = False
                steps = (("fn_hz", factor), ("fn_hz", 1 / factor), ("zeta", factor**3), ("zeta", factor**-3))
                for key, mult in steps:
                    trial = dict(best, **{key: best[key] * mult})
                    trial["zeta"] = float(np.clip(trial["zeta"], 0.003, MAX_ZETA))
                    c = cost(trial)
                    if c < best_cost:
                        best, best_cost, improved = trial, c, True
                if not improved:
                    break
        return best

    def describe(self, theta, values):
        return f"resonance {theta['fn_hz']:.4g} Hz, damping ratio {theta['zeta']:.3g}"
