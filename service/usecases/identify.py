"""Identification jobs and comparisons: glue between stored datasets and the hysteresis models.

``check_identify_request`` refuses a bad request (naming the field) before any job is queued;
``identify`` is the job body; ``compare`` predicts a stored dataset with a stored model.
"""
from __future__ import annotations

import numpy as np

from service.science.data.datasets import stored_sample_rate_hz
from service.science.data.export import json_stride
from service.science.errors import FieldError
from service.runtime.jobs import JobContext, JobInterrupted
from service.store import NotFoundError, Store
from service.science.fitting.validation import evaluate_record, fit_on_training_rows, mean_of, split_blocks, training_mask
from service.science.fitting.validation import metrics as sample_metrics

from service.science.discovery.records import drive_derivatives  # noqa: F401  (re-exported)
from service.science.effects import EFFECT_NAMES

#: Effect names the identification accepts (DESIGN §5, plus the ``operators`` capacity candidate).
EFFECTS_AVAILABLE = EFFECT_NAMES


def model_registry() -> dict:
    from service.science.models import MODEL_REGISTRY

    return MODEL_REGISTRY


def check_identify_request(store: Store, axis: str, datasets: list[str], effects: list[str], model: str) -> None:
    """Raise FieldError naming the field at fault, or return if the identification can run."""
    registry = model_registry()
    if model not in registry and model != "composite":
        raise FieldError("model", f"unknown model {model!r}; use one of {', '.join(registry)}, composite")
    unknown = [e for e in effects if e not in EFFECTS_AVAILABLE]
    if unknown or "hysteresis" not in effects:
        raise FieldError("effects", f"{', '.join(map(repr, unknown)) or 'an empty list'} is not available: "
                         f"use {', '.join(map(repr, EFFECTS_AVAILABLE))}, and 'hysteresis' is required")
    if model not in ("static_pi", "composite") and len(set(effects)) > 1:
        raise FieldError("effects", f"effects beyond 'hysteresis' build a composite model on a static PI; "
                         f"model {model!r} takes effects ['hysteresis'] only")
    if not datasets:
        raise FieldError("datasets", "give at least one dataset id")
    training_samples = 0
    for dataset_id in datasets:
        try:
            row = store.get_dataset(dataset_id)
        except NotFoundError:
            raise FieldError("datasets", f"no dataset with id {dataset_id!r}") from None
        if axis not in row["axes"]:
            raise FieldError("datasets", f"dataset {dataset_id} has no {axis} axis (it has "
                             f"{', '.join(row['axes'])})")
        if not split_blocks(row["blocks"], row["samples"], row["sample_rate_hz"], axis):
            raise FieldError("datasets", f"dataset {dataset_id} has no block that drives axis {axis}")
        training_samples += int(_load(store, dataset_id, axis, row=row)[3].sum())  # FieldError if unusable
    if training_samples == 0:
        raise FieldError("datasets", "no training data: every block is too short to hold out its last "
                                     "cycle and keep one for the fit (sweep at least 2 cycles)")


def identify(ctx: JobContext, store: Store, axis: str, datasets: list[str], effects: list[str],
             model: str, n_operators: int, parent_id: str | None = None) -> dict:
    """Job body: fit on the training cycles of every dataset, validate on the held-out ones,
    store the model and return ``{"model_id", "train_rms_um", "validation_rms_um"}``."""
    if len(set(effects)) > 1 or model == "composite":
        from service.usecases.discover import identify_composite

        return identify_composite(ctx, store, axis, datasets, effects, n_operators, parent_id)
    ctx.progress(0.02, "loading datasets")
    loaded = [_load(store, dataset_id, axis) for dataset_id in datasets]
    ctx.progress(0.1, f"fitting {model} on {sum(int(m.sum()) for _, _, _, m in loaded)} training samples")
    fitted = fit_on_training_rows(model_registry()[model](n_operators=n_operators),
                                  [series for _, series, _, _ in loaded], [mask for _, _, _, mask in loaded])
    if ctx.cancelled:
        raise JobInterrupted("cancelled before the model was stored")
    ctx.progress(0.8, "validating on held-out cycles")
    per_dataset = []
    for dataset_id, series, splits, _ in loaded:
        figures = evaluate_record(series.x_um, fitted.predict(series), splits)
        per_dataset.append({"dataset_id": dataset_id, **figures})
    all_blocks = [b for d in per_dataset for b in d["blocks"]]
    metrics = {"train_rms_um": mean_of(all_blocks, "train"), "validation_rms_um": mean_of(all_blocks, "validation"),
               "train_max_abs_um": _max_of(all_blocks, "train"),
               "validation_max_abs_um": _max_of(all_blocks, "validation"), "per_dataset": per_dataset,
               "held_out": "last ceil(20 %) of the full cycles of every block (last 20 % of samples "
                           "where a block has no cycles); means are over blocks"}
    row = store.add_model({"axis": axis, "kind": model, "effects": effects, "parent_id": parent_id,
                           "datasets": datasets, "options": {"n_operators": n_operators},
                           "parameters": fitted.to_dict(), "metrics": metrics, "job_id": ctx.job_id})
    return {"model_id": row["id"], "train_rms_um": metrics["train_rms_um"],
            "validation_rms_um": metrics["validation_rms_um"]}


