"""Blocks of records imported without a block table (service/science/data/segmentation.py), on synthetic drives."""
from __future__ import annotations

import numpy as np

from service.science.data.segmentation import blocks_without_table, detect_blocks

FS = 2000.0


def biased_sine(f_hz: float, cycles: int, rest_s: float = 0.2) -> np.ndarray:
    """A 0–120 V biased sine from 0 V (as a sweep block), followed by a rest at 0 V."""
    t = np.arange(int(round(cycles * FS / f_hz))) / FS
    return np.concatenate([60 - 60 * np.cos(2 * np.pi * f_hz * t), np.zeros(int(rest_s * FS))])


def test_a_sequential_two_axis_sweep_is_cut_into_its_frequencies_and_axes():
    parts = [biased_sine(1, 5), biased_sine(10, 5), biased_sine(50, 5)]
    y = np.concatenate(parts)
    rest = np.zeros(y.size)
    u = {"y": np.concatenate([y, rest]), "z": np.concatenate([rest, y])}
    blocks = detect_blocks(u, FS)
    assert [round(b["frequency_hz"], 6) for b in blocks] == [1.0, 10.0, 50.0] * 2
    assert [b["axes"] for b in blocks] == [["y"]] * 3 + [["z"]] * 3
    assert all(b["cycles"] == 4 for b in blocks)            # whole cycles between mid-level crossings
    starts = np.cumsum([0] + [p.size for p in parts])
    for b, k in zip(blocks, list(range(3)) * 2):            # each block lies inside its own sine
        offset = 0 if b["axes"] == ["y"] else y.size
        sine_start, sine_stop = offset + starts[k], offset + starts[k] + round(5 * FS / b["frequency_hz"])
        assert sine_start <= b["start"] < b["stop"] <= sine_stop


def test_axes_driven_together_make_one_block_and_a_single_sine_is_one_whole_block():
    y = np.concatenate([biased_sine(2, 6), biased_sine(20, 6)])
    blocks = detect_blocks({"y": y, "z": 0.5 * y}, FS)
    assert [b["axes"] for b in blocks] == [["y", "z"], ["y", "z"]]
    [one] = blocks_without_table({"y": biased_sine(1, 20)}, FS)          # one steady oscillation
    assert (one["start"], one["frequency_hz"], one["cycles"]) == (0, 1.0, 20)
    [none] = blocks_without_table({"y": np.full(5000, 30.0)}, FS)        # no oscillation at all
    assert none["frequency_hz"] is None and (none["start"], none["stop"]) == (0, 5000)


def test_prominent_peaks_are_scipys_without_its_quadratic_scan():
    """Equally high peaks (a clean or quantised drive) made SciPy scan the whole record from every
    peak; ``prominent_peaks`` must give exactly SciPy's peaks, plateaus and ties included."""
    from scipy.signal import find_peaks

    from service.science.data.signals import prominent_peaks

    rng = np.random.default_rng(0)
    for trial in range(200):
        n = int(rng.integers(3, 400))
        y = [rng.normal(size=n).cumsum(), np.round(3 * np.sin(np.arange(n) * rng.uniform(0.05, 1.0))),
             rng.integers(0, 3, n).astype(float), np.round(rng.normal(size=n).cumsum())][trial % 4]
        for prominence in (0.0, 0.5, 1.0, 2.0):
            np.testing.assert_array_equal(prominent_peaks(y, prominence), find_peaks(y, prominence=prominence)[0])
    drive = np.round(biased_sine(10, 2000, rest_s=0), 3)             # 400 000 samples, 2000 equal peaks
    assert prominent_peaks(drive, 12.0).size == 2000
