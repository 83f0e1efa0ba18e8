"""Glue between the store and discovery: load records, identify composite models (a job body),
diagnose a stored model, refine it (add/remove/set effects) and walk its lineage."""
from __future__ import annotations

from service.science.data.datasets import stored_sample_rate_hz
from service.science.discovery.composite import CompositeModel, fit_composite, held_out_frequency_metrics
from service.science.discovery.diagnosis import diagnose
from service.science.discovery.records import Record, record_for_axis
from service.science.effects import EFFECTS, ordered
from service.science.errors import FieldError
from service.runtime.jobs import JobContext, JobInterrupted
from service.store import NotFoundError, Store
from service.science.fitting.validation import mean_of


def load_records(store: Store, dataset_ids: list[str], axis: str, field: str = "datasets") -> list[Record]:
    """One Record per dataset for ``axis`` (with the other axis's drive when recorded)."""
    out = []
    for dataset_id in dataset_ids:
        try:
            row = store.get_dataset(dataset_id)
        except NotFoundError:
            raise FieldError(field, f"no dataset with id {dataset_id!r}") from None
        if axis not in row["axes"]:
            raise FieldError(field, f"dataset {dataset_id} has no {axis} axis")
        fs_hz = stored_sample_rate_hz(row, field)
        arrays = store.load_arrays(dataset_id)
        out.append(record_for_axis(dataset_id, arrays, fs_hz, row["blocks"], axis))
    return out


def model_effects(row: dict) -> list[str]:
    """The effects of a stored model (without ``hysteresis``); a dynamic PI is hysteresis + rate dependence."""
    effects = [e for e in row["effects"] if e != "hysteresis"]
    if row["kind"] == "dynamic_pi" and "rate_dependence" not in effects:
        effects.append("rate_dependence")
    return ordered(effects)


def identify_composite(ctx: JobContext, store: Store, axis: str, datasets: list[str], effects: list[str],
                       n_operators: int, parent_id: str | None = None) -> dict:
    """Job body: fit hysteresis + effects on the training cycles, validate on the held-out ones, store."""
    ctx.progress(0.05, "loading datasets")
    records = load_records(store, datasets, axis)
    ctx.progress(0.15, f"fitting hysteresis + {', '.join(ordered(effects)) or 'nothing'}")
    warm = store.get_model(parent_id)["parameters"].get("theta") if parent_id else None
    model = fit_composite(records, effects, n_operators, warm)
    if ctx.cancelled:
        raise JobInterrupted("cancelled before the model was stored")
    ctx.progress(0.85, "validating on held-out cycles")
    ev = model.evaluate(records)
    ctx.progress(0.9, "validating on held-out frequencies")
    ev["held_out_frequencies"] = held_out_frequency_metrics(records, model.effects, n_operators, model.theta)
    blocks = [b for d in ev["per_dataset"] for b in d["blocks"]]
    metrics = {**ev, "train_max_abs_um": mean_of(blocks, "train", "max_abs_um"),
               "validation_max_abs_um": mean_of(blocks, "validation", "max_abs_um"),
               "held_out": "last ceil(20 %) of the full cycles of every block; means are over blocks. "
                           "held_out_frequencies: each frequency left out of the fit in turn"}
    row = store.add_model({"axis": axis, "kind": "composite", "effects": ["hysteresis"] + model.effects,
                           "parent_id": parent_id, "datasets": datasets, "options": {"n_operators": n_operators},
                           "parameters": model.to_dict(), "metrics": metrics, "job_id": ctx.job_id})
    return {"model_id": row["id"], "train_rms_um": ev["train_rms_um"], "validation_rms_um": ev["validation_rms_um"],
            "effects": ["hysteresis"] + model.effects}


