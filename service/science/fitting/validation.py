"""Held-out validation of hysteresis models: train/held-out split by whole cycles, and metrics.

Split ("whole held-out cycles"): within each block of a record, the last ⌈20 %⌉ of its full
cycles (at least one) are held out and the earlier full cycles train; a block without cycles
(step, non-periodic import) holds out its last 20 % of samples. Samples outside every block
(ramps, settling) and a trailing part-cycle belong to neither set, though models still run
over them so that their operator state carries through the whole record.

Metrics per sample set: ``rms_um``, ``max_abs_um`` and MATLAB-style
``fit_pct`` = 100·(1 − ‖e‖/‖x − mean(x)‖). Summary figures are the mean over blocks, so a short
100 Hz block counts as much as a long 1 Hz one. Pure numpy: no HTTP, no store.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.science.fitting.metrics import fit_metrics

HELD_OUT_FRACTION = 0.2


@dataclass(frozen=True)
class BlockSplit:
    """One block's training and held-out sample ranges (start, stop), in record indices."""

    block: dict
    train: tuple[int, int]
    held_out: tuple[int, int]


def other_axes(block: dict, axis: str | None) -> list[str]:
    """The axes ``block`` drove when ``axis`` is not among them (``axis`` was at rest: its record shows
    cross-coupling there), else [] (a block of ``axis``, or one whose axes are not recorded)."""
    driven = block.get("axes") or []
    return list(driven) if axis and driven and axis not in driven else []


def axis_frequency_hz(block: dict, axis: str | None) -> float | None:
    """The frequency (Hz) at which ``block`` drove ``axis``: its own where the block drove the axes
    at different frequencies (``frequencies_hz``, an imported two-axis record), else the block's."""
    return (block.get("frequencies_hz") or {}).get(axis) or block.get("frequency_hz")


def split_blocks(
    blocks: Sequence[dict],
    samples: int,
    sample_rate_hz: float,
    axis: str | None = None,
    fraction: float = HELD_OUT_FRACTION,
) -> list[BlockSplit]:
    """Train/held-out ranges per block. Blocks that drive other axes only are skipped when
    ``axis`` is given; an empty block table means one block over the whole record. With
    ``fraction`` 0 nothing is held out: a block's whole cycles (or all its samples) train."""
    if not blocks:
        blocks = [{"index": 0, "start": 0, "stop": samples, "kind": "imported", "frequency_hz": None, "cycles": None}]
    out = []
    for block in blocks:
        if other_axes(block, axis):
            continue
        start, stop = int(block["start"]), min(int(block["stop"]), samples)
        if stop - start < 2:
            continue
        f_hz, cycles = block.get("frequency_hz"), block.get("cycles")
        if f_hz and cycles and cycles >= 1:
            period = sample_rate_hz / float(f_hz)
            full = min(int(cycles), int(math.floor((stop - start) / period + 1e-9)))
        else:
            full = 0
        if full >= 1:
            held = max(1, math.ceil(fraction * full - 1e-9)) if fraction > 0 else 0
            cut = start + int(round((full - held) * period))
            end = min(stop, start + int(round(full * period)))
            out.append(BlockSplit(block, (start, cut), (cut, end)))
        else:
            cut = stop - (max(1, math.ceil(fraction * (stop - start))) if fraction > 0 else 0)
            out.append(BlockSplit(block, (start, cut), (cut, stop)))
    return out


def training_mask(splits: Sequence[BlockSplit], samples: int) -> np.ndarray:
    """Boolean mask of the training rows of one record."""
    mask = np.zeros(samples, dtype=bool)
    for s in splits:
        mask[s.train[0] : s.train[1]] = True
    return mask


