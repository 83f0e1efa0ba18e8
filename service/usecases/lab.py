"""The lab: every bench registered on the shared store with its state and latest model per axis,
and one axis's latest models compared across benches (effects, held-out RMS, noise floor, and the
physical parameters discovery fitted: resonance, creep, delay, drift, coupling). Reads the store
only: an offline bench's models are compared like any other."""

from __future__ import annotations

from datetime import UTC, datetime

from service.runtime.heartbeat import OFFLINE_AFTER_HEARTBEATS, age_s, is_online
from service.science.discovery.composite import as_composite
from service.science.discovery.parameters import physical_parameters
from service.store import IntegrityError, NotFoundError, Store, clean_json, json_sha256
from service.store.benches import dataset_counts, latest_models
from service.usecases.identify import load_model
from service.usecases.provenance import model_origin

AXES = ("y", "z")


def benches(store: Store) -> dict:
    """``{"benches": [...], "offline_after_heartbeats", "this_bench_id"}``: each bench's row (no
    config snapshot) with ``online``, ``heartbeat_age_s``, ``datasets`` (how many it recorded),
    ``imported_datasets`` (imports it stores: another stage recorded them) and
    ``latest_models`` ``{axis: summary | None}`` (fitted on its own data) and, apart,
    ``latest_imported_models`` ``{axis: summary | None}`` (fitted on data another stage recorded, with
    its ``origin``: the files it was imported from)."""
    now = datetime.now(UTC)
    latest = {(m["bench_id"], m["axis"], m["imported_data"]): m for m in latest_models(store.engine)}
    counts = dataset_counts(store.engine)
    out = []
    for row in store.benches.list():
        view = _bench_summary(row, now)
        count = counts.get(row["id"]) or {}
        view["datasets"], view["imported_datasets"] = count.get("recorded", 0), count.get("imported", 0)
        for field, imported in (("latest_models", False), ("latest_imported_models", True)):
            view[field] = {axis: _model_summary(store, latest.get((row["id"], axis, imported))) for axis in AXES}
        out.append(view)
    return {"benches": out, "offline_after_heartbeats": OFFLINE_AFTER_HEARTBEATS, "this_bench_id": store.bench_id}


def compare(store: Store, axis: str) -> dict:
    """Per registered bench, its newest model of ``axis`` fitted on its own data (None if it has none):
    the summary plus ``parameters`` ``{effect: {name_unit: value}}`` (service.science.discovery.parameters);
    ``imported``: per bench, its newest model fitted on imported data, with its ``origin`` (the stage
    it describes is another's, so it is not that bench's row); ``parameter_names``, the union over
    them all (``effect.name``), in a stable order."""
    now = datetime.now(UTC)
    latest = {(m["bench_id"], m["imported_data"]): m for m in latest_models(store.engine, axis=axis, parameters=True)}
    rows, imported, names = [], [], {}

    def compared(model: dict) -> dict:
        out = {**_model_summary(store, model), "parameters": discovered_parameters(model)}
        for effect, values in out["parameters"].items():
            for name in values:
                names.setdefault(f"{effect}.{name}", None)
        return out

    for row in store.benches.list():
        own, other = latest.get((row["id"], False)), latest.get((row["id"], True))
        rows.append({**_bench_summary(row, now), "model": compared(own) if own is not None else None})
        if other is not None:
            imported.append({"bench_id": row["id"], "model": compared(other)})
    return {"axis": axis, "benches": rows, "imported": imported, "parameter_names": list(names)}


def discovered_parameters(model_row: dict) -> dict[str, dict[str, float]]:
    """The physical parameters of a stored model (a composite's effects; a paper's PI has none)."""
    if json_sha256(model_row["parameters"]) != model_row["parameters_sha256"]:
        raise IntegrityError(f"model {model_row['id']}: parameters do not match their sha256")
    composite = as_composite(load_model(model_row))
    return clean_json(physical_parameters(composite)) if composite.is_fitted else {}


def noise_floor_um(store: Store, model_row: dict) -> float | None:
    """The model's noise floor (µm): from its metrics if they hold one, else from the discovery
    step that stored it (its job's result); None when neither knows it."""
    value = (model_row.get("metrics") or {}).get("noise_floor_um")
    if value is not None or not model_row.get("job_id"):
        return value
    try:
        job = store.get_job(model_row["job_id"])
    except NotFoundError:
        return None
    steps = (job.get("result") or {}).get("steps") or []
    return next((s.get("noise_floor_um") for s in steps if s.get("model_id") == model_row["id"]), None)


def _bench_summary(row: dict, now: datetime) -> dict:
    keys = (
        "id",
        "name",
        "bench",
        "url",
        "state",
        "running_job_id",
        "started_at",
        "heartbeat_at",
        "heartbeat_s",
        "software_version",
    )
    return {**{k: row[k] for k in keys}, "online": is_online(row, now), "heartbeat_age_s": age_s(row, now)}


def _model_summary(store: Store, model: dict | None) -> dict | None:
    if model is None:
        return None
    metrics = model.get("metrics") or {}
    return {
        "id": model["id"],
        "kind": model["kind"],
        "effects": model["effects"],
        "validation_rms_um": metrics.get("validation_rms_um"),
        "train_rms_um": metrics.get("train_rms_um"),
        "noise_floor_um": noise_floor_um(store, model),
        "created_at": model["created_at"],
        "origin": model_origin(store, model.get("datasets") or []),
        "made_by": _made_by(store, model.get("job_id")),
    }


def _made_by(store: Store, job_id: str | None) -> dict | None:
    """The job that stored a model: ``{"job_id", "kind", "state"}`` (a discover's step models are stored
    as it goes, so the newest may be from a run that was cancelled: the page says so), None if unknown."""
    if not job_id:
        return None
    try:
        job = store.get_job(job_id)
    except NotFoundError:
        return None
    return {"job_id": job_id, "kind": job["kind"], "state": job["state"]}
