"""Periodic steady state in the frequency domain, for searching a transform's parameters.

The mean training cycle of each periodic block becomes harmonic phasors of the measurement and of
every design column. A linear time-invariant transform (a resonance) multiplies harmonic k by its
response H(f_k), so for one candidate (fn, ζ) the whole linear fit is a small least-squares
problem on the harmonics; for many candidates the normal equations are one matrix product
(variable projection on a dense grid). Bounds on the weights are ignored here: the search only
locates the nonlinear parameters, the exact bounded fit follows in the time domain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: harmonics above this fraction of the sample rate are left out (anti-alias margin)
MAX_HARMONIC_FRACTION_OF_FS = 0.45
#: harmonics kept per block (a biased sine's loop has little above this; it bounds the cost)
HARMONICS_PER_BLOCK = 60


@dataclass
class HarmonicData:
    """Harmonics across every periodic block: ``frequency_hz`` (K,), the columns ``a`` (K, p) and
    the measurement ``x`` (K,), complex phasors in µm per unit weight / µm."""

    frequency_hz: np.ndarray
    a: np.ndarray
    x: np.ndarray

    @property
    def empty(self) -> bool:
        return self.frequency_hz.size == 0


def mean_cycle(r: np.ndarray, period_samples: int) -> np.ndarray | None:
    """Mean of the whole cycles of ``r`` (n, …) along axis 0 (the first cycle dropped when three or
    more), or None with fewer than two cycles."""
    n = r.shape[0] // period_samples
    if n < 2:
        return None
    mat = r[: n * period_samples].reshape((n, period_samples) + r.shape[1:])
    return (mat[1:] if n >= 3 else mat).mean(axis=0)


def harmonic_data(records, columns) -> HarmonicData:
    """Harmonics 1..K of each periodic block's training cycles (period a whole number of samples,
    at least two cycles). ``columns[k]`` (n, p) is the design of ``records[k]``."""
    freqs, cols, xs = [], [], []
    for rec, a in zip(records, columns):
        for s in rec.splits:
            period = rec.period_samples(s)
            if not period or abs(period - round(period)) > 1e-6:
                continue
            m = int(round(period))
            lo, hi = s.train
            ac, xc = mean_cycle(a[lo:hi], m), mean_cycle(rec.x_um[lo:hi], m)
            if ac is None:
                continue
            f0 = rec.sample_rate_hz / m
            k_max = min(HARMONICS_PER_BLOCK, m // 2 - 1, int(MAX_HARMONIC_FRACTION_OF_FS * rec.sample_rate_hz / f0))
            if k_max < 1:
                continue
            freqs.append(f0 * np.arange(1, k_max + 1))
            cols.append(np.fft.rfft(ac, axis=0)[1 : k_max + 1] / m)
            xs.append(np.fft.rfft(xc)[1 : k_max + 1] / m)
    if not freqs:
        return HarmonicData(np.zeros(0), np.zeros((0, 0), complex), np.zeros(0, complex))
    return HarmonicData(np.concatenate(freqs), np.vstack(cols), np.concatenate(xs))


def projected_costs(h: np.ndarray, data: HarmonicData, ridge: float = 1e-9) -> np.ndarray:
    """For responses ``h`` (G, K): min over real weights c of Σ_k |x_k − h_k·(a_k·c)|² per row (µm²),
    all G rows by one matrix product (normal equations Σ_k |h_k|² Re(ā_k a_kᵀ))."""
    a = data.a / np.maximum(np.linalg.norm(data.a, axis=0), 1e-300)  # unit columns: conditioning
    k, p = a.shape
    outer = np.real(np.conj(a)[:, :, None] * a[:, None, :]).reshape(k, p * p)
    normal = (np.abs(h) ** 2 @ outer).reshape(-1, p, p)
    diagonal = np.arange(p)
    normal[:, diagonal, diagonal] += ridge * np.trace(normal, axis1=1, axis2=2)[:, None] / p  # on the diagonal only
    rhs = np.real(np.conj(h) @ (np.conj(a) * data.x[:, None]))
    coef = np.linalg.solve(normal, rhs[:, :, None])[:, :, 0]
    return float(np.sum(np.abs(data.x) ** 2)) - np.einsum("gp,gp->g", rhs, coef)