def metrics(x_um: np.ndarray, x_hat_um: np.ndarray) -> dict:
    """RMS and largest absolute error (µm) and fit % of a prediction (``fit_metrics`` of
    service.science.fitting); None figures for no samples, None fit % when x has no spread."""
    x = np.asarray(x_um, dtype=float)
    if x.size == 0:
        return {"samples": 0, "rms_um": None, "max_abs_um": None, "fit_pct": None}
    figures = fit_metrics(x, x_hat_um)
    fit = figures["fit_percent"]
    return {
        "samples": int(x.size),
        "rms_um": figures["rms_um"],
        "max_abs_um": figures["max_abs_um"],
        "fit_pct": fit if math.isfinite(fit) else None,
    }


def evaluate_record(x_um: np.ndarray, x_hat_um: np.ndarray, splits: Sequence[BlockSplit], trained: bool = True) -> dict:
    """Per-block train and held-out metrics of one record, plus their means.

    With ``trained`` False (a record the model never saw) every block row is unseen: the
    whole block is the validation set and there is no training set.
    """
    per_block = []
    for s in splits:
        if trained:
            train = metrics(x_um[slice(*s.train)], x_hat_um[slice(*s.train)])
            held = metrics(x_um[slice(*s.held_out)], x_hat_um[slice(*s.held_out)])
        else:
            rows = slice(s.train[0], s.held_out[1])
            train, held = metrics(x_um[:0], x_hat_um[:0]), metrics(x_um[rows], x_hat_um[rows])
        per_block.append(
            {
                "index": s.block.get("index"),
                "kind": s.block.get("kind"),
                "frequency_hz": s.block.get("frequency_hz"),
                "cycles": s.block.get("cycles"),
                "train": train,
                "validation": held,
            }
        )
    return {
        "train_rms_um": mean_of(per_block, "train"),
        "validation_rms_um": mean_of(per_block, "validation"),
        "blocks": per_block,
    }


def evaluate_records(records: Sequence, predictions: Sequence[np.ndarray], own_axis_only: bool = False) -> dict:
    """Per-record ``evaluate_record`` (labelled ``dataset_id``) over each record's block splits
    (``own_axis_only``: the blocks that drive its axis), and train/held-out means over all blocks."""
    per, blocks = [], []
    for r, x_hat in zip(records, predictions):
        fig = evaluate_record(r.x_um, x_hat, r.splits_of(own_axis_only))
        per.append({"dataset_id": r.label, **fig})
        blocks += fig["blocks"]
    return {
        "train_rms_um": mean_of(blocks, "train"),
        "validation_rms_um": mean_of(blocks, "validation"),
        "per_dataset": per,
    }


def max_of(per_block: Sequence[dict], part: str) -> float | None:
    """Largest absolute error (µm) over blocks of ``part`` (train or validation); None if none has it."""
    values = [b[part]["max_abs_um"] for b in per_block if b[part]["max_abs_um"] is not None]
    return float(max(values)) if values else None


def mean_of(per_block: Sequence[dict], part: str, key: str = "rms_um") -> float | None:
    """Mean over blocks of one figure (``part`` is train or validation); None if no block has it."""
    values = [b[part][key] for b in per_block if b[part][key] is not None]
    return float(np.mean(values)) if values else None


def fit_on_training_rows(model, series: Sequence, masks: Sequence[np.ndarray]):
    """Fit ``model`` to the training rows only and return it.

    The model predicts over the whole records (operator state carries through held-out cycles)
    while rows outside ``masks`` get zero weight in its least-squares fit.
    """
    weights = np.concatenate([np.asarray(m, dtype=bool) for m in masks]).astype(float)
    if not weights.any():
        raise ValueError("no training rows: every block is too short to hold out a cycle and keep one")
    return model.fit(list(series), row_weights=weights)


def trained_loops_v(records) -> list[list[float]]:
    """[min, max] V of the drive over each training stretch of the blocks that drive the records'
    own axis: the loops a model fitted on ``records`` has seen (stored with it at identification)."""
    loops = []
    for rec in records:
        for split in rec.splits_of(own_axis_only=True):
            u = rec.u_v[split.train[0] : split.train[1]]
            if u.size:
                loops.append([float(np.min(u)), float(np.max(u))])
    return loops
