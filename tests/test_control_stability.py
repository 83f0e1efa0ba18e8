"""Delay margins of PID gains on a flexure axis, checked against closed forms."""
from __future__ import annotations

import numpy as np

from service.science.control.stability import delay_margin


def test_pure_proportional_on_a_static_plant_has_an_infinite_margin_and_pd_crosses_where_kd_says():
    # P alone with kp·g = 0.4 on a well-damped mode (no peak) never reaches |L| = 1; with ζ = 0.05 the
    # mode's peak (1/2ζ = 10×) lifts it above 1 and the margin becomes finite
    assert np.isinf(delay_margin(5.0, 0.0, 0.0, 0.08, 300.0, 0.7).delay_margin_s)
    assert np.isfinite(delay_margin(5.0, 0.0, 0.0, 0.08, 300.0, 0.05).delay_margin_s)
    # far above the mode a PD loop is kd·g·ωn²/ω: crossover at kd·g·ωn²/(2π) Hz, phase margin → 90°
    m = delay_margin(0.0, 0.0, 0.08, 0.077, 290.7, 0.05)
    expected_hz = 0.08 * 0.077 * (2 * np.pi * 290.7) ** 2 / (2 * np.pi)
    assert abs(m.crossover_hz / expected_hz - 1) < 0.01
    assert abs(m.phase_margin_deg - 90) < 3
    assert abs(m.delay_margin_s - np.pi / 2 / (2 * np.pi * m.crossover_hz)) < 2e-6


def test_the_papers_gains_need_less_delay_than_a_20_khz_loop_has():
    from service.reports.tracking import PAPER_AXES
    from service.science.control.session import PAPER_PID, TUNED_PID

    loop_delay_s = 1.5 / 20_000                      # one sample + half a sample of hold
    for axis, (g, fn) in PAPER_AXES.items():
        paper, tuned = PAPER_PID[axis], TUNED_PID[axis]
        assert delay_margin(paper.kp, paper.ki, paper.kd, g, fn, 0.05).delay_margin_s < loop_delay_s
        assert delay_margin(tuned.kp, tuned.ki, tuned.kd, g, fn, 0.05).delay_margin_s > 2 * loop_delay_s
