"""Identification jobs and comparisons: glue between stored datasets and the models.

``load_records`` is the one dataset loader (a FieldError naming the field when a dataset cannot be
modelled); ``check_identify_request`` refuses a bad request (naming the field) before any job is
queued; ``identify`` is the job body for every model kind (service.science.discovery.registry);
``compare`` predicts a stored dataset with a stored model. No branch on the model kind: the
models' contract (service.science.models.contract) does the rest.
"""

from __future__ import annotations

import numpy as np

from drivers.interfaces import AxisLimits
from service.runtime.jobs import JobContext, JobInterrupted
from service.science.data.datasets import stored_sample_rate_hz
from service.science.data.export import json_stride
from service.science.data.holdout import split_blocks
from service.science.data.record import Record
from service.science.discovery.column_memo import shared_effect_columns
from service.science.discovery.noise import noise_floor
from service.science.discovery.records import record_for_axis
from service.science.discovery.registry import MODELS, model_for, model_from_dict
from service.science.discovery.rests import LineFree
from service.science.effects import effect_names, ordered
from service.science.errors import FieldError
from service.science.fitting.memory import memory_shortfall
from service.science.fitting.validation import evaluate_record, trained_loops_v
from service.science.fitting.validation import metrics as sample_metrics
from service.science.interrupt import Interrupted, interruptible
from service.store import NotFoundError, Store


def load_record(store: Store, dataset_id: str, axis: str, field: str = "datasets", row: dict | None = None) -> Record:
    """The held-out Record of ``axis`` of a stored dataset (its block table, the other axis's drive
    and displacement when recorded); FieldError naming ``field`` if it is missing or cannot be modelled."""
    try:
        row = row or store.get_dataset(dataset_id)
    except NotFoundError:
        raise FieldError(field, f"no dataset with id {dataset_id!r}") from None
    if axis not in row["axes"]:
        raise FieldError(field, f"dataset {dataset_id} has no {axis} axis (it has {', '.join(row['axes'])})")
    sample_rate_hz = stored_sample_rate_hz(row, field)
    try:
        arrays = store.load_arrays(dataset_id)
        return record_for_axis(dataset_id, arrays, sample_rate_hz, row["blocks"], axis, rated_rate_v_per_s(row, axis))
    except ValueError as exc:
        raise FieldError(field, f"dataset {dataset_id} cannot be modelled: {exc}") from None


def rated_rate_v_per_s(row: dict, axis: str) -> float | None:
    """The fastest the amplifier that recorded dataset ``row`` was rated to move ``axis``'s stack (V/s),
    from the bench configuration stored with it; None for an import (its stage's amplifier is unknown)."""
    limits = ((row.get("config") or {}).get("limits") or {}).get(axis)
    try:
        return None if not limits else AxisLimits(**limits).max_rate_v_per_s
    except (TypeError, ZeroDivisionError):  # a dataset stored before the limits had these fields
        return None


def load_records(store: Store, dataset_ids: list[str], axis: str, field: str = "datasets") -> list[Record]:
    """One Record per dataset for ``axis`` (``load_record``)."""
    return [load_record(store, dataset_id, axis, field) for dataset_id in dataset_ids]


def require_fit_memory(store: Store, dataset_ids: list[str], field: str = "datasets") -> None:
    """FieldError naming ``field`` if fitting or diagnosing on these datasets (every sample of each)
    would need more memory than this machine has free (service.science.fitting.memory); unknown ids
    are left to the loader's own error."""
    samples = 0
    for dataset_id in dataset_ids:
        try:
            samples += int(store.get_dataset(dataset_id)["samples"])
        except NotFoundError:
            continue
    shortfall = memory_shortfall(samples)
    if shortfall is not None:
        raise FieldError(field, f"dataset{'s' if len(dataset_ids) > 1 else ''} {', '.join(dataset_ids)}: {shortfall}")


def load_model(row: dict):
    """The model object stored in a model record; FieldError naming ``model`` (422) when it uses an
    effect this service has not loaded (a plug-in it was fitted with, started without): the stored
    model is kept, and serves again once the plug-in is loaded."""
    missing = [e for e in row.get("effects") or () if e not in effect_names()]
    if missing:
        raise FieldError(
            "model",
            f"model {row.get('id', '')} uses effects this service has not loaded: {', '.join(missing)} "
            "(plug-ins: start the service with their --effects-dir or entry point; GET /api/effects lists "
            "what is loaded)",
        )
    return model_from_dict(row["parameters"])


