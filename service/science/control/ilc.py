"""Learned periodic correction (ILC) in the harmonic domain, with a zero-phase Q-filter.

Per steady period j with error e_j (µm), for harmonics k = 0..K of the trajectory frequency:
    U_{j+1}(k) = U_j(k) + γ_k · E_j(k) / Ĝ(k),      U(k) = 0 for k > K   (Q: ideal zero-phase low-pass)
Ĝ(k) (µm/V) is the response from the feedforward input to the gauge at k·f0. Its prior G₀ is measured
on the bench by a small multisine in the same loop (PID on or off) that the ILC runs in; the piezo's
incremental gain depends on the amplitude, though (a 4 V minor loop has about a third of the full
swing's), so Ĝ is refined from the run itself: every period gives ΔE(k) ≈ −G(k)·ΔU(k) between the
corrections actually applied, and Ĝ is the Bayesian blend of those observations (weighted by |ΔU|²,
forgetting factor ρ) with G₀ (trusted to ±50 %). Learning converges while the phase error of Ĝ is below 90°.

Noise. σ² (µm², per harmonic of one period's normalised DFT) is measured with G₀. Harmonics whose
error is within 2σ of zero learn with γ/4, so the correction averages the noise out instead of
freezing a sample of it in. The monitor watches the learnable error (harmonics 0..K, where noise is
a small part) rather than the total: it stops learning when that has not fallen for ``patience``
periods (resuming if the total rises 1.25× above its best, e.g. by creep), and falls back to the best
correction with half the gain if the total grows 3× (divergence).
"""

from __future__ import annotations

import numpy as np

from drivers.jit import njit

#: Ĝ's prior is trusted to this fraction of |G₀| (one standard deviation)
PRIOR_REL_SD = 0.5
#: forgetting factor of the running Ĝ estimate per period
FORGET = 0.95
#: |E(k)|² below this many σ² counts as noise: that harmonic learns with γ·NOISE_GAIN_FACTOR
SNR_GATE = 4.0
NOISE_GAIN_FACTOR = 0.25


def multisine(period: int, harmonics: int, amplitude_v: float, seed: int = 0) -> np.ndarray:
    """One period (samples) of a Schroeder-phased multisine on harmonics 1..K, peak ≈ amplitude_v."""
    k = np.arange(1, harmonics + 1)
    phase = -np.pi * k * (k - 1) / harmonics
    t = np.arange(period) / period
    s = np.cos(2 * np.pi * np.outer(t, k) + phase).sum(axis=1)
    return amplitude_v * s / np.max(np.abs(s))


def period_spectra(x: np.ndarray, period: int, harmonics: int) -> np.ndarray:
    """Normalised DFT (x's unit) at harmonics 0..K of each whole period: (periods, K+1[, ...])."""
    m = len(x) // period
    return np.fft.rfft(x[: m * period].reshape(m, period, *x.shape[1:]), axis=1)[:, : harmonics + 1] / period


def frf_from_periods(u_v: np.ndarray, x_um: np.ndarray, period: int, harmonics: int) -> tuple[np.ndarray, float]:
    """G(k) (µm/V), k = 0..K, from whole periods of periodic input/output (averaged spectra), and the
    noise variance σ² (µm²) of one period's normalised DFT of x at a harmonic (median over k of the
    period-to-period scatter). G(0) is taken as the real |G(1)| (a multisine has no DC)."""
    U = period_spectra(u_v, period, harmonics).mean(axis=0)
    Xp = period_spectra(x_um, period, harmonics)
    X = Xp.mean(axis=0)
    g = X / np.where(np.abs(U) > 0, U, 1.0)
    g[0] = abs(g[1])
    scatter = np.mean(np.abs(Xp[:, 1:] - X[None, 1:]) ** 2, axis=0) * len(Xp) / max(len(Xp) - 1, 1)
    return g, float(np.median(scatter))


