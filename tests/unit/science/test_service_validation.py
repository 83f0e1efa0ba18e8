"""Held-out validation: whole-cycle splits, metrics, and fits that never see held-out rows."""

from __future__ import annotations

import numpy as np
import pytest

from service.science.data.holdout import split_blocks, training_mask
from service.science.data.record import Record
from service.science.fitting.validation import evaluate_record, fit_on_training_rows, metrics
from service.science.models import PAPER_MODELS


def _block(index, start, stop, f=None, cycles=None, axes=None):
    b = {
        "index": index,
        "start": start,
        "stop": stop,
        "kind": "sine" if f else "step",
        "frequency_hz": f,
        "cycles": cycles,
    }
    return {**b, "axes": axes} if axes else b


def test_last_fifth_of_whole_cycles_is_held_out():
    fs = 1000.0
    splits = split_blocks(
        [
            _block(0, 100, 600, f=10, cycles=5),
            _block(1, 700, 4700, f=10, cycles=40),
            _block(2, 5000, 6000),
            _block(3, 6000, 6300, f=10, cycles=3, axes=["z"]),
        ],
        7000,
        fs,
        "y",
    )
    assert [s.block["index"] for s in splits] == [0, 1, 2]  # block 3 drives z only
    assert (splits[0].train, splits[0].held_out) == ((100, 500), (500, 600))  # 1 of 5 cycles
    assert (splits[1].train, splits[1].held_out) == ((700, 3900), (3900, 4700))  # 8 of 40 cycles
    assert (splits[2].train, splits[2].held_out) == ((5000, 5800), (5800, 6000))  # no cycles: last 20 %
    mask = training_mask(splits, 7000)
    assert mask.sum() == 400 + 3200 + 800 and not mask[:100].any() and not mask[500:700].any()


def test_part_cycle_and_short_blocks():
    splits = split_blocks([_block(0, 0, 250, f=10, cycles=3)], 250, 1000.0)  # a cut block: 2.5 cycles
    assert (splits[0].train, splits[0].held_out) == ((0, 100), (100, 200))  # the half cycle is in neither
    assert split_blocks([], 50, 1000.0)[0].held_out == (40, 50)  # no table: the whole record


def test_metrics_follow_their_definitions():
    x = np.array([0.0, 1.0, 2.0, 3.0])
    m = metrics(x, x + np.array([0.1, -0.1, 0.1, -0.1]))
    assert m["rms_um"] == pytest.approx(0.1) and m["max_abs_um"] == pytest.approx(0.1)
    assert m["fit_pct"] == pytest.approx(100 * (1 - 0.2 / np.sqrt(5)))
    assert metrics(x, x)["fit_pct"] == 100.0
    assert metrics(np.ones(3), np.ones(3))["fit_pct"] is None  # no spread: fit % undefined
    assert metrics(x[:0], x[:0])["rms_um"] is None


def test_summary_is_the_mean_over_blocks_not_over_samples():
    x = np.zeros(1200)
    x_hat = np.zeros(1200)
    x_hat[800:1000] = 1.0  # held-out part of a long block: error 1
    x_hat[1160:1200] = 3.0  # held-out part of a short block (its last 40-sample cycle): error 3
    splits = split_blocks([_block(0, 0, 1000, f=5, cycles=5), _block(1, 1000, 1200, f=25, cycles=5)], 1200, 1000.0)
    result = evaluate_record(x, x_hat, splits)
    assert result["validation_rms_um"] == pytest.approx(2.0)  # (1 + 3) / 2, not sample-weighted
    assert result["train_rms_um"] == 0.0
    unseen = evaluate_record(x, x_hat, splits, trained=False)
    assert unseen["train_rms_um"] is None and unseen["blocks"][1]["validation"]["samples"] == 200


def _loops(fs=2000.0, f=5.0, cycles=10):
    t = np.arange(int(cycles * fs / f)) / fs
    u = 60 - 60 * np.cos(2 * np.pi * f * t)
    state, x = 0.0, np.empty_like(u)
    for k, v in enumerate(u):  # a backlash of half-width 8 V: not a PI model exactly
        state = min(max(state, v - 8), v + 8)
        x[k] = 0.05 * state + 0.0002 * v**1.5
    return u, x, fs, [_block(0, 0, len(u), f=f, cycles=cycles)]


@pytest.mark.parametrize("name", sorted(PAPER_MODELS))
def test_held_out_rows_do_not_influence_the_fit(name):
    u, x, fs, blocks = _loops()
    splits = split_blocks(blocks, len(u), fs)
    mask = training_mask(splits, len(u))
    spoiled = x.copy()
    spoiled[~mask] += 50.0  # garbage where the fit must not look
    clean = fit_on_training_rows(PAPER_MODELS[name](n_operators=6), [Record(u, x, fs)], [mask])
    dirty = fit_on_training_rows(PAPER_MODELS[name](n_operators=6), [Record(u, spoiled, fs)], [mask])
    np.testing.assert_allclose(dirty.predict(Record(u, x, fs)), clean.predict(Record(u, x, fs)), atol=1e-6)
    held = evaluate_record(x, clean.predict(Record(u, x, fs)), splits)
    assert held["validation_rms_um"] < 0.1  # and the model is a reasonable one


def _two_block_loops(fs=2000.0):
    """The backlash stage of ``_loops`` driven at 5 Hz then 25 Hz, 10 cycles each, one record."""
    u5, x5, _, _ = _loops(fs, 5.0)
    u25, x25, _, _ = _loops(fs, 25.0)
    blocks = [_block(0, 0, u5.size, f=5.0, cycles=10), _block(1, u5.size, u5.size + u25.size, f=25.0, cycles=10)]
    return Record(np.concatenate([u5, u25]), np.concatenate([x5, x25]), fs, blocks=blocks, hold_out=True)


@pytest.mark.parametrize("family", ["static_pi", "composite"])
def test_the_largest_error_is_the_largest_over_blocks_in_every_model_family(family):
    """``train_max_abs_um`` / ``validation_max_abs_um`` name one quantity in every family: the largest
    |error| over all blocks (the composite gave the mean of the blocks' maxima under the same name)."""
    from service.science.discovery.composite import CompositeModel

    record = _two_block_loops()
    model = PAPER_MODELS["static_pi"](n_operators=6) if family == "static_pi" else CompositeModel([], n_operators=6)
    model.fit([record])
    figures = model.validate([record])
    blocks = [b for d in figures["per_dataset"] for b in d["blocks"]]
    maxima = {part: [b[part]["max_abs_um"] for b in blocks] for part in ("train", "validation")}
    assert len(blocks) == 2 and maxima["validation"][0] != pytest.approx(maxima["validation"][1], rel=1e-3)
    assert figures["train_max_abs_um"] == max(maxima["train"])
    assert figures["validation_max_abs_um"] == max(maxima["validation"])
