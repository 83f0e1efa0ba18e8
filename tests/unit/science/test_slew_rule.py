"""The amplifier's rate limit is testable only where it could act (issue 38 §3): a bench's records
carry the rate its amplifier is rated to move the stack (I/C, or its slew rating), and a drive whose
fastest rate stays under half of it cannot be held back, whatever the residual looks like. An
import's amplifier is unknown, so there the records decide alone."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.interfaces import AxisLimits
from service.science.data.record import Record
from service.science.effects import EFFECTS

FS = 20_000.0  # Hz


def _sine_record(f_hz: float, rated_rate_v_per_s: float | None) -> Record:
    """Five cycles of a 0–120 V sine at ``f_hz`` (steepest rate π·f·120 V/s)."""
    t = np.arange(int(5 * FS / f_hz)) / FS
    u = 60.0 - 60.0 * np.cos(2 * np.pi * f_hz * t)
    return Record(u, 0.05 * u, FS, rated_rate_v_per_s=rated_rate_v_per_s)


DEFAULT_AMPLIFIER = AxisLimits(0.0, 150.0, 2.0e5, 0.2, 1.8e-6, 482.6)  # the default bench: 111 kV/s
WEAK_AMPLIFIER = AxisLimits(0.0, 150.0, 2.0e5, 0.07, 1.8e-6, 482.6)  # the slew bench's 70 mA: 38.9 kV/s


def test_the_rated_rate_is_the_lower_of_i_over_c_and_the_slew_rating():
    assert DEFAULT_AMPLIFIER.max_rate_v_per_s == pytest.approx(0.2 / 1.8e-6)
    assert AxisLimits(0.0, 150.0, 5.0e4, 0.2, 1.8e-6, 482.6).max_rate_v_per_s == 5.0e4


def test_a_drive_far_under_the_amplifiers_rating_cannot_test_a_rate_limit():
    reason = EFFECTS["slew_limit"].untestable([_sine_record(100.0, DEFAULT_AMPLIFIER.max_rate_v_per_s)])
    assert reason is not None and "37.7 kV/s" in reason and "111 kV/s" in reason, reason


@pytest.mark.parametrize(
    "f_hz, rated, why",
    [
        (100.0, WEAK_AMPLIFIER.max_rate_v_per_s, "37.7 kV/s against a 38.9 kV/s rating"),
        (200.0, DEFAULT_AMPLIFIER.max_rate_v_per_s, "75.4 kV/s: past half the 111 kV/s rating"),
        (100.0, None, "an import: the amplifier is unknown"),
    ],
)
def test_a_drive_near_the_rating_or_of_an_unknown_amplifier_can(f_hz, rated, why):
    assert EFFECTS["slew_limit"].untestable([_sine_record(f_hz, rated)]) is None, why


def test_the_rated_rate_survives_taking_a_line_out_of_the_record():
    rec = _sine_record(100.0, 1.0e5)
    assert rec.with_x(rec.x_um + 1e-3).rated_rate_v_per_s == 1.0e5