class HarmonicILC:
    """Per-axis harmonic ILC on one period. ``g`` (2, K+1) measured responses G₀ (µm/V);
    ``noise_var_um2`` (2,) σ² per axis (see the module doc; None: no SNR gating); ``learned_harmonics``
    (2,) the highest harmonic each axis learns (the robustness filter; None: all K)."""

    def __init__(
        self,
        g: np.ndarray,
        period: int,
        gain: float = 0.2,
        patience: int = 15,
        min_improvement: float = 0.01,
        noise_var_um2=None,
        adapt: bool = True,
        learned_harmonics=None,
    ):
        self.g0 = np.asarray(g, dtype=complex)
        self.g = self.g0.copy()
        self.harmonics = self.g.shape[1] - 1
        if period // 2 < self.harmonics:
            raise ValueError(f"harmonics: {self.harmonics} exceed the period's Nyquist limit ({period // 2})")
        self.period, self.gain = period, float(gain)
        self.patience, self.min_improvement = patience, min_improvement
        self.noise_var = (
            np.zeros(2)
            if noise_var_um2 is None  # no noise known: every harmonic learns at γ
            else np.broadcast_to(np.asarray(noise_var_um2, float), (2,)).copy()
        )
        self.adapt = adapt
        # the robustness filter per axis: harmonics above an axis's ``learned_harmonics`` do not learn
        tops = np.broadcast_to(self.harmonics if learned_harmonics is None else learned_harmonics, (2,))
        self.q = (np.arange(self.harmonics + 1)[None, :] <= np.asarray(tops)[:, None]).astype(float)
        self.u_v = np.zeros((period, 2))
        self.best_u_v = self.u_v.copy()
        self.best_learnable_um = np.inf
        self.best_rms_um = np.inf
        self.stale = 0
        self.learning = True
        self.history_um: list[float] = []
        self.stop_reason: str | None = None
        self.resume_factor = 1.25
        self.resumed = 0
        self.reverts = 0
        self._suu = np.zeros((2, self.harmonics + 1))
        self._sue = np.zeros((2, self.harmonics + 1), dtype=complex)
        self._see = np.zeros((2, self.harmonics + 1))
        self._n = 0.0
        self._prev: tuple[np.ndarray, np.ndarray] | None = None  # (E, applied U) (2, K+1) of the last period
        k = np.arange(self.harmonics + 1)[:, None]
        phase = 2 * np.pi * k * np.arange(period)[None, :] / period
        self._cos, self._sin = np.cos(phase), np.sin(phase)  # (K+1, period) DFT tables
        self._zeros = np.zeros((period, 2))
        compile_kernels()

    # ------------------------------------------------------------------ the response estimate
    def _refine_response(self, E: np.ndarray, applied_v: np.ndarray | None) -> None:
        """Blend this period's ΔE/ΔU observation into Ĝ (see the module doc). E (2, K+1) µm."""
        if applied_v is None or not self.adapt:
            return
        A = np.empty_like(E)
        spectrum(np.ascontiguousarray(applied_v), self._cos, self._sin, A)
        if self._prev is not None:
            self._n = FORGET * self._n + 1.0
            blend_response(
                E,
                A,
                self._prev[0],
                self._prev[1],
                self._suu,
                self._sue,
                self._see,
                self._n,
                self.g0,
                self.noise_var,
                PRIOR_REL_SD,
                FORGET,
                self.g,
            )
        self._prev = (E, A)

    # ------------------------------------------------------------------ one period
    def update(
        self, error_um: np.ndarray, base_v: np.ndarray | None = None, limits_v=None, applied_v: np.ndarray | None = None
    ) -> np.ndarray:
        """Learn from one period's error (period, 2) µm; returns the correction (period, 2) V to apply next.

        ``applied_v`` is the correction that was actually applied during that period (the loop may
        run one or more periods behind ``u_v``): it is what Ĝ is refined from. With ``base_v`` (the
        feedforward's period, V) and ``limits_v`` (lo, hi) per axis, the total command is projected
        into the limits, so the learned correction cannot wind up against the clamp."""
        error_um = np.ascontiguousarray(error_um)
        E = np.empty((2, self.harmonics + 1), dtype=complex)  # normalised DFT, µm
        rms, learnable = spectrum(error_um, self._cos, self._sin, E)
        self.history_um.append(rms)
        self._refine_response(E, applied_v)
        self.best_rms_um = min(self.best_rms_um, rms)
        if not self.learning:  # paused: resume if the plant has drifted away
            if rms > self.resume_factor * self.best_rms_um:
                self.learning, self.stale = True, 0
                self.best_rms_um, self.best_learnable_um = rms, learnable
                self.resumed += 1
            return self.u_v
        if rms > 3.0 * self.best_rms_um:  # diverging: back to the best correction, half the gain
            self.u_v, self.gain = self.best_u_v.copy(), 0.5 * self.gain
            self.best_rms_um, self.best_learnable_um, self.stale = np.inf, np.inf, 0
            self.reverts += 1
            self.stop_reason = f"error grew to {rms * 1e3:.1f} nm RMS: reverted, gain halved to {self.gain:g}"
            if self.reverts >= 3:
                self.learning = False
            return self.u_v
        if learnable < self.best_learnable_um * (1 - self.min_improvement):
            self.best_learnable_um, self.best_u_v, self.stale = learnable, self.u_v.copy(), 0
        else:
            self.stale += 1
            if self.stale >= self.patience:
                self.learning = False
                self.stop_reason = (
                    f"learnable error stopped falling (best {self.best_learnable_um * 1e3:.1f} nm "
                    f"RMS in harmonics 0–{self.harmonics}); learning paused, resumes if the "
                    f"error rises {self.resume_factor:g}×"
                )
                return self.u_v
        self.u_v = self.u_v.copy()
        if base_v is None or limits_v is None:
            base_v, limits_v = self._zeros, (np.full(2, -np.inf), np.full(2, np.inf))
        coef_re, coef_im = np.empty((2, self.harmonics + 1)), np.empty((2, self.harmonics + 1))
        learning_coefficients(E, self.g, self.gain, SNR_GATE * self.noise_var, NOISE_GAIN_FACTOR, coef_re, coef_im)
        coef_re *= self.q
        coef_im *= self.q
        learn_step(
            E,
            coef_re,
            coef_im,
            self._cos,
            self._sin,
            self.u_v,
            np.ascontiguousarray(base_v),
            np.asarray(limits_v[0], dtype=float),
            np.asarray(limits_v[1], dtype=float),
        )
        return self.u_v


