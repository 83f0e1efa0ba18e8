"""Held-out validation of hysteresis models: metrics over the train/held-out split of
service.science.data.holdout (whole held-out cycles), fits on the training rows only.

Metrics per sample set: ``rms_um``, ``max_abs_um`` and MATLAB-style
``fit_pct`` = 100·(1 − ‖e‖/‖x − mean(x)‖). Summary figures are the mean over blocks, so a short
100 Hz block counts as much as a long 1 Hz one. Pure numpy: no HTTP, no store.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from service.science.data.holdout import BlockSplit
from service.science.fitting.metrics import fit_metrics


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
