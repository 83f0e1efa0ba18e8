"""Sweep plans → per-axis waveforms and block tables (no bench needed here)."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.plans import (
    ChirpPlan,
    MultisinePlan,
    PlanError,
    SinePlan,
    StepPlan,
    build,
    check_sample_rate,
    plan_from_dict,
    trim_blocks,
)

MAX_RATE = 100e3  # V/s


def test_biased_sine_blocks_follow_the_formula():
    plan = SinePlan(frequencies_hz=(10.0, 50.0), cycles=3, v_min=10.0, v_max=110.0, settle_s=0.1)
    sweep = build(plan, MAX_RATE)
    u, fs = sweep.u_v["y"], sweep.sample_rate_hz
    assert u[0] < 1.0 and u[-1] == 0.0  # ramps from and back to 0 V
    assert [b["frequency_hz"] for b in sweep.blocks] == [10.0, 50.0]
    for block in sweep.blocks:
        assert block["kind"] == "sine" and block["cycles"] == 3 and block["axes"] == ["y"]
        n = block["stop"] - block["start"]
        assert n == round(3 * fs / block["frequency_hz"])
        t = np.arange(n) / fs
        expected = 10 + 100 * (1 - np.cos(2 * np.pi * block["frequency_hz"] * t)) / 2
        np.testing.assert_allclose(u[block["start"] : block["stop"]], expected, atol=1e-9)
    # settling at v_min between the blocks, which belongs to no block
    gap = u[sweep.blocks[0]["stop"] : sweep.blocks[1]["start"]]
    assert len(gap) == round(0.1 * fs) and np.all(gap == 10.0)
    assert np.max(np.abs(np.diff(u))) * fs < MAX_RATE


def test_axes_one_after_the_other_hold_the_idle_axis_at_zero():
    sweep = build(SinePlan(axes=("y", "z"), frequencies_hz=(20.0,), cycles=2, together=False), MAX_RATE)
    by_axis = {b["axes"][0]: b for b in sweep.blocks}
    assert set(by_axis) == {"y", "z"} and [b["index"] for b in sweep.blocks] == [0, 1]
    y, z = by_axis["y"], by_axis["z"]
    assert np.all(sweep.u_v["z"][y["start"] : y["stop"]] == 0) and np.ptp(sweep.u_v["y"][y["start"] : y["stop"]]) > 119
    assert np.all(sweep.u_v["y"][z["start"] : z["stop"]] == 0) and np.ptp(sweep.u_v["z"][z["start"] : z["stop"]]) > 119
    together = build(SinePlan(axes=("y", "z"), frequencies_hz=(20.0,), cycles=2), MAX_RATE)
    np.testing.assert_array_equal(together.u_v["y"], together.u_v["z"])
    assert together.blocks[0]["axes"] == ["y", "z"] and sweep.samples == 2 * together.samples


def test_step_hold_reaches_and_holds_each_level():
    sweep = build(StepPlan(levels_v=(40.0, 120.0), hold_s=0.2, settle_s=0.05, sample_rate_hz=10_000), MAX_RATE)
    u = sweep.u_v["y"]
    assert [b["level_v"] for b in sweep.blocks] == [40.0, 120.0]
    for block in sweep.blocks:
        segment = u[block["start"] : block["stop"]]
        assert segment.max() == pytest.approx(block["level_v"])
        assert np.sum(segment == block["level_v"]) == 1 + 2000  # the ramp's last sample, then the hold
        assert block["frequency_hz"] is None and block["kind"] == "step"
    assert np.max(np.abs(np.diff(u))) * 10_000 <= 0.8 * MAX_RATE * 1.001


def test_chirp_and_multisine_are_periodic_and_bounded():
    chirp = build(ChirpPlan(f_start_hz=1, f_stop_hz=20, duration_s=1.0, sample_rate_hz=10_000), MAX_RATE)
    block = chirp.blocks[0]
    u = chirp.u_v["y"][block["start"] : block["stop"]]
    assert u.min() >= 0 and u.max() <= 120 and u.max() > 119 and abs(u[-1]) < 1.0  # ends near v_min
    multi = build(MultisinePlan(frequencies_hz=(2.0, 6.0, 10.0), cycles=3, sample_rate_hz=10_000), MAX_RATE)
    b = multi.blocks[0]
    segment = multi.u_v["y"][b["start"] : b["stop"]]
    period = 5000
    np.testing.assert_allclose(segment[:period], segment[period : 2 * period])
    assert segment.min() == pytest.approx(0.0) and segment.max() == pytest.approx(120.0)
    assert (b["frequency_hz"], b["cycles"]) == (2.0, 3)
    with pytest.raises(PlanError) as info:
        build(MultisinePlan(frequencies_hz=(2.0, 3.3)), MAX_RATE)
    assert info.value.field == "frequencies_hz"


def test_bad_plans_name_their_field():
    with pytest.raises(PlanError) as info:
        plan_from_dict({"waveform": "square"})
    assert info.value.field == "waveform"
    with pytest.raises(PlanError) as info:
        build(SinePlan(frequencies_hz=(0.0,)), MAX_RATE)
    assert info.value.field == "frequencies_hz"
    with pytest.raises(PlanError) as info:
        build(SinePlan(frequencies_hz=(0.01,), cycles=100), MAX_RATE)  # 10^4 s at 20 kHz
    assert info.value.field == "cycles"
    with pytest.raises(PlanError) as info:
        build(StepPlan(levels_v=(130.0,)), MAX_RATE)
    assert info.value.field == "levels_v"


def test_sample_rate_must_divide_the_timebase():
    assert check_sample_rate(20_000) == 20_000
    assert check_sample_rate(200) == 200
    with pytest.raises(PlanError, match="nearest rates are 29994 and 30003") as info:
        check_sample_rate(30_000)
    assert info.value.field == "sample_rate_hz"


def test_trimmed_blocks_of_a_partial_record():
    sweep = build(SinePlan(frequencies_hz=(10.0, 50.0, 100.0), cycles=4, sample_rate_hz=10_000), MAX_RATE)
    cut = sweep.blocks[1]["start"] + 500  # 2.5 cycles of 50 Hz
    blocks = trim_blocks(sweep.blocks, cut, 10_000)
    assert len(blocks) == 2 and blocks[0] == sweep.blocks[0]
    assert (blocks[1]["stop"], blocks[1]["cycles"], blocks[1]["complete"]) == (cut, 2, False)
    assert sweep.blocks[1]["cycles"] == 4  # the plan's table is untouched