@njit(cache=True, fastmath=True, nogil=True)
def learn_step(E, coef_re, coef_im, cos_t, sin_t, u, base, lo, hi):
    """One compiled ILC step in place: per axis a, with E (2, K+1) the period's error at harmonics
    0..K (normalised DFT, µm), Δu = irfft(coef[a, k]·E(k)) (harmonics above K zero: the Q-filter),
    u += Δu, then u is projected so that base + u stays within [lo[a], hi[a]] V. ``coef`` = γ/Ĝ(k)
    (V/µm) as real and imaginary parts."""
    n, kk = u.shape[0], cos_t.shape[0]
    for a in range(u.shape[1]):
        d_re = np.empty(kk)
        d_im = np.empty(kk)
        for k in range(kk):
            er, ei = E[a, k].real, E[a, k].imag
            d_re[k] = coef_re[a, k] * er - coef_im[a, k] * ei
            d_im[k] = coef_re[a, k] * ei + coef_im[a, k] * er
        acc = np.full(n, d_re[0])
        for k in range(1, kk):
            cr, ci = 2.0 * d_re[k], 2.0 * d_im[k]
            for i in range(n):
                acc[i] += cr * cos_t[k, i] - ci * sin_t[k, i]
        for i in range(n):
            total = min(max(base[i, a] + u[i, a] + acc[i], lo[a]), hi[a])
            u[i, a] = total - base[i, a]


