"""Issue 37, records as labs make them: an imported step-hold is read as steps, in both record forms.

A staircase of holds (0 → 96 → 24 → 120 → 48 → 84 → 0 V, half a second each) has turning points a
steady half second apart, and was read as a 1 Hz block of two cycles: its 84 V hold, a minor loop the
sines never draw, fell outside every block (neither fitted nor held out), and the step block's tiny
residual put a "1.00001 Hz" point into the residual-against-frequency description, which then read a
rate-independent stage as "a rate-dependent loop". Drives built here with numpy, not the product's
plans.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from service.science.data.segmentation import blocks_without_table

FS = 5000.0  # Hz
LEVELS_V = (96.0, 24.0, 120.0, 48.0, 84.0, 0.0)
HOLD_S = 0.5


def _staircase(rest_s: float = 0.2) -> np.ndarray:
    """The step-hold drive (V): a rest at 0 V, then each level held HOLD_S."""
    return np.concatenate([np.zeros(int(rest_s * FS))] + [np.full(int(HOLD_S * FS), v) for v in LEVELS_V])


def _sine_burst(f_hz: float, cycles: int = 5) -> np.ndarray:
    t = np.arange(int(cycles * FS / f_hz)) / FS
    return 60.0 - 60.0 * np.cos(2 * np.pi * f_hz * t)


def _rest(s: float) -> np.ndarray:
    return np.zeros(int(s * FS))


def test_a_staircase_is_one_step_block_per_level_and_no_oscillation():
    u = _staircase()
    blocks = blocks_without_table({"y": u}, FS)
    assert [b["kind"] for b in blocks] == ["step"] * len(LEVELS_V)
    assert [b["level_v"] for b in blocks] == pytest.approx(LEVELS_V, abs=1e-9)
    assert all(b["frequency_hz"] is None and b["cycles"] is None for b in blocks)
    # contiguous, each the step into its level and its hold, the last to the record's end
    assert all(a["stop"] == b["start"] for a, b in zip(blocks, blocks[1:]))
    assert blocks[-1]["stop"] == u.size
    assert [b["index"] for b in blocks] == list(range(len(LEVELS_V)))


def test_the_staircase_gives_the_same_blocks_alone_and_after_a_sweep_in_one_long_record():
    sweep = np.concatenate([_rest(0.3), _sine_burst(1.0), _rest(0.5), _sine_burst(10.0), _rest(0.5)])
    long_record = np.concatenate([sweep, _staircase()])
    alone = blocks_without_table({"y": _staircase()}, FS)
    blocks = blocks_without_table({"y": long_record}, FS)
    periodic = [b for b in blocks if b["kind"] != "step"]
    steps = [b for b in blocks if b["kind"] == "step"]
    assert [round(b["frequency_hz"], 3) for b in periodic] == [1.0, 10.0]
    shift = sweep.size
    assert [(b["start"] - shift, b["stop"] - shift) for b in steps] == [(b["start"], b["stop"]) for b in alone]
    assert [b["index"] for b in blocks] == list(range(len(blocks)))


def test_rests_between_bursts_and_a_single_offset_hold_are_not_steps():
    rests = np.concatenate([_rest(0.5), _sine_burst(10.0), _rest(0.5), _sine_burst(50.0), _rest(0.5)])
    assert {b["kind"] for b in blocks_without_table({"y": rests}, FS)} == {"detected"}
    offset = np.concatenate([_rest(0.5), _sine_burst(10.0), _rest(0.5), np.full(int(0.5 * FS), 60.0), _rest(0.5)])
    assert "step" not in {b["kind"] for b in blocks_without_table({"y": offset}, FS)}


def test_a_steady_oscillation_repeats_its_levels():
    """Turning points a steady half period apart whose levels change by a fifth of the swing are not
    one oscillation: a sine whose amplitude changes half way is two blocks, not one."""
    small = 60.0 - 48.0 * np.cos(2 * np.pi * 10.0 * np.arange(int(0.5 * FS)) / FS)
    big = _sine_burst(10.0)
    blocks = blocks_without_table({"y": np.concatenate([_rest(0.3), small, big, _rest(0.3)])}, FS)
    periodic = [b for b in blocks if b["kind"] == "detected"]
    assert len(periodic) == 2, blocks
    assert all(round(b["frequency_hz"], 3) == 10.0 for b in periodic)


@pytest.mark.filterwarnings("ignore")
def test_a_failing_hold_is_named_by_its_level():
    """With one block per level, six places were all called "step-hold block": the failures list names
    each by its index and its level (a Jiles–Atherton stage, one file per block, 5 kHz)."""
    from service.science.discovery.diagnosis import diagnose
    from tests.support.hysteresis_worlds import records

    d = diagnose(records("jiles_atherton", "blocks", fs=FS))
    holds = [f["where"] for f in d["failures"] if "step-hold block" in f["where"]]
    assert holds, [f["where"] for f in d["failures"]]
    assert all(re.search(r"step-hold block \d+ \(the hold at -?[0-9.]+ V\)", w) for w in holds), holds
    assert len(set(holds)) == len(holds)
