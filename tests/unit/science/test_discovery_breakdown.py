"""Where a model fails, in words: a block that drove only the other axis is named as such, so a
user reading "worst: …" on Y's diagnosis is not sent to a Y sweep for what is Z's cross-coupling."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.record import Record
from service.science.discovery.breakdown import failures


def test_the_other_axiss_block_is_named_as_the_other_axiss():
    fs, f, n = 2000.0, 10.0, 1000  # two 5-cycle 10 Hz blocks, Y driven then Z
    t = np.arange(n) / fs
    sine = 60.0 * (1.0 - np.cos(2 * np.pi * f * t))
    u_y = np.concatenate([sine, np.zeros(n)])
    u_z = np.concatenate([np.zeros(n), sine])
    blocks = [
        {"index": 0, "start": 0, "stop": n, "kind": "sine", "cycles": 5, "frequency_hz": f, "axes": ["y"]},
        {"index": 1, "start": n, "stop": 2 * n, "kind": "sine", "cycles": 5, "frequency_hz": f, "axes": ["z"]},
    ]
    rec = Record(
        u_y,
        0.06 * u_y,
        fs,
        label="sweep y",
        blocks=blocks,
        axis="y",
        u_other_v=u_z,
        x_other_um=0.08 * u_z,
        hold_out=True,
    )
    residual = np.concatenate([np.full(n, 0.001), 0.02 * np.sin(2 * np.pi * f * t)])  # coupling from Z
    by_block = [p for p in failures([rec], [residual], top=20) if p["by"] == "frequency"]
    assert [p["block_index"] for p in by_block] == [1, 0]  # Z's block is the worst
    assert by_block[0]["where"] == "sweep y 10 Hz block that drives Z (Y undriven)"
    assert by_block[1]["where"] == "sweep y 10 Hz block"
    assert by_block[0]["rms_um"] > 10 * by_block[1]["rms_um"]


def test_a_block_title_names_the_axis_the_block_drove():
    """usecases.discover.block_title: Y's own block is "Y …", Z's block in Y's record is "Z …, Y undriven"."""
    from service.science.data.holdout import BlockSplit
    from service.usecases.discover import block_title

    block = {"index": 1, "start": 0, "stop": 1000, "kind": "sine", "cycles": 5, "frequency_hz": 5.0}
    split = BlockSplit({**block, "axes": ["z"]}, (0, 800), (800, 1000))
    assert block_title("y", split, 1000.0) == "Z 5 Hz sine, Y undriven (held-out cycle 5)"
    own = BlockSplit({**block, "axes": ["y"]}, (0, 800), (800, 1000))
    assert block_title("y", own, 1000.0) == "Y 5 Hz sine (held-out cycle 5)"


def test_the_mean_lag_lies_among_the_per_block_lags_printed_beside_it():
    """Two 100 Hz blocks (two datasets) and a 1 Hz block whose slope is too small for a lag to show:
    the printed 100 Hz figure is both blocks' weighted mean, not the last one's, and the overall lag is
    the mean of the printed figures only (the walk read '26 µs, slope-weighted mean' beside blocks
    that did not hold it)."""
    from service.science.discovery.breakdown import mean_lag_s, visible_lags

    lags = [(50.0, 30e-6, 10.0), (100.0, 90e-6, 40.0), (100.0, 70e-6, 40.0), (1.0, 5e-3, 0.01)]
    per = visible_lags(lags)
    assert set(per) == {50.0, 100.0}
    assert per[100.0][0] == pytest.approx(80e-6) and per[100.0][1] == pytest.approx(80.0)
    assert 30e-6 <= mean_lag_s(per) <= 80e-6
    assert mean_lag_s(per) == pytest.approx((10 * 30e-6 + 80 * 80e-6) / 90)