@njit(cache=True, nogil=True)
def blend_response(E, A, E_prev, A_prev, suu, sue, see, n, g0, noise_var, prior_rel_sd, forget, g):
    """One period's Ĝ refinement in place (see the module doc). E, A (2, K+1): this period's error and
    applied correction spectra; suu, sue, see: the forgetting sums of |ΔU|², conj(ΔU)·(−ΔE), |ΔE|²;
    n: the forgetting count (already updated). Ĝ keeps G₀ until two observations are in, and where
    ΔU(k) explains nothing of ΔE(k) (then the unexplained variance, floored at 2σ², is the prior's weight)."""
    for a in range(E.shape[0]):
        for k in range(E.shape[1]):
            de = E[a, k] - E_prev[a, k]
            da = A[a, k] - A_prev[a, k]
            suu[a, k] = forget * suu[a, k] + (da.real * da.real + da.imag * da.imag)
            sue[a, k] = forget * sue[a, k] - np.conj(da) * de
            see[a, k] = forget * see[a, k] + (de.real * de.real + de.imag * de.imag)
            if n <= 1.5 or suu[a, k] <= 0.0:
                g[a, k] = g0[a, k]
                continue
            explained = (sue[a, k].real ** 2 + sue[a, k].imag ** 2) / suu[a, k]
            unexplained = max((see[a, k] - explained) / max(n - 1.0, 1.0), 2.0 * noise_var[a])
            sd = prior_rel_sd * abs(g0[a, k])
            w0 = unexplained / (sd * sd) if sd > 0.0 else np.inf
            if not np.isfinite(w0):
                g[a, k] = g0[a, k]
                continue
            est = (sue[a, k] + w0 * g0[a, k]) / (suu[a, k] + w0)
            g[a, k] = est.real + 0j if k == 0 else est  # DC gain is real


@njit(cache=True, fastmath=True, nogil=True)
def spectrum(x, cos_t, sin_t, out):
    """Normalised DFT of each column of x (n, 2) at harmonics 0..K into out (2, K+1); returns
    (RMS of x, RMS of its harmonics 0..K), both in x's unit. Each column is copied out first so the
    inner sums run over contiguous rows of the tables (about 3× faster than striding x)."""
    n, kk, cols = x.shape[0], cos_t.shape[0], x.shape[1]
    col = np.empty(n)
    total = 0.0
    band = 0.0
    for a in range(cols):
        for i in range(n):
            col[i] = x[i, a]
            total += col[i] * col[i]
        for k in range(kk):
            c, s = cos_t[k], sin_t[k]
            re = 0.0
            im = 0.0
            for i in range(n):
                re += col[i] * c[i]
                im += col[i] * s[i]
            out[a, k] = complex(re / n, -im / n)
            band += (re * re + im * im) / (n * n) * (1.0 if k == 0 else 2.0)
    return np.sqrt(total / (n * cols)), np.sqrt(band / cols)


@njit(cache=True, nogil=True)
def learning_coefficients(E, g, gain, gate, noise_factor, coef_re, coef_im):
    """γ_k/Ĝ(k) per (axis, harmonic) into coef_re/coef_im: γ where |E(k)|² > gate[a] (SNR_GATE·σ²),
    γ·noise_factor where the error is at the noise."""
    for a in range(E.shape[0]):
        for k in range(E.shape[1]):
            e2 = E[a, k].real ** 2 + E[a, k].imag ** 2
            c = (gain * noise_factor if e2 <= gate[a] else gain) / g[a, k]
            coef_re[a, k] = c.real
            coef_im[a, k] = c.imag


_compiled = False


def compile_kernels() -> None:
    """Compile the per-period kernels once per process (seconds on a fresh numba cache), so it
    happens before a tracking run arms the bench's watchdog, not in its first period."""
    global _compiled
    if _compiled:
        return
    e = np.zeros((4, 2))
    cos_t, sin_t = np.ones((2, 4)), np.zeros((2, 4))
    E, A = np.zeros((2, 2), dtype=complex), np.zeros((2, 2), dtype=complex)
    spectrum(e, cos_t, sin_t, E)
    g = np.ones((2, 2), dtype=complex)
    blend_response(
        E,
        A,
        E.copy(),
        A.copy(),
        np.zeros((2, 2)),
        np.zeros((2, 2), dtype=complex),
        np.zeros((2, 2)),
        2.0,
        g,
        np.zeros(2),
        PRIOR_REL_SD,
        FORGET,
        g.copy(),
    )
    re, im = np.zeros((2, 2)), np.zeros((2, 2))
    learning_coefficients(E, g, 0.1, np.zeros(2), 0.25, re, im)
    learn_step(E, re, im, cos_t, sin_t, np.zeros((4, 2)), np.zeros((4, 2)), np.zeros(2), np.ones(2))
    _compiled = True
