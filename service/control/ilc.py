"""Learned periodic correction (ILC) in the harmonic domain, with a zero-phase Q-filter.

Per steady period j with error e_j (µm), for harmonics k = 0..K of the trajectory frequency:
    U_{j+1}(k) = U_j(k) + γ · E_j(k) / G(k),      U(k) = 0 for k > K   (Q: ideal zero-phase low-pass)
G(k) is the measured response (µm/V) from the feedforward input to the gauge at k·f0, measured
on the bench by a small periodic multisine in the same loop (PID on or off) that the ILC runs in.
The learning converges while |1 − γ·G_true/G| < 1 per harmonic, i.e. a phase error below 90°.
A monitor pauses learning when the error has not fallen for ``patience`` periods (resuming if it
later rises 1.25× above the best, e.g. by creep), and falls back to the best correction with half the
gain if the error grows 3× (divergence).
"""
from __future__ import annotations

import numpy as np
from numba import njit


def multisine(period: int, harmonics: int, amplitude_v: float, seed: int = 0) -> np.ndarray:
    """One period (samples) of a Schroeder-phased multisine on harmonics 1..K, peak ≈ amplitude_v."""
    k = np.arange(1, harmonics + 1)
    phase = -np.pi * k * (k - 1) / harmonics
    t = np.arange(period) / period
    s = np.cos(2 * np.pi * np.outer(t, k) + phase).sum(axis=1)
    return amplitude_v * s / np.max(np.abs(s))


def frf_from_periods(u_v: np.ndarray, x_um: np.ndarray, period: int, harmonics: int) -> np.ndarray:
    """G(k) (µm/V), k = 0..K, from whole periods of periodic input/output (averaged spectra).
    G(0) is taken as the real |G(1)| (a multisine has no DC)."""
    m = len(u_v) // period
    U = np.fft.rfft(u_v[:m * period].reshape(m, period), axis=1).mean(axis=0)
    X = np.fft.rfft(x_um[:m * period].reshape(m, period), axis=1).mean(axis=0)
    g = X[:harmonics + 1] / np.where(np.abs(U[:harmonics + 1]) > 0, U[:harmonics + 1], 1.0)
    g[0] = abs(g[1])
    return g