def compare(store: Store, model_id: str, dataset_id: str, max_points: int | None = None, arrays: bool = True) -> dict:
    """Measured, predicted and residual displacement (µm) of a stored dataset, with metrics.

    Blocks of a dataset the model was fitted on report train and held-out figures; for any
    other dataset the whole of every block is unseen data. The returned arrays are every
    ``stride``-th sample, at most ``max_points`` (default JSON_DEFAULT_MAX_POINTS, as a dataset's
    JSON download) per array; the metrics use every sample. ``arrays`` False leaves them out.
    """
    model_row = store.get_model(model_id)
    axis = model_row["axis"]
    row = store.get_dataset(dataset_id)
    if axis not in row["axes"]:
        raise FieldError("dataset", f"dataset {dataset_id} has no {axis} axis, which model {model_id} describes")
    record = load_record(store, dataset_id, axis, field="dataset", row=row)
    splits = record.splits_of(own_axis_only=True)
    if not splits:
        raise FieldError("dataset", f"dataset {dataset_id} has no block that drives axis {axis}")
    predicted = load_model(model_row).predict(record)
    used = dataset_id in model_row["datasets"]
    figures = evaluate_record(record.x_um, predicted, splits, trained=used)
    in_blocks = np.zeros(record.n_samples, dtype=bool)
    for s in splits:
        in_blocks[s.train[0] : s.held_out[1]] = True
    stride = json_stride(record.n_samples, max_points)
    signals = (
        {}
        if not arrays
        else {
            "t_s": (np.arange(0, record.n_samples, stride) / row["sample_rate_hz"]).tolist(),
            "u_v": record.u_v[::stride].tolist(),
            "x_measured_um": record.x_um[::stride].tolist(),
            "x_predicted_um": predicted[::stride].tolist(),
            "residual_um": (record.x_um - predicted)[::stride].tolist(),
        }
    )
    return {
        "model_id": model_id,
        "dataset_id": dataset_id,
        "axis": axis,
        "used_in_fit": used,
        "sample_rate_hz": row["sample_rate_hz"],
        "samples": record.n_samples,
        "stride": stride,
        **signals,
        "metrics": {
            "overall": _overall(record, predicted, in_blocks, row["sample_rate_hz"]),
            "train_rms_um": figures["train_rms_um"],
            "validation_rms_um": figures["validation_rms_um"],
            "per_block": figures["blocks"],
        },
    }


def _overall(record: Record, predicted: np.ndarray, in_blocks: np.ndarray, sample_rate_hz: float) -> dict:
    """The figures over every sample inside a block, and where the largest |error| falls
    (``max_abs_at_s``, s from the record's start): a start transient's maximum reads as one."""
    figures = sample_metrics(record.x_um[in_blocks], predicted[in_blocks])
    inside = np.flatnonzero(in_blocks)
    if inside.size:
        worst = inside[np.argmax(np.abs(record.x_um[inside] - predicted[inside]))]
        figures["max_abs_at_s"] = float(worst / sample_rate_hz)
    return figures


def check_identify_request(store: Store, axis: str, datasets: list[str], effects: list[str], model: str) -> None:
    """Raise FieldError naming the field at fault, or return if the identification can run."""
    if model not in MODELS:
        raise FieldError("model", f"unknown model {model!r}; use one of {', '.join(MODELS)}")
    available = effect_names()  # the built-ins and the loaded plug-ins
    unknown = [e for e in effects if e not in available]
    if unknown or "hysteresis" not in effects:
        raise FieldError(
            "effects",
            f"{', '.join(map(repr, unknown)) or 'an empty list'} is not available: "
            f"use {', '.join(map(repr, available))}, and 'hysteresis' is required",
        )
    try:
        model_for(model, effects)
    except ValueError as exc:
        raise FieldError("effects", str(exc)) from None
    if not datasets:
        raise FieldError("datasets", "give at least one dataset id")
    require_fit_memory(store, datasets)
    training_samples = 0
    for dataset_id in datasets:
        try:
            row = store.get_dataset(dataset_id)
        except NotFoundError:
            raise FieldError("datasets", f"no dataset with id {dataset_id!r}") from None
        if axis in row["axes"] and not split_blocks(row["blocks"], row["samples"], row["sample_rate_hz"], axis):
            raise FieldError("datasets", f"dataset {dataset_id} has no block that drives axis {axis}")
        record = load_record(store, dataset_id, axis, row=row)  # FieldError if unusable
        training_samples += int(record.training_mask(own_axis_only=True).sum())
    if training_samples == 0:
        raise FieldError(
            "datasets",
            "no training data: every block is too short to hold out its last "
            "cycle and keep one for the fit (sweep at least 2 cycles)",
        )


