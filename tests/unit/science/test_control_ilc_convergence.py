"""The ILC's convergence predicted before a run (issue 19 §3, service.science.control.ilc_stability):
the learning plant is the closed loop with the chosen PID, over the piezo's amplitude band of gains."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.control.ilc_stability import (
    factors,
    learning_refusal,
    max_learning_gain,
    predict_learning,
    predict_plan,
)
from service.science.control.stability import AxisPlant

#: the default bench's plant as "auto" sees it (seed 1, composite models over case 2's span) and auto's gains
PLANTS = {"y": AxisPlant(0.0609, 482.6, 0.02, 125e-6), "z": AxisPlant(0.0872, 290.7, 0.02, 125e-6)}
AUTO = {"y": (0.5999, 248.6, 0.0, 2e-4), "z": (0.4189, 121.5, 3.627e-4, 2e-4)}
SCANNED = {ax: (1.0, 300.0, 0.01, 2e-4) for ax in "yz"}  # issue 6's gains: thin margins on Y


def test_auto_pid_learning_is_predicted_to_converge_at_the_default_gain():
    preds = predict_plan(PLANTS, AUTO, 0.2, 100.0, 20)
    # measured: Y 0.95 (harmonic 5), Z 0.94 (harmonic 3): slow at the worst gain pair of the band, < 1
    assert all(p.factor < 1 for p in preds) and learning_refusal(preds) is None
    assert [p.worst_harmonic for p in preds] == [5, 3]
    assert 0.4 < min(p.max_gain for p in preds) < 0.5


def test_a_learning_gain_too_high_for_the_band_is_refused_on_ilc_gain_with_the_factor():
    preds = predict_plan(PLANTS, AUTO, 0.5, 100.0, 20)
    field, reason = learning_refusal(preds)
    assert field == "controller.ilc_gain"
    assert "predicted convergence factor 1.15" in reason and "≤ 0.45 converges" in reason


def test_thin_margins_diverge_at_any_learning_gain():
    """Issue 19's trip (kp 1, ki 300, kd 0.01 + ILC diverged at 177 ms) is predicted: on Y the closed
    loop's response turns by more than 90° across the band, so no learning gain converges."""
    preds = predict_plan(PLANTS, SCANNED, 0.2, 100.0, 20)
    assert preds[0].max_gain == 0.0 and preds[0].factor > 1
    field, reason = learning_refusal(preds)
    assert field == "controller.ilc" and "at any learning gain" in reason


def test_without_pid_the_factor_is_the_amplitude_band_alone():
    p = predict_learning("y", None, None, 0.2, 100.0, 20)
    assert p.factor == pytest.approx(1 - 0.2 * 0.35)  # the small-signal end learns slowest
    assert p.max_gain == pytest.approx(2 / (1 / 0.35), rel=0.03)  # |1 − γ/0.35| < 1
    buffered = predict_learning("y", None, None, 0.5, 100.0, 20, latency_periods=1)
    assert buffered.factor > 1  # a period's latency halves the stable gains


def test_factor_with_latency_is_the_root_of_the_delayed_recursion():
    r = np.array([0.3 + 0.1j, 1.2 - 0.4j])
    for gain in (0.1, 0.4):
        f = factors(gain, r, 1)
        for ri, fi in zip(r, f):
            assert fi == pytest.approx(max(abs(np.roots([1, -1, gain * ri]))))
    assert max_learning_gain(np.array([1.0 + 0j])) == pytest.approx(2.0, rel=0.03)