class HarmonicILC:
    """Per-axis harmonic ILC on one period. ``g`` (2, K+1) measured responses (µm/V)."""

    def __init__(self, g: np.ndarray, period: int, gain: float = 0.2, patience: int = 15,
                 min_improvement: float = 0.01):
        self.g = np.asarray(g, dtype=complex)
        self.harmonics = self.g.shape[1] - 1
        if period // 2 < self.harmonics:
            raise ValueError(f"harmonics: {self.harmonics} exceed the period's Nyquist limit ({period // 2})")
        self.period, self.gain = period, float(gain)
        self.patience, self.min_improvement = patience, min_improvement
        self.u_v = np.zeros((period, 2))
        self.best_u_v = self.u_v.copy()
        self.best_rms_um = np.inf
        self.stale = 0
        self.learning = True
        self.history_um: list[float] = []
        self.stop_reason: str | None = None
        self.resume_factor = 1.25
        self.resumed = 0
        self.reverts = 0
        k = np.arange(self.harmonics + 1)[:, None]
        phase = 2 * np.pi * k * np.arange(period)[None, :] / period
        self._cos, self._sin = np.cos(phase), np.sin(phase)        # (K+1, period) DFT tables
        self._zeros = np.zeros((period, 2))

    def update(self, error_um: np.ndarray, base_v: np.ndarray | None = None, limits_v=None) -> np.ndarray:
        """Learn from one period's error (period, 2) µm; returns the correction (period, 2) V to apply next.

        With ``base_v`` (the feedforward's period, V) and ``limits_v`` (lo, hi) per axis, the total
        command is projected into the limits, so the learned correction cannot wind up against the clamp."""
        flat = error_um.ravel()
        rms = float(np.sqrt(flat @ flat / flat.size))
        self.history_um.append(rms)
        if not self.learning:                 # paused: resume if the plant has drifted away
            if rms > self.resume_factor * self.best_rms_um:
                self.learning, self.stale, self.best_rms_um = True, 0, rms
                self.resumed += 1
            return self.u_v
        if rms < self.best_rms_um * (1 - self.min_improvement):
            self.best_rms_um, self.best_u_v, self.stale = rms, self.u_v.copy(), 0
        else:
            self.stale += 1
            if rms > 3.0 * self.best_rms_um:  # diverging: back to the best correction, half the gain
                self.u_v, self.gain = self.best_u_v.copy(), 0.5 * self.gain
                self.best_rms_um, self.stale, self.reverts = np.inf, 0, self.reverts + 1
                self.stop_reason = f"error grew to {rms * 1e3:.1f} nm RMS: reverted, gain halved to {self.gain:g}"
                if self.reverts >= 3:
                    self.learning = False
                return self.u_v
            if self.stale >= self.patience:
                self.learning = False
                self.stop_reason = (f"error stopped falling (best {self.best_rms_um * 1e3:.1f} nm RMS); learning "
                                    f"paused, resumes if it rises {self.resume_factor:g}×")
                return self.u_v
        self.u_v = self.u_v.copy()
        if base_v is None or limits_v is None:
            base_v, limits_v = self._zeros, (np.full(2, -np.inf), np.full(2, np.inf))
        if getattr(self, "_coef_gain", None) != self.gain:
            c = self.gain / self.g
            self._coef, self._coef_gain = (np.ascontiguousarray(c.real), np.ascontiguousarray(c.imag)), self.gain
        learn_step(np.ascontiguousarray(error_um), self._coef[0], self._coef[1], self._cos,
                   self._sin, self.u_v, np.ascontiguousarray(base_v), np.asarray(limits_v[0], dtype=float),
                   np.asarray(limits_v[1], dtype=float))
        return self.u_v

    def learning_matrices(self) -> np.ndarray:
        """(2, period, period) real matrices L with Δu = L·e per axis: irfft(Q·γ/G·rfft(e))."""
        eye = np.eye(self.period)
        E = np.fft.rfft(eye, axis=0)[:self.harmonics + 1]            # (K+1, period)
        out = np.empty((2, self.period, self.period))
        for a in range(2):
            dU = np.zeros((self.period // 2 + 1, self.period), dtype=complex)
            dU[:self.harmonics + 1] = self.gain * E / self.g[a][:, None]
            out[a] = np.fft.irfft(dU, n=self.period, axis=0)
        return out

    def _step(self, error_um: np.ndarray) -> np.ndarray:
        """Δu (period, 2) V for one period's error by the dense learning matrices (reference for tests)."""
        return np.matmul(self.learning_matrices(), error_um.T[:, :, None])[:, :, 0].T


@njit(cache=True, fastmath=True)
def learn_step(e, coef_re, coef_im, cos_t, sin_t, u, base, lo, hi):
    """One compiled ILC step in place: per axis a, E(k) = DFT of e[:, a] at harmonics 0..K,
    Δu = irfft(coef[a, k]·E(k)) (harmonics above K zero: the Q-filter), u += Δu, then u is projected
    so that base + u stays within [lo[a], hi[a]] V. ``coef`` = γ/G(k) (V/µm) as real and imaginary parts."""
    n, kk = e.shape[0], cos_t.shape[0]
    ea = np.empty(n)
    for a in range(e.shape[1]):
        for i in range(n):
            ea[i] = e[i, a]
        d_re = np.zeros(kk)
        d_im = np.zeros(kk)
        for k in range(kk):
            er = 0.0
            ei = 0.0
            for i in range(n):
                er += ea[i] * cos_t[k, i]
                ei -= ea[i] * sin_t[k, i]
            d_re[k] = coef_re[a, k] * er - coef_im[a, k] * ei
            d_im[k] = coef_re[a, k] * ei + coef_im[a, k] * er
        acc = np.full(n, d_re[0])
        for k in range(1, kk):
            cr, ci = 2.0 * d_re[k], 2.0 * d_im[k]
            for i in range(n):
                acc[i] += cr * cos_t[k, i] - ci * sin_t[k, i]
        for i in range(n):
            v = u[i, a] + acc[i] / n
            total = min(max(base[i, a] + v, lo[a]), hi[a])
            u[i, a] = total - base[i, a]