def identify(
    ctx: JobContext,
    store: Store,
    axis: str,
    datasets: list[str],
    effects: list[str],
    model: str,
    n_operators: int,
    parent_id: str | None = None,
    name: str | None = None,
) -> dict:
    """Job body: build the model the request names (``parent_id``: the stored model it refines), fit
    it on the training cycles of every dataset, validate on the held-out ones, store it (labelled
    ``name``, if given) and return
    ``{"model_id", "train_rms_um", "validation_rms_um", "effects"}``."""
    ctx.progress(0.02, "loading datasets")
    records = load_records(store, datasets, axis)
    parent = load_model(store.get_model(parent_id)) if parent_id else None
    estimator = model_for(model, effects, n_operators, parent)
    effects = ["hysteresis"] + ordered(effects)
    ctx.progress(
        0.1,
        f"fitting {estimator.name} ({' + '.join(effects)}) on "
        f"{sum(int(r.training_mask(own_axis_only=True).sum()) for r in records)} training samples",
    )
    with shared_effect_columns():  # the fit, and validation's refits and predictions, share columns
        try:
            with interruptible(lambda: ctx.cancelled):  # a cancel lands at the fit's next solve
                estimator.fit(records)
        except Interrupted:
            raise JobInterrupted("cancelled while fitting: nothing stored", cancelled=True) from None
        if ctx.cancelled:
            raise JobInterrupted("cancelled before the model was stored")
        ctx.progress(0.8, "validating on held-out cycles")
        row = store_model(
            store,
            estimator,
            records,
            axis,
            datasets,
            effects,
            n_operators,
            parent_id,
            ctx.job_id,
            {"name": name} if name else None,
        )
    metrics = row["metrics"]
    return {
        "model_id": row["id"],
        "train_rms_um": metrics["train_rms_um"],
        "validation_rms_um": metrics["validation_rms_um"],
        "effects": effects,
    }


def without_lines_metrics(estimator, line_free: LineFree) -> dict:
    """The model's train and held-out RMS (µm) on its records with the lines seen at rest taken out,
    the figures its diagnosis and a discover step give, and those lines' frequencies (Hz)."""
    figures = estimator.evaluate(line_free.records)
    return {
        "train_rms_um": figures["train_rms_um"],
        "validation_rms_um": figures["validation_rms_um"],
        "lines_hz": [line["frequency_hz"] for line in line_free.rests["lines"]],
    }


def store_model(
    store: Store,
    estimator,
    records: list[Record],
    axis: str,
    datasets: list[str],
    effects: list[str],
    n_operators: int,
    parent_id: str | None,
    job_id: str | None,
    labels: dict | None = None,
    line_free: LineFree | None = None,
) -> dict:
    """Validate a fitted model on the held-out cycles of ``records`` (train/held-out RMS in µm) and
    store it (``parent_id``: the model it refines; ``labels``: more fields of the row, such as its
    bench and tags; ``line_free``: what ``records``' rests showed, where the caller has read them
    already, as the discover loop has); the stored row."""
    metrics = estimator.validate(records)
    # the data's own noise floor (µm RMS), so that a lab comparing models across benches sees how far each
    # is from what its data allow: by the diagnosis's rule (what the gauge shows at rest less the lines
    # seen there, else the residual's cycle-to-cycle differences), so a model's page and its diagnosis
    # print one floor (a walk read 3.05 nm here against 3.153 nm at rest in the diagnosis)
    residuals = [r.x_um - estimator.predict(r) for r in records]
    line_free = line_free if line_free is not None else LineFree.of(records)
    metrics["noise_floor_um"] = noise_floor(records, residuals, line_free.rests)["noise_floor_um"]
    if line_free.had_lines:  # the held-out figures the diagnosis and discover judge: the lines out
        metrics["without_lines"] = without_lines_metrics(estimator, line_free)
    # the loops it was trained on: a trajectory checks its own against them without reading the data
    metrics["trained_loops_v"] = trained_loops_v(records)
    return store.add_model(
        {
            **(labels or {}),
            "axis": axis,
            "kind": estimator.name,
            "effects": effects,
            "parent_id": parent_id,
            "datasets": datasets,
            "options": {"n_operators": n_operators},
            "parameters": estimator.to_dict(),
            "metrics": metrics,
            "job_id": job_id,
        }
    )
