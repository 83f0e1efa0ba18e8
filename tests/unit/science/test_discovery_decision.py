"""The claim rule's signed-rank test (service.science.discovery.decision.held_out_improvement):
segments where two fits agree to rounding are ties, whatever the rounding's sign."""

from __future__ import annotations

import numpy as np

from service.science.data.record import Record
from service.science.discovery.decision import TIE_SHARE, _segments, held_out_improvement

FS = 2000.0


def _two_axis_record() -> Record:
    """Four held-out blocks of Y (10 Hz, 5 cycles each), then four that drive only Z (Y still)."""
    t = np.arange(int(FS * 0.5)) / FS
    burst = 60 - 60 * np.cos(2 * np.pi * 10 * t)
    n = burst.size
    u_y = np.concatenate([burst] * 4 + [np.zeros(n)] * 4)
    u_z = np.concatenate([np.zeros(n)] * 4 + [burst] * 4)
    blocks = [
        {"start": i * n, "stop": (i + 1) * n, "axis": "y" if i < 4 else "z", "frequency_hz": 10.0} for i in range(8)
    ]
    return Record(u_y, 0.05 * u_y, FS, blocks=blocks, axis="y", u_other_v=u_z, hold_out=True)


def test_segments_that_differ_by_rounding_are_ties_whatever_the_sign():
    record = _two_axis_record()
    rng = np.random.default_rng(0)
    reference = 0.01 * rng.standard_normal(record.n_samples)
    better = reference.copy()
    z_blocks = slice(4 * record.n_samples // 8, record.n_samples)
    better[: z_blocks.start] *= 0.9 + 0.2 * rng.random(z_blocks.start)  # Y's blocks: a real change
    exact = held_out_improvement([record], [reference], [better])
    counted = exact["segments"]
    y_segments = sum(len(_segments(record, s)) for s in record.splits if s.held_out[0] < z_blocks.start)
    assert counted == y_segments > 0  # the Z blocks' residuals are the same: ties
    # the same, with rounding-sized differences of either sign on the Z blocks (as two fits that
    # agree there give): the count and p do not move
    for sign in (1.0, -1.0):
        rounded = better.copy()
        rounded[z_blocks] *= 1.0 + sign * 1e-14 * rng.random(record.n_samples - z_blocks.start)
        assert np.any(rounded[z_blocks] != reference[z_blocks])
        out = held_out_improvement([record], [reference], [rounded])
        assert out["segments"] == counted and out["p"] == exact["p"], (sign, out, exact)
    # a difference a thousand times the tie share is a difference
    real = better.copy()
    real[z_blocks] *= 1.0 + 1e3 * TIE_SHARE
    assert held_out_improvement([record], [reference], [real])["segments"] > counted
