"""Record validation and the signal helpers it relies on."""

import numpy as np
import pytest
from scipy.signal import savgol_filter

from service.science.data.record import Record
from service.science.data.signals import (
    SAVGOL_DIRECT_MAX_WINDOW,
    SAVGOL_POLYORDER,
    biased_sine,
    dominant_period_samples,
    multi_sine,
    savgol,
    savgol_derivatives,
)
from service.science.models import StaticPI

FS = 20_000.0


def sine_u(n=4000, cycles=4):
    return 60.0 - 60.0 * np.cos(2 * np.pi * cycles * np.arange(n) / n)


def test_nan_is_named_with_count_and_samples():
    u = sine_u()
    u[[10, 11, 12]] = np.nan
    with pytest.raises(ValueError, match=r"u_v contains 3 NaN values at samples 10, 11, 12"):
        Record(u, np.zeros(u.size), FS)
    x = np.zeros(u.size)
    x[7] = np.inf
    with pytest.raises(ValueError, match=r"x_um contains 1 infinite value at sample 7"):
        Record(sine_u(), x, FS)


def test_length_mismatch_names_both_arrays():
    with pytest.raises(ValueError, match=r"u_v has 1000 samples but x_um has 999"):
        Record(sine_u(1000), np.zeros(999), FS)
    with pytest.raises(ValueError, match=r"u_v has 1000 samples but du_v_per_s has 10"):
        Record(sine_u(1000), None, FS, du_v_per_s=np.zeros(10), ddu_v_per_s2=np.zeros(1000))


def test_constant_input_excites_no_hysteresis():
    with pytest.raises(ValueError, match=r"u_v is constant \(60 V\): it excites no hysteresis"):
        Record(np.full(500, 60.0), np.zeros(500), FS)


def test_too_few_samples_per_cycle_says_how_many():
    u = sine_u(n=400, cycles=40)  # 10 samples per cycle
    with pytest.raises(ValueError, match=r"u_v has only 10\.0 samples per cycle.*at least 20"):
        Record(u, np.zeros(u.size), FS)
    assert Record(sine_u(n=1000, cycles=40), None, FS).period_samples() == pytest.approx(25.0, abs=0.1)


@pytest.mark.parametrize("rate", [0.0, -5.0, float("nan"), "fast"])
def test_sample_rate_must_be_positive(rate):
    with pytest.raises(ValueError, match="sample_rate_hz"):
        Record(sine_u(), None, rate)


def test_fit_requires_a_displacement_and_label_appears():
    s = Record(sine_u(), None, FS, label="10 Hz")
    with pytest.raises(ValueError, match=r"record '10 Hz' has no x_um"):
        StaticPI().fit(s)
    with pytest.raises(ValueError, match=r"record 'bad': u_v contains"):
        Record(np.array([1.0, np.nan, 3.0] * 100), None, FS, label="bad")


def test_dominant_period_from_turning_points_ignores_noise():
    rng = np.random.default_rng(0)
    w = biased_sine(10.0, 5, FS)
    assert dominant_period_samples(w.value + rng.normal(0, 0.5, w.value.size)) == pytest.approx(2000, rel=0.01)
    assert dominant_period_samples(np.linspace(0, 120, 300)) == pytest.approx(2 * 299)  # a ramp: one half cycle


def test_savgol_derivatives_track_the_analytic_ones():
    """Window = period/10, polyorder 4: measured 4.2e-5 (u̇) and 3.9e-3 (ü, 1 Hz) relative max errors."""
    for f in (1.0, 10.0, 100.0):
        w = biased_sine(f, 5, FS)
        d1, d2 = savgol_derivatives(w.value, FS)
        assert np.max(np.abs(d1 - w.d1_per_s)) < 1e-4 * np.max(np.abs(w.d1_per_s))
        assert np.max(np.abs(d2 - w.d2_per_s2)) < 1e-2 * np.max(np.abs(w.d2_per_s2))


@pytest.mark.parametrize(
    "n, window", [(20_001, SAVGOL_DIRECT_MAX_WINDOW + 2), (100_000, 2001), (60_000, 6001), (30_001, 30_001)]
)
def test_long_windows_by_fft_are_scipys_savgol_filter(n, window):
    """Past SAVGOL_DIRECT_MAX_WINDOW the convolution runs by FFT: the same filter as scipy's, edges
    included (mode="interp"), to 1e-12 of the largest value; a 1 Hz block's window is 2001 samples, a
    step-hold block's thousands."""
    rng = np.random.default_rng(3)
    y = np.cumsum(rng.normal(size=n)) + 40.0 * np.sin(np.arange(n) / 700.0)
    for deriv in (1, 2):
        want = savgol_filter(y, window, SAVGOL_POLYORDER, deriv=deriv, delta=1 / FS, mode="interp")
        got = savgol(y, window, deriv, 1 / FS)
        assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want)), deriv


def test_record_uses_given_derivatives_else_estimates():
    w = multi_sine([10.0, 40.0], [40.0, 10.0], FS, 0.3)
    exact = Record.from_waveform(w)
    assert exact.analytic_derivatives and exact.derivatives()[0] is not None
    np.testing.assert_array_equal(exact.derivatives()[1], w.d2_per_s2)
    estimated = Record(w.value, None, FS)
    assert not estimated.analytic_derivatives
    assert np.max(np.abs(estimated.derivatives()[0] - w.d1_per_s)) < 1e-3 * np.max(np.abs(w.d1_per_s))
    with pytest.raises(ValueError, match="both du_v_per_s and ddu_v_per_s2"):
        Record(w.value, None, FS, du_v_per_s=w.d1_per_s)
