"""Blocks of records imported without a block table (service/segmentation.py), on synthetic drives."""
from __future__ import annotations

import numpy as np

from service.segmentation import detect_blocks, imported_blocks

FS = 2000.0


def biased_sine(f_hz: float, cycles: int, rest_s: float = 0.2) -> np.ndarray:
    """A 0–120 V biased sine from 0 V (as a sweep block), followed by a rest at 0 V."""
    t = np.arange(int(round(cycles * FS / f_hz))) / FS
    return np.concatenate([60 - 60 * np.cos(2 * np.pi * f_hz * t), np.zeros(int(rest_s * FS))])


def test_a_sequential_two_axis_sweep_is_cut_into_its_frequencies_and_axes():
    y = np.concatenate([biased_sine(1, 5), biased_sine(10, 5), biased_sine(50, 5)])
    rest = np.zeros(y.size)
    u = {"y": np.concatenate([y, rest]), "z": np.concatenate([rest, y])}
    blocks = detect_blocks(u, FS)
    assert [round(b["frequency_hz"], 6) for b in blocks] == [1.0, 10.0, 50.0] * 2
    assert [b["axes"] for b in blocks] == [["y"]] * 3 + [["z"]] * 3
    assert all(b["cycles"] == 4 for b in blocks)            # whole cycles between mid-level crossings
    for b in blocks:                                        # each block lies inside its sine
        period = FS / b["frequency_hz"]
        assert b["stop"] - b["start"] == round(b["cycles"] * period)


def test_axes_driven_together_make_one_block_and_a_single_sine_needs_no_table():
    y = np.concatenate([biased_sine(2, 6), biased_sine(20, 6)])
    blocks = detect_blocks({"y": y, "z": 0.5 * y}, FS)
    assert [b["axes"] for b in blocks] == [["y", "z"], ["y", "z"]]
    assert imported_blocks({"y": biased_sine(1, 20)}, FS) is None          # one steady oscillation
    assert imported_blocks({"y": np.full(5000, 30.0)}, FS) is None         # no oscillation at all
