"""Blocks of records imported without a block table (service/science/data/segmentation.py), on synthetic drives."""

from __future__ import annotations

import numpy as np
import pytest

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
    assert all(b["cycles"] == 4 for b in blocks)  # whole cycles between mid-level crossings
    starts = np.cumsum([0] + [p.size for p in parts])
    for b, k in zip(blocks, list(range(3)) * 2):  # each block lies inside its own sine
        offset = 0 if b["axes"] == ["y"] else y.size
        sine_start, sine_stop = offset + starts[k], offset + starts[k] + round(5 * FS / b["frequency_hz"])
        assert sine_start <= b["start"] < b["stop"] <= sine_stop


def test_axes_driven_together_make_one_block_and_a_single_sine_is_one_whole_block():
    y = np.concatenate([biased_sine(2, 6), biased_sine(20, 6)])
    blocks = detect_blocks({"y": y, "z": 0.5 * y}, FS)
    assert [b["axes"] for b in blocks] == [["y", "z"], ["y", "z"]]
    [one] = blocks_without_table({"y": biased_sine(1, 20)}, FS)  # one steady oscillation
    assert (one["start"], one["frequency_hz"], one["cycles"]) == (0, 1.0, 20)
    [none] = blocks_without_table({"y": np.full(5000, 30.0)}, FS)  # no oscillation at all
    assert none["frequency_hz"] is None and (none["start"], none["stop"]) == (0, 5000)


def test_prominent_peaks_are_scipys_without_its_quadratic_scan():
    """Equally high peaks (a clean or quantised drive) made SciPy scan the whole record from every
    peak; ``prominent_peaks`` must give exactly SciPy's peaks, plateaus and ties included."""
    from scipy.signal import find_peaks

    from service.science.data.signals import prominent_peaks

    rng = np.random.default_rng(0)
    for trial in range(200):
        n = int(rng.integers(3, 400))
        y = [
            rng.normal(size=n).cumsum(),
            np.round(3 * np.sin(np.arange(n) * rng.uniform(0.05, 1.0))),
            rng.integers(0, 3, n).astype(float),
            np.round(rng.normal(size=n).cumsum()),
        ][trial % 4]
        for prominence in (0.0, 0.5, 1.0, 2.0):
            np.testing.assert_array_equal(prominent_peaks(y, prominence), find_peaks(y, prominence=prominence)[0])
    drive = np.round(biased_sine(10, 2000, rest_s=0), 3)  # 400 000 samples, 2000 equal peaks
    assert prominent_peaks(drive, 12.0).size == 2000


def _swept_beside_steady(z_hz: float) -> dict:
    """Y at 1 Hz then 10 Hz (10 s each) while Z oscillates steadily at ``z_hz`` the whole time."""
    t = np.arange(int(20 * FS)) / FS
    phase = 2 * np.pi * np.cumsum(np.where(t < 10, 1.0, 10.0)) / FS
    return {"y": 60 - 60 * np.cos(phase), "z": 40 - 40 * np.cos(2 * np.pi * z_hz * t)}


def test_axes_driven_at_once_at_their_own_frequencies_make_blocks_that_never_overlap():
    """A new user's import: Y swept while Z ran steadily at 5 Hz. Z's one long run swallowed Y's 1 Hz
    run (one block 'at 5 Hz' driving both), Y's 10 Hz block overlapped it, and every diagnosis of
    the dataset answered 500 (the rows of a fit must rise)."""
    u = _swept_beside_steady(5.0)
    blocks = detect_blocks(u, FS)
    assert all(a["stop"] <= b["start"] for a, b in zip(blocks, blocks[1:])), blocks
    together = [b for b in blocks if len(b["axes"]) == 2]
    assert [{a: round(f, 6) for a, f in b["frequencies_hz"].items()} for b in together] == [
        {"y": 1.0, "z": 5.0},
        {"y": 10.0, "z": 5.0},
    ]
    # each block is whole cycles of the period at which its drives repeat together (1 s, then 0.2 s)
    assert [round(b["frequency_hz"], 6) for b in together] == [1.0, 5.0]
    for b in together:
        assert b["stop"] - b["start"] == round(b["cycles"] * FS / b["frequency_hz"]) and b["cycles"] >= 8
        assert 0 <= b["start"] and b["stop"] <= u["y"].size
    # 5.3 Hz beside 1 Hz repeats every 10 s, longer than the stretch; beside 10 Hz never: no period
    loose = [b for b in detect_blocks(_swept_beside_steady(5.3), FS) if len(b["axes"]) == 2]
    assert [b["frequency_hz"] for b in loose] == [None, None]  # and so have no period
    assert [b["joint_frequency_hz"] for b in loose] == [pytest.approx(0.1), None]  # 53/10: 10 s > the stretch


def test_a_diagnosis_of_axes_driven_at_their_own_frequencies_names_both_in_its_blocks():
    from service.science.data.record import Record
    from service.science.discovery.diagnosis import diagnose
    from service.usecases.discover import block_title

    u = _swept_beside_steady(5.0)
    x = {a: 0.1 * v + 0.3 * np.sin(v / 20.0) for a, v in u.items()}  # a static nonlinearity
    record = Record(u["y"], x["y"], FS, axis="y", u_other_v=u["z"], x_other_um=x["z"], hold_out=True)
    d = diagnose([record])  # raised 'rows must rise strictly' on the overlapping blocks
    assert d["verdict"] in ("complete", "missing_effect") and 0 < d["residual_rms_um"] < 1.0
    titles = [block_title("y", s, FS) for s in record.splits]
    assert "Y 10 Hz + Z 5 Hz detected, repeating at 5 Hz (held-out common cycles" in titles[-1], titles
