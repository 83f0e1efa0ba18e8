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

AXES = ("y", "z")


def benches(store: Store) -> dict:
    """``{"benches": [...], "offline_after_heartbeats", "this_bench_id"}``: each bench's row (no
    config snapshot) with ``online``, ``heartbeat_age_s``, ``datasets`` (how many it holds) and
    ``latest_models`` ``{axis: summary | None}``."""
    now = datetime.now(UTC)
    latest: dict[tuple[str, str], dict] = {(m["bench_id"], m["axis"]): m for m in latest_models(store.engine)}
    counts = dataset_counts(store.engine)
    out = []
    for row in store.benches.list():
        view = _bench_summary(row, now)
        view["datasets"] = counts.get(row["id"], 0)
        view["latest_models"] = {axis: _model_summary(store, latest.get((row["id"], axis))) for axis in AXES}
        out.append(view)
    return {"benches": out, "offline_after_heartbeats": OFFLINE_AFTER_HEARTBEATS, "this_bench_id": store.bench_id}


def compare(store: Store, axis: str) -> dict:
    """Per registered bench, its newest model of ``axis`` (None if it has none): the summary plus
    ``parameters`` ``{effect: {name_unit: value}}`` (service.science.discovery.parameters) and
    ``parameter_names``, the union over benches (``effect.name``), in a stable order."""
    now = datetime.now(UTC)
    latest = {m["bench_id"]: m for m in latest_models(store.engine, axis=axis, parameters=True)}
    rows, names = [], {}
    for row in store.benches.list():
        model = latest.get(row["id"])
        entry = {**_bench_summary(row, now), "model": None}
        if model is not None:
            entry["model"] = {**_model_summary(store, model), "parameters": discovered_parameters(model)}
            for effect, values in entry["model"]["parameters"].items():
                for name in values:
                    names.setdefault(f"{effect}.{name}", None)
        rows.append(entry)
    return {"axis": axis, "benches": rows, "parameter_names": list(names)}


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
    return {**{k: row[k] for k in keys}, "online": is_online(row, now), "heartbeat_age_s": round(age_s(row, now), 3)}


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
    }
