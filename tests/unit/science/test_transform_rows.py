"""A fit's design needs the transformed columns at its training rows only (about 1 in 24 samples
of a sweep): the resonance filter writes those rows alone and a delay reads its input at the rows
its taps name. Both give exactly the numbers of the full transform at those rows, and a fitted
composite's training error is the one its full-length prediction gives there."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.record import Record
from service.science.discovery.composite import CompositeModel
from service.science.effects import EFFECTS
from service.science.effects.dynamics import NO_MODE, resonance_filter
from service.science.fitting.metrics import rms

FS = 20_000.0


def test_the_filter_at_rows_is_the_full_filter_there_bit_for_bit():
    x = np.random.default_rng(4).normal(size=(5000, 7)).cumsum(axis=0)
    rows = np.array([3, 4, 90, 1234, 4000])  # stops after 4000: the tail is never run
    full = resonance_filter(x, FS, 900.0, 0.05)
    assert np.array_equal(resonance_filter(x, FS, 900.0, 0.05, rows), full[rows])
    assert np.array_equal(resonance_filter(x[:, 0], FS, 900.0, 0.05, rows), full[rows, 0])
    with pytest.raises(ValueError, match="rise"):
        resonance_filter(x, FS, 900.0, 0.05, np.array([5, 5]))


def test_a_column_that_comes_to_rest_leaves_no_subnormal_tail():
    """An operator that moves, then rests at 0 V for 40 000 samples: scipy's lfilter rings down into
    subnormals (below 2.2e-308, 25x slower in every later product); the kernel's tail is exactly 0
    where lfilter's is that small, and equals lfilter's to 1e-12 µm everywhere."""
    from scipy.signal import bilinear, lfilter

    x = np.zeros((60_000, 2))
    x[:2000, 0] = np.sin(np.linspace(0.0, 20 * np.pi, 2000)) * 50.0
    x[:2000, 1] = np.linspace(0.0, 30.0, 2000)  # a step down to rest at 0
    fn_hz, zeta = 3000.0, 0.2
    wn = 2.0 * FS * np.tan(np.pi * fn_hz / FS)
    b, a = bilinear([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn], FS)
    ref = lfilter(b, a, x, axis=0)
    tiny = np.finfo(float).tiny
    assert np.sum((ref != 0.0) & (np.abs(ref) < tiny)) > 10_000  # the world the flush is for
    out = resonance_filter(x, FS, fn_hz, zeta)
    assert np.sum((out != 0.0) & (np.abs(out) < tiny)) == 0
    assert np.max(np.abs(out - ref)) < 1e-12


def test_a_mode_above_half_the_sample_rate_is_the_identity_a_fit_starts_from():
    """The composite starts every search from fn = 1e12 Hz. There the prewarp's tan is meaningless
    (wn = -0.00078 rad/s at 20 kHz) and scipy's bilinear gave a one-coefficient numerator, so the
    kernel read two coefficients past the array: garbage that now and then overflowed a fit's normal
    matrix (numba's NUMBA_BOUNDSCHECK=1 found it). Now such a mode passes every column unchanged."""
    x = np.random.default_rng(6).normal(size=(2000, 4)).cumsum(axis=0)
    for fn_hz in (NO_MODE["fn_hz"], 0.5 * FS, 3e9):
        assert np.array_equal(resonance_filter(x, FS, fn_hz, NO_MODE["zeta"]), x)
        assert np.array_equal(resonance_filter(x, FS, fn_hz, 1.0, np.array([0, 7, 1999])), x[[0, 7, 1999]])
    assert not np.array_equal(resonance_filter(x, FS, 0.45 * FS, 0.3), x)  # the highest mode a fit may place


def test_the_delay_at_rows_is_the_full_delay_there_bit_for_bit():
    x = np.random.default_rng(5).normal(size=(3000, 3))
    rows = np.array([0, 1, 2, 500, 2999])
    for delay_s in (0.0, 3.3 / FS, 17.0 / FS):
        theta = {"delay_s": delay_s}
        assert np.array_equal(
            EFFECTS["delay"].apply_rows(x, FS, theta, rows), EFFECTS["delay"].apply(x, FS, theta)[rows]
        )


def test_a_fit_with_a_mode_and_a_delay_trains_on_what_its_prediction_gives():
    t = np.arange(int(1.5 * FS)) / FS
    u = 60.0 - 55.0 * np.cos(2 * np.pi * 20.0 * t) + 5.0 * np.sin(2 * np.pi * 230.0 * t)
    x = 0.1 * resonance_filter(np.roll(u, 3), FS, 1800.0, 0.08) + 2e-3 * np.random.default_rng(6).normal(size=t.size)
    record = Record(u, x, FS, label="mode+delay")
    model = CompositeModel(["dynamics", "delay"]).fit([record])
    rows = record.fit_rows()
    assert model.train_rms_um == pytest.approx(rms(record.x_um[rows] - model.predict(record)[rows]), rel=1e-9)
    assert model.theta["delay"]["delay_s"] > 0 and 1000.0 < model.theta["dynamics"]["fn_hz"] < 3000.0
