"""Play-operator kernels against a plain-Python transcription of eq. 1 and eq. 13."""

import numpy as np
import pytest

from service.science.models import equal_thresholds
from service.science.models.kernels import (
    dynamic_weight_shift,
    envelope_play_operators,
    gpi_step,
    play_operators,
    play_update,
    segment_index,
    segment_of,
)


def reference_play(u, r, y0=0.0):
    """Eq. 1 written out: P(0) = max(u0 − r, min(u0 + r, y0)), then the same recursion."""
    out = []
    y = y0
    for uk in u:
        y = max(uk - r, min(uk + r, y))
        out.append(y)
    return np.array(out)


def reference_envelope_play(h_l, h_r, r, y0=0.0):
    out, y = [], y0
    for lo, hi in zip(h_l, h_r):
        y = max(lo - r, min(hi + r, y))
        out.append(y)
    return np.array(out)


@pytest.fixture
def wild_input():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 3000)
    return 60 + 50 * np.sin(2 * np.pi * 3 * t) * np.cos(2 * np.pi * 0.7 * t) + rng.normal(0, 2, t.size)


def test_thresholds_follow_eq9():
    np.testing.assert_array_equal(equal_thresholds(120.0, 10), [0, 6, 12, 18, 24, 30, 36, 42, 48, 54])


def test_play_operators_equal_python_reference_exactly(wild_input):
    r = np.array([0.0, 3.5, 12.0, 30.0, 54.0])
    y0 = np.array([0.0, 10.0, -4.0, 70.0, 25.0])  # nonzero initial states, some outside the band
    got = play_operators(wild_input, r, y0)
    for j in range(r.size):
        np.testing.assert_array_equal(got[:, j], reference_play(wild_input, r[j], y0[j]))
    relaxed = play_operators(wild_input, r)
    np.testing.assert_array_equal(relaxed[:, 2], reference_play(wild_input, 12.0, 0.0))


def test_envelope_operators_equal_reference_and_reduce_to_eq1(wild_input):
    r = equal_thresholds(120.0, 6)
    h_l, h_r = 1.1 * wild_input + 3.0, 0.9 * wild_input - 2.0
    got = envelope_play_operators(h_l, h_r, r, y0=5.0)
    for j in range(r.size):
        np.testing.assert_array_equal(got[:, j], reference_envelope_play(h_l, h_r, r[j], 5.0))
    np.testing.assert_array_equal(envelope_play_operators(wild_input, wild_input, r), play_operators(wild_input, r))


def test_per_sample_update_matches_batch(wild_input):
    r = equal_thresholds(120.0, 10)
    batch = play_operators(wild_input, r, y0=2.0)
    state = np.full(r.size, 2.0)
    for k, uk in enumerate(wild_input):
        play_update(uk, r, state)
        np.testing.assert_array_equal(state, batch[k])


def test_gpi_step_is_the_weighted_operator_sum(wild_input):
    r = equal_thresholds(120.0, 10)
    w = np.linspace(0.02, 0.001, 10)
    p = play_operators(wild_input, r)
    state = np.zeros(r.size)
    x = np.array([gpi_step(uk, 1.0, 0.0, 1.0, 0.0, r, w, 0.25, state, True) for uk in wild_input])
    np.testing.assert_allclose(x, p @ w + 0.25, rtol=0, atol=1e-12)
    frozen = state.copy()
    gpi_step(17.0, 1.0, 0.0, 1.0, 0.0, r, w, 0.0, state, False)
    np.testing.assert_array_equal(state, frozen)  # commit=False leaves the states alone


def test_segments_follow_eq3_first_matching_row():
    cases = {
        (1.0, 1.0): 0,
        (1.0, -1.0): 1,
        (-1.0, -1.0): 2,
        (-1.0, 1.0): 3,
        (0.0, 0.0): 0,
        (0.0, -1.0): 1,
        (-1.0, 0.0): 2,
        (0.0, 1.0): 0,
    }
    for (du, ddu), seg in cases.items():
        assert segment_of(du, ddu) == seg, (du, ddu)
    du = np.array([k[0] for k in cases])
    ddu = np.array([k[1] for k in cases])
    np.testing.assert_array_equal(segment_index(du, ddu), list(cases.values()))
    alpha, beta = np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0, 30.0, 40.0])
    assert dynamic_weight_shift(-2.0, 0.5, alpha, beta) == 4.0 * -2.0 + 40.0 * 0.5


@pytest.mark.parametrize("fn_hz, zeta", [(300.0, 0.01), (1500.0, 0.3)])
def test_resonance_filter_kernel_matches_scipy_lfilter(fn_hz, zeta):
    """The compiled biquad gives scipy's direct form II transposed output, column by column, about
    the first sample; a constant column passes unchanged and the DC gain is 1."""
    from scipy.signal import bilinear, lfilter

    from service.science.effects.dynamics import resonance_filter

    fs_hz = 10_000.0
    columns = np.cumsum(np.random.default_rng(3).normal(size=(20_000, 5)), axis=0)
    columns[:, 4] = 2.5
    wn = 2.0 * fs_hz * np.tan(np.pi * fn_hz / fs_hz)
    b, a = bilinear([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn], fs_hz)
    expected = lfilter(b, a, columns - columns[:1], axis=0) + columns[:1]
    got = resonance_filter(columns, fs_hz, fn_hz, zeta)
    assert np.max(np.abs(got - expected)) < 1e-9 * np.max(np.abs(expected))
    assert np.array_equal(got[:, 4], columns[:, 4])
    np.testing.assert_allclose(
        resonance_filter(columns[:, 0], fs_hz, fn_hz, zeta),
        expected[:, 0],
        rtol=0,
        atol=1e-9 * np.max(np.abs(expected)),
    )
    step = resonance_filter(np.r_[np.zeros(10), np.ones(20_000)], fs_hz, fn_hz, zeta)
    assert abs(step[-1] - 1.0) < 1e-6
