"""The harmonic ILC on a simulated linear periodic plant: the in-run refinement of Ĝ rescues learning
when the measured G₀ is wrong by more than 90° of phase (where plain γ/G₀ learning stalls or
diverges), and the SNR gate lets the correction average the gauge noise out."""

from __future__ import annotations

import numpy as np

from service.science.control.ilc import HarmonicILC

PERIOD, K = 200, 20


def plant_response(g_true: np.ndarray, u: np.ndarray) -> np.ndarray:
    """x (period, 2) µm of a linear periodic plant with responses g_true (2, K+1) µm/V to u (period, 2) V."""
    U = np.fft.rfft(u, axis=0)
    X = np.zeros_like(U)
    X[: K + 1] = U[: K + 1] * g_true.T
    return np.fft.irfft(X, n=PERIOD, axis=0)


def reference() -> np.ndarray:
    t = np.arange(PERIOD) / PERIOD
    r = np.stack(
        [
            0.5 * np.sin(2 * np.pi * t) + 0.05 * np.sin(2 * np.pi * 6 * t + 0.3),
            0.8 * np.cos(2 * np.pi * t) + 0.04 * np.cos(2 * np.pi * 7 * t),
        ],
        axis=1,
    )
    return r - r.mean(axis=0)


def run(ilc: HarmonicILC, g_true: np.ndarray, periods: int, noise_um: float, seed: int = 0) -> list[float]:
    rng = np.random.default_rng(seed)
    r = reference()
    for _ in range(periods):
        applied = ilc.u_v
        e = r - plant_response(g_true, applied) - noise_um * rng.standard_normal((PERIOD, 2))
        ilc.update(e, applied_v=applied)
    return ilc.history_um


def g_nominal() -> np.ndarray:
    k = np.arange(K + 1)
    g = 0.05 * np.exp(-1j * 2 * np.pi * k * 0.02) / (1 + 1j * k / 15)  # µm/V, delay + lag
    return np.stack([g, g])


def test_refined_response_rescues_learning_where_the_measured_phase_is_wrong_by_over_90_degrees():
    g0 = g_nominal()
    g_true = 2.5 * g0.copy()  # the large-signal gain is 2.5× the small-signal one
    g_true[:, 5:9] *= np.exp(-1j * np.deg2rad(110))  # and a shifted mode: > 90° phase error at 5–8
    noise = 1e-3
    var = np.full(2, noise**2 / PERIOD)  # σ² of one period's normalised DFT
    plain = run(HarmonicILC(g0, PERIOD, noise_var_um2=var, adapt=False), g_true, 60, noise)
    adaptive_ilc = HarmonicILC(g0, PERIOD, noise_var_um2=var, adapt=True)
    adaptive = run(adaptive_ilc, g_true, 60, noise)
    assert max(plain) > 1.5 * plain[0] or plain[-1] > 0.5 * plain[0]  # plain learning diverges or stalls
    assert adaptive[-1] < 0.05 * adaptive[0]  # refined learning converges 20×
    assert adaptive[-1] < 2.0 * noise
    ratio = adaptive_ilc.g / g0  # where the reference has content (Y: 6th, Z: 7th harmonic)
    excited = np.array([ratio[0, 6], ratio[1, 7]])
    assert np.all(np.abs(np.angle(excited, deg=True) + 110) < 15)  # Ĝ found the phase shift
    assert np.all(np.abs(np.abs(excited) - 2.5) < 0.4) and np.all(np.abs(np.abs(ratio[:, 1]) - 2.5) < 0.4)


def test_learned_correction_averages_the_noise_out():
    """With a fixed gain γ the correction freezes in √(γ/(2−γ)) of the noise in its 2K+1 learned
    components; the noise gate (γ/4 where the error is at the noise) must leave less."""
    g0 = g_nominal()
    noise = 3e-3
    var = np.full(2, noise**2 / PERIOD)
    gamma = 0.2
    fixed_gain_um = noise * np.sqrt(gamma / (2 - gamma)) * np.sqrt((2 * K + 1) / PERIOD)
    r = reference()
    left = []
    for seed in range(5):
        ilc = HarmonicILC(g0, PERIOD, gain=gamma, noise_var_um2=var, patience=1000, adapt=False)
        run(ilc, g0, 80, noise, seed=seed)
        left.append(np.sqrt(np.mean((r - plant_response(g0, ilc.u_v)) ** 2)))  # systematic error left, µm
    assert np.mean(left) < 0.75 * fixed_gain_um
    assert max(left) < 0.15 * noise
