"""Delay: the measured output lags the drive by τ (DAQ pipeline, amplifier/gauge lag) — the
whole model output is evaluated at t − τ, with fractional τ by linear interpolation. τ (s) is
found by a 1-D search (grid, then golden refinement)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from service.science.data.units import fmt_us
from service.science.effects.base import Effect, sum_of_taps
from service.science.effects.rules import two_rates

#: the sweep that separates a delay from the other rate effects (above the paper's band)
HIGHER_SWEEP = {"waveform": "sine", "rate_multiples": [1.0, 1.5, 2.0], "cycles": 10}


def shift_columns(columns: np.ndarray, delay_samples: float) -> np.ndarray:
    """columns(t − d) for d ≥ 0 samples (fractional, linear interpolation; held at the start)."""
    if delay_samples <= 0:
        return columns
    k, frac = int(np.floor(delay_samples)), delay_samples - np.floor(delay_samples)
    n = columns.shape[0]
    idx = np.arange(n)
    i0 = np.clip(idx - k, 0, n - 1)
    i1 = np.clip(idx - k - 1, 0, n - 1)
    return (1.0 - frac) * columns[i0] + frac * columns[i1]


#: evaluations of the bounded search between grid values (Brent's method: to ~1e-3 of the interval)
REFINE_EVALUATIONS = 12


class Delay(Effect):
    name = "delay"
    stage = "transform"
    row_local = True
    signature = (
        "the residual is the model's slope times a constant time: it lags the drive by the "
        "same time at every frequency, so it grows in proportion to frequency"
    )

    def grid(self, fs_hz, min_period_s, max_frequency_hz):
        tau_max = min(0.2 * min_period_s, 64.0 / fs_hz)  # a delay is a fraction of the fastest cycle
        return [{"delay_s": float(t)} for t in np.linspace(0.0, tau_max, 25)]

    def apply(self, columns, fs_hz, theta):
        return shift_columns(columns, theta["delay_s"] * fs_hz)

    def taps(self, fs_hz, theta, rows, n):
        """((w0, rows0), (w1, rows1)): the delayed columns at ``rows`` of an n-sample record are
        w0·columns[rows0] + w1·columns[rows1] (linear interpolation, held at the start)."""
        d = max(theta["delay_s"] * fs_hz, 0.0)
        k, frac = int(np.floor(d)), d - np.floor(d)
        return (1.0 - frac, np.clip(rows - k, 0, n - 1)), (frac, np.clip(rows - k - 1, 0, n - 1))

    def apply_rows(self, columns, fs_hz, theta, rows):
        """The delayed columns at ``rows`` only (cheap: the search re-solves every weight)."""
        return sum_of_taps(self.taps(fs_hz, theta, rows, columns.shape[0]), columns)

    def clamp(self, theta, fs_hz):
        return {"delay_s": max(float(theta["delay_s"]), 0.0)}

    def refine(self, theta, cost, fine: bool = False, bracket=None):
        """The delay between the grid values beside the best one (``bracket``), else within ±25 % of
        it: a quarter of the value left every delay between grid points out of reach (a true 30 µs
        fitted as 0.9 µs from the grid's 0; 120 µs as 104 µs from its 83 µs)."""
        t0 = theta["delay_s"]
        if bracket is not None:
            lo, hi = min(bracket[0]["delay_s"], t0), max(bracket[1]["delay_s"], t0)
        else:
            step = max(t0 * 0.25, 1e-6)
            lo, hi = max(0.0, t0 - step), t0 + step
        res = minimize_scalar(
            lambda t: cost({"delay_s": max(t, 0.0)}),
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-7, "maxiter": REFINE_EVALUATIONS},
        )
        return {"delay_s": float(max(res.x, 0.0))} if res.fun <= cost(theta) else theta

    def describe(self, theta, values):
        return f"delay {fmt_us(theta['delay_s'])}"

    def parameters(self, theta, values, scales, sign):
        return {"delay_us": float(theta["delay_s"]) * 1e6}

    units = {"delay_s": "s", "delay_us": "µs"}
    rule = "at least two drive rates a factor 2 apart: at one rate a delay is one fixed loop shape"
    inverse = "response"
    identity = {"delay_s": 0.0}
    emulator_bench = "delay"
    separated_from = {
        "rate_dependence": (
            "a higher-frequency sine sweep: a delay is the same time at every "
            "frequency; rate dependence changes the loop shape with rate",
            HIGHER_SWEEP,
        ),
        "dynamics": (
            "a higher-frequency sine sweep: a resonance amplifies towards f_n, a delay only shifts the phase",
            HIGHER_SWEEP,
        ),
    }

    def untestable(self, records):
        return two_rates(self.name, records)

    def response(self, frequency_hz, fs_hz, theta):
        """e^(−2πjfτ): the delay's frequency response."""
        return np.exp(-2j * np.pi * np.asarray(frequency_hz) * theta["delay_s"])

    def evidence(self, sig, floor):
        if sig.get("lag_ms") is None:
            return "no lag can be measured: the model's prediction does not move in any block"
        per = ", ".join(  # a block without a frequency (a step-hold, an import's) is keyed "record"
            f"{'a block without a frequency' if k == 'record' else f'{k} Hz'}: {fmt_us(1e-3 * v)}"
            for k, v in sig["lag_ms_by_frequency"].items()
        )
        spread = sig.get("lag_ms_spread")
        return (
            f"the residual lags the drive by {fmt_us(1e-3 * sig['lag_ms'])} (slope-weighted mean; per block: {per}; "
            f"spread {'unknown' if spread is None else fmt_us(1e-3 * spread, 2)}): delay"
        )
