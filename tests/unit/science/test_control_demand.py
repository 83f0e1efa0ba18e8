"""The demand a tracking run puts on the hardware, predicted before it runs (issue 41,
service.science.control.demand), and the learning's robustness filter over the identified mode's
spread (service.science.control.ilc_stability)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.interfaces import AxisLimits
from service.science.control.demand import demand_refusal, predict_demand
from service.science.control.ilc_stability import (
    closed_loop_um_per_v,
    measured_factor,
    mode_spread,
    predict_learning,
    prior_scale,
    scaled_response,
)
from service.science.control.stability import AxisPlant

FS = 20_000.0
#: the default bench's Z channel: 0–150 V stack, 200 kV/s, 0.2 A into 1.8 µF, mode 290.7 Hz
Z_LIMITS = AxisLimits(0.0, 150.0, 2.0e5, 0.2, 1.8e-6, 290.7)
Z_MODE = (290.7, 0.1)


def _periods(frequency_hz: float, amplitude_v: float, periods: int = 4):
    period = int(round(FS / frequency_hz))
    t = np.arange(periods * period) / FS
    return period, 60.0 + amplitude_v * np.sin(2 * np.pi * frequency_hz * t)


def test_the_current_is_c_du_dt_of_the_drive_and_each_harmonic_to_the_mode_is_listed():
    period, u = _periods(200.0, 30.0)
    x = 5.0 + 4.0 * np.sin(2 * np.pi * 200.0 * np.arange(u.size) / FS)
    d = predict_demand("z", Z_LIMITS, x, u, Z_MODE, 200.0, period, FS)
    assert d.peak_current_a == pytest.approx(1.8e-6 * 2 * np.pi * 200.0 * 30.0, rel=0.01)  # 68 mA
    assert [h["k"] for h in d.harmonics] == [1, 2]  # 2 × 200 Hz ≥ 1.25 × 290.7 Hz
    r = 200.0 / 290.7
    assert d.harmonics[0]["mode_gain"] == pytest.approx(1 / abs(1 - r * r + 0.2j * r), rel=1e-9)
    assert d.harmonics[0]["drive_v"] == pytest.approx(30.0, rel=1e-6)
    assert d.harmonics[0]["reference_um"] == pytest.approx(4.0, rel=1e-6)
    assert d.exceeded() == [] and demand_refusal([d], 200.0) is None


def test_a_drive_beyond_the_current_or_voltage_limit_is_refused_with_the_figure_and_by_how_much():
    period, u = _periods(400.0, 45.0)  # 2π·400·45·1.8 µF = 204 mA > 0.9 × 200 mA
    d = predict_demand("z", Z_LIMITS, u / 10, u, Z_MODE, 400.0, period, FS)
    why = demand_refusal([d], 400.0)
    assert "axis z: peak current 203 mA" in why and "(180 mA) by 13 %" in why
    period, u = _periods(50.0, 95.0)  # -35…155 V
    why = demand_refusal([predict_demand("z", Z_LIMITS, u / 10, u, Z_MODE, 50.0, period, FS)], 50.0)
    assert "drive -35.0–155.0 V leaves the axis's 0–150 V limits by 35.0 V" in why
    assert demand_refusal([predict_demand("z", Z_LIMITS, u / 10, u, Z_MODE, 50.0, period, FS)], 50.0, np.inf) is None


def test_the_mode_spread_widens_the_prediction_and_the_filter_cuts_harmonics_that_would_not_converge():
    spread = mode_spread([290.7, 297.3], [0.02, 0.113])
    assert spread.fn_hz[0] < 290.7 and spread.fn_hz[1] > 297.3 and spread.zeta == (0.02, 0.113)
    plant = AxisPlant(0.0872, 290.7, 0.02, 125e-6)
    pid = (0.4189, 121.5, 3.627e-4, 2e-4)
    nominal = predict_learning("z", plant, pid, 0.2, 200.0, 20)
    robust = predict_learning("z", plant, pid, 0.2, 200.0, 20, spread=spread)
    assert nominal.harmonics == 20 and nominal.cut_hz is None  # no spread: every harmonic asked for
    # the robustness filter: harmonics up to 2 × the top of the spread (2 × 303 Hz: 3 × 200 Hz)
    assert robust.harmonics == 3 and robust.cut_hz == pytest.approx(800.0)
    assert robust.factor >= np.max(predict_learning("z", plant, pid, 0.2, 200.0, 3).factor) - 1e-12
    assert robust.factor < 0.98
    assert robust.expected == pytest.approx(0.8, abs=0.05)  # the median at the fundamental: 1 − γ
    # a learning gain that harmonic 2 (400 Hz, past the mode) would not converge at over the spread:
    # the prediction says so (measured: 1.00 at 400 Hz), and the request is refused (learning_refusal)
    fast = predict_learning("z", plant, pid, 0.65, 200.0, 20, spread=spread)
    assert fast.worst_harmonic == 2 and fast.factor >= 1.0


def test_the_measured_factor_is_the_decay_of_the_error_above_its_floor():
    e = list(100.0 * 0.75 ** np.arange(12)) + [3.0] * 12
    assert measured_factor(e) == pytest.approx(0.75, abs=1e-9)
    assert measured_factor([3.0] * 30) is None


@pytest.mark.parametrize("share", [0.9, 1.1])
def test_the_predicted_current_is_the_emulators_own_and_the_amplifier_trips_beyond_it(share):
    """The emulated amplifier (Z, 0.2 A into 1.8 µF) latches an over-current fault when its drive needs
    more current than its limit for 5 ms, and not below it: as the demand predicts."""
    from drivers.factory import open_bench

    bench = open_bench("default", seed=3)
    try:
        amp, lim = bench.parts.amplifiers["z"], bench.limits["z"]
        f = share * lim.current_limit_a / (lim.capacitance_f * 2 * np.pi * 40.0)  # 40 V amplitude
        t = np.arange(int(0.05 * FS)) / FS
        u = 40.0 - 40.0 * np.cos(2 * np.pi * f * t)  # from rest, 0–80 V
        period = int(round(FS / f))
        d = predict_demand("z", lim, u / 10, u, Z_MODE, f, period, FS)
        assert d.peak_current_a == pytest.approx(share * lim.current_limit_a, rel=0.01)
        bench.parts.daq.write_read(np.column_stack([np.zeros_like(u), u / amp.gain_v_per_v]))
        assert amp.status().fault == (d.peak_current_a > lim.current_limit_a)
    finally:
        bench.close()


def test_the_learning_prior_is_scaled_to_the_trajectorys_gain_through_the_closed_loop():
    """G₀ measured with a small probe sees the stack's small-signal gain; the prior becomes the closed
    loop around the trajectory's gain (κ = 2 here): exactly T at twice the plant's gain."""
    pid = (0.4189, 121.5, 3.627e-4, 2e-4)
    small, mode = AxisPlant(0.04, 290.7, 0.1, 125e-6), (290.7, 0.1)
    f = 150.0 * np.arange(6)
    g0 = closed_loop_um_per_v(small, pid, f)
    kappa = prior_scale(g0, 150.0, pid, 0.08, mode)
    assert kappa == pytest.approx(2.0, rel=0.01)  # |e^(−sτ)| = 1: only the mode's gain is taken out
    large = closed_loop_um_per_v(AxisPlant(0.08, 290.7, 0.1, 125e-6), pid, f)
    assert np.allclose(scaled_response(g0, 150.0, pid, kappa)[1:], large[1:], rtol=0.01)
    assert prior_scale(g0, 150.0, pid, 0.01, mode) == 1.0  # never below the probe's
