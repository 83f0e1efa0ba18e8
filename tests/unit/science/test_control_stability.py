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
    from service.science.control.session import PAPER_PID, SCANNED_PID

    loop_delay_s = 1.5 / 20_000  # one sample + half a sample of hold
    for axis, (g, fn) in PAPER_AXES.items():
        paper, tuned = PAPER_PID[axis], SCANNED_PID[axis]
        assert delay_margin(paper.kp, paper.ki, paper.kd, g, fn, 0.05).delay_margin_s < loop_delay_s
        assert delay_margin(tuned.kp, tuned.ki, tuned.kd, g, fn, 0.05).delay_margin_s > 2 * loop_delay_s


def test_loop_margins_of_an_integrator_with_delay_match_the_closed_form():
    """L = K/s·e^(−sτ) (a flat plant: its mode far away): crossover K/(2π) Hz, phase margin 90° − Kτ
    (rad → deg), delay margin π/(2K) − τ; stable while Kτ < π/2, and Nyquist says so."""
    from service.science.control.stability import AxisPlant, loop_margins

    g, tau = 0.08, 125e-6
    for k in (500.0, 5000.0, 11_000.0, 13_000.0):
        m = loop_margins(0.0, k / g, 0.0, 1e-4, AxisPlant(g, 1e7, 0.7, tau))
        assert abs(m.crossover_hz / (k / (2 * np.pi)) - 1) < 0.01
        assert m.stable == (k * tau < np.pi / 2)
        if m.stable:
            assert abs(m.phase_margin_deg - (90 - np.degrees(k * tau))) < 0.5
            assert abs(m.delay_margin_s / (np.pi / (2 * k) - tau) - 1) < 0.03


def test_the_papers_gains_are_predicted_unstable_and_pure_proportional_is_judged_by_its_gain_margin():
    from service.science.control.session import PAPER_PID
    from service.science.control.stability import AxisPlant, loop_margins

    for axis, plant in {"y": AxisPlant(0.06, 482.6, 0.04, 125e-6), "z": AxisPlant(0.087, 290.7, 0.05, 125e-6)}.items():
        p = PAPER_PID[axis]
        m = loop_margins(p.kp, p.ki, p.kd, p.tf_s, plant)
        assert not m.stable and m.gain_margin_db < 0, (axis, m)
    # P on a lightly damped mode: the delay turns the phase past −180° just above the mode, where the
    # mode's peak (1/2ζ = 10×) has lifted |L|; the gain margin falls through 0 dB at kp ≈ 5 V/µm
    plant = AxisPlant(0.087, 290.7, 0.05, 125e-6)
    for kp, stable in ((0.5, True), (2.0, True), (10.0, False)):
        m = loop_margins(kp, 0.0, 0.0, 1e-4, plant)
        assert m.stable == stable and (m.gain_margin_db > 0) == stable, (kp, m)
