"""The tracking error's split into harmonics of the period and the rest (service.reports.tracking_error_spectrum)."""

import numpy as np

from service.reports.tracking_error_spectrum import HARMONICS, error_harmonics


def test_known_harmonics_and_noise_are_recovered():
    period, periods = 200, 40
    t = np.arange(period * periods) / period
    rng = np.random.default_rng(3)
    locked = 0.05 + 0.03 * np.sin(2 * np.pi * t + 0.4) + 0.14 * np.cos(2 * np.pi * 3 * t)  # µm
    noise = rng.standard_normal(t.size) * 0.003
    ref = 5 + 4 * np.sin(2 * np.pi * t)
    amplitudes, rest = error_harmonics(ref, ref - locked - noise, period, periods=20)
    assert amplitudes.shape == (HARMONICS,)
    np.testing.assert_allclose(amplitudes[[0, 1, 3]], [0.05, 0.03, 0.14], atol=0.0015)  # noise/√20 per harmonic
    assert amplitudes[[2, 4, 5, 6, 7]].max() < 0.0015
    assert 0.0027 < rest < 0.0031  # the noise left after the period average: σ·√(1 − 1/20)
