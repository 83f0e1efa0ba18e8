"""A stage nobody on the project built, simulated without the product's code (written for a new
user's trial of issue 17): a Bouc–Wen stack (n = 1, solved exactly along the piecewise-linear drive)
at 5 kHz, driven ±150 V with a 3 s rest and 0.5 s gaps between 1/10/50/100 Hz bursts, plus one
hidden effect, plus 3 nm of gauge noise. The emulator's own Bouc–Wen family is a different
implementation with other parameters; discovery fits neither."""

from __future__ import annotations

import numpy as np
from scipy import signal

SAMPLE_RATE_HZ = 5000.0


def drive_v(
    frequencies_hz=(1, 10, 50, 100), cycles=(5, 10, 20, 30), amplitude_v=150.0, rest_s=3.0, gap_s=0.5
) -> np.ndarray:
    """A rest at 0 V, then each burst of whole sine cycles followed by a gap at 0 V (V)."""
    parts = [np.zeros(int(rest_s * SAMPLE_RATE_HZ))]
    for f, c in zip(frequencies_hz, cycles):
        t = np.arange(int(round(c / f * SAMPLE_RATE_HZ))) / SAMPLE_RATE_HZ
        parts += [amplitude_v * np.sin(2 * np.pi * f * t), np.zeros(int(gap_s * SAMPLE_RATE_HZ))]
    return np.concatenate(parts)


def bouc_wen_um(u_v: np.ndarray, a=0.35, beta_per_v=0.012, gamma_per_v=0.004, gain_um_per_v=0.1) -> np.ndarray:
    """x = k (u − h), dh/du = A − κ h with κ = (β ± γ)·sign(du): exact exponential approach per
    sample, split where h crosses 0 (where κ changes)."""
    h = np.zeros_like(u_v)
    state = 0.0
    for i in range(1, u_v.size):
        du = u_v[i] - u_v[i - 1]
        if du == 0.0:
            h[i] = state
            continue
        direction, left = (1.0 if du > 0 else -1.0), abs(du)
        while left > 0.0:
            positive = state > 0 or (state == 0 and direction > 0)
            kappa = direction * (beta_per_v + gamma_per_v if positive == (direction > 0) else beta_per_v - gamma_per_v)
            target = a / kappa
            new = target + (state - target) * np.exp(-direction * kappa * left)
            if state != 0.0 and np.sign(new) != np.sign(state):  # crosses 0 within this step
                run = min(max(-np.log(target / (target - state)) / (direction * kappa), 0.0), left)
                left, state = left - run, 0.0
                if run == 0.0:
                    state, left = new, 0.0
                continue
            state, left = new, 0.0
        h[i] = state
    return gain_um_per_v * (u_v - h)


def stage_um(effect: str, u_v: np.ndarray, seed: int = 0) -> np.ndarray:
    """The gauge reading (µm) of the stage with ``effect`` hidden: "clean", "resonance" (300 Hz,
    ζ 0.05, bilinear), "creep" (first-order lags of 0.5, 5 and 50 s) or "delay" (2 ms)."""
    x = bouc_wen_um(u_v)
    if effect == "creep":
        for tau_s in (0.5, 5.0, 50.0):
            pole = np.exp(-1.0 / (SAMPLE_RATE_HZ * tau_s))
            x = x + 0.004 * signal.lfilter([1 - pole], [1, -pole], u_v)
    elif effect == "delay":
        n = int(round(0.002 * SAMPLE_RATE_HZ))
        x = np.concatenate([np.full(n, x[0]), x[:-n]])
    elif effect == "resonance":
        wn = 2 * np.pi * 300.0
        b, a = signal.bilinear([wn**2], [1, 2 * 0.05 * wn, wn**2], SAMPLE_RATE_HZ)
        x = signal.lfilter(b, a, x)
    elif effect != "clean":
        raise ValueError(effect)
    return x + np.random.default_rng(seed).normal(0.0, 0.003, x.size)