def load_model(row: dict):
    """The model object stored in a model record."""
    from service.science.models import model_from_dict

    if row["parameters"].get("model") == "composite":
        from service.science.discovery.composite import CompositeModel

        return CompositeModel.from_dict(row["parameters"])

    return model_from_dict(row["parameters"])


def compare(store: Store, model_id: str, dataset_id: str, max_points: int | None = None,
            arrays: bool = True) -> dict:
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
    _, series, splits, _ = _load(store, dataset_id, axis, row=row, field="dataset")
    if not splits:
        raise FieldError("dataset", f"dataset {dataset_id} has no block that drives axis {axis}")
    model = load_model(model_row)
    if model_row["parameters"].get("model") == "composite":
        from service.usecases.discover import load_records

        predicted = model.predict(load_records(store, [dataset_id], axis)[0])
    else:
        predicted = model.predict(series)
    used = dataset_id in model_row["datasets"]
    figures = evaluate_record(series.x_um, predicted, splits, trained=used)
    in_blocks = np.zeros(series.n_samples, dtype=bool)
    for s in splits:
        in_blocks[s.train[0]:s.held_out[1]] = True
    stride = json_stride(series.n_samples, max_points)
    signals = {} if not arrays else {
        "t_s": (np.arange(0, series.n_samples, stride) / row["sample_rate_hz"]).tolist(),
        "u_v": series.u_v[::stride].tolist(), "x_measured_um": series.x_um[::stride].tolist(),
        "x_predicted_um": predicted[::stride].tolist(),
        "residual_um": (series.x_um - predicted)[::stride].tolist()}
    return {
        "model_id": model_id, "dataset_id": dataset_id, "axis": axis, "used_in_fit": used,
        "sample_rate_hz": row["sample_rate_hz"], "samples": series.n_samples, "stride": stride, **signals,
        "metrics": {"overall": sample_metrics(series.x_um[in_blocks], predicted[in_blocks]),
                    "train_rms_um": figures["train_rms_um"], "validation_rms_um": figures["validation_rms_um"],
                    "per_block": figures["blocks"]},
    }


def _load(store: Store, dataset_id: str, axis: str, row: dict | None = None, field: str = "datasets"):
    """(id, Series of the whole record for ``axis``, block splits, training mask); a FieldError
    naming ``field`` if the record cannot be modelled."""
    from service.science.models import Series

    row = row or store.get_dataset(dataset_id)
    arrays = store.load_arrays(dataset_id)
    u, x, fs = arrays[f"u_{axis}_v"], arrays[f"x_{axis}_um"], stored_sample_rate_hz(row, field)
    splits = split_blocks(row["blocks"], len(u), fs, axis)
    du, ddu = drive_derivatives(u, fs, row["blocks"])
    try:
        series = Series(u, x, fs, du, ddu, label=dataset_id)
    except ValueError as exc:
        raise FieldError(field, f"dataset {dataset_id} cannot be modelled: {exc}") from None
    return dataset_id, series, splits, training_mask(splits, len(u))


def _max_of(per_block: list[dict], part: str) -> float | None:
    values = [b[part]["max_abs_um"] for b in per_block if b[part]["max_abs_um"] is not None]
    return float(max(values)) if values else None