def diagnose_model(store: Store, model_id: str, extra_datasets: list[str] | None = None) -> dict:
    """The diagnosis of a stored model on its datasets (plus ``extra_datasets``, refitted on all)."""
    row = store.get_model(model_id)
    datasets = list(row["datasets"]) + [d for d in (extra_datasets or []) if d not in row["datasets"]]
    records = load_records(store, datasets, row["axis"], field="extra_datasets")
    n_ops = int(row["options"].get("n_operators", 10))
    stored = None
    if row["parameters"].get("model") == "composite":  # the stored fit itself; refitted if data were added
        stored = CompositeModel.from_dict(row["parameters"])
        if len(datasets) > len(row["datasets"]):
            stored = fit_composite(records, stored.effects, n_ops, stored.theta)
    out = diagnose(records, model_effects(row), n_ops, model=stored)
    out.update({"model_id": model_id, "datasets": datasets, "axis": row["axis"]})
    if out.get("ambiguity"):
        out["ambiguity"]["then"] = (f"POST /api/sweeps with the experiment body, then GET /api/models/{model_id}"
                                    "/diagnosis?extra_datasets=<dataset_id> or refine with added datasets")
    out.pop("metrics", None)
    return out


def refined_effects(row: dict, add: str | None, remove: str | None, effects: list[str] | None) -> list[str]:
    """The effect list a refine request asks for; FieldError naming the field at fault."""
    current = model_effects(row)
    for fld, name in (("add", add), ("remove", remove)):
        if name is not None and name not in EFFECTS:
            raise FieldError(fld, f"unknown effect {name!r}; use one of {', '.join(EFFECTS)}")
    if sum(x is not None for x in (add, remove, effects)) != 1:
        raise FieldError("add", "give exactly one of add, remove or effects")
    if add is not None:
        if add in current:
            raise FieldError("add", f"model {row['id']} already has {add!r}")
        return ordered(current + [add])
    if remove is not None:
        if remove not in current:
            raise FieldError("remove", f"model {row['id']} has no {remove!r} (it has {', '.join(current) or 'none'})")
        return [e for e in current if e != remove]
    unknown = [e for e in effects if e != "hysteresis" and e not in EFFECTS]
    if unknown:
        raise FieldError("effects", f"unknown effects {unknown}; use {', '.join(EFFECTS)}")
    return ordered(e for e in effects if e != "hysteresis")


def history(store: Store, model_id: str) -> list[dict]:
    """The lineage root → ``model_id`` with train and validation RMS and the change at each step."""
    chain, seen = [], set()
    row = store.get_model(model_id)
    while row is not None and row["id"] not in seen:
        seen.add(row["id"])
        chain.append(row)
        row = store.get_model(row["parent_id"]) if row.get("parent_id") else None
    chain.reverse()
    out, prev = [], None
    for r in chain:
        effects = model_effects(r)
        change = None
        if prev is not None:
            added = [e for e in effects if e not in prev]
            removed = [e for e in prev if e not in effects]
            change = ", ".join([f"+{e}" for e in added] + [f"-{e}" for e in removed]) or "refit"
        out.append({"model_id": r["id"], "parent_id": r["parent_id"], "effects": ["hysteresis"] + effects,
                    "change": change, "datasets": list(r["datasets"]), "train_rms_um": r["metrics"].get("train_rms_um"),
                    "validation_rms_um": r["metrics"].get("validation_rms_um"), "created_at": r["created_at"]})
        prev = effects
    return out


def refine_params(store: Store, model_id: str, add: str | None, remove: str | None, effects: list[str] | None,
                  datasets: list[str]) -> dict:
    """The identification a refine request asks for: the stored model's axis, datasets (plus
    ``datasets``) and operators, with the effect set changed; ``parent_id`` is ``model_id``.
    FieldError names ``add``, ``remove``, ``effects`` or ``datasets`` at fault."""
    row = store.get_model(model_id)
    chosen = ["hysteresis"] + refined_effects(row, add, remove, effects)
    if datasets:
        load_records(store, datasets, row["axis"])  # FieldError naming datasets
    return {"axis": row["axis"], "datasets": list(row["datasets"]) + [d for d in datasets if d not in row["datasets"]],
            "effects": chosen, "model": "composite", "n_operators": int(row["options"].get("n_operators", 10)),
            "parent_id": model_id}
