"""Glue between the store and discovery: diagnose a stored model, refine it (add/remove/set effects)
and walk its lineage. Records are loaded and models identified by service.usecases.identify."""

from __future__ import annotations

from service.science.data.holdout import BlockSplit, other_axes
from service.science.discovery.composite import as_composite, fit_composite
from service.science.discovery.diagnosis import diagnose
from service.science.discovery.like_for_like import effects_key, like_for_like
from service.science.discovery.rests import LineFree
from service.science.effects import EFFECTS, ordered
from service.science.errors import FieldError
from service.store import Store
from service.usecases.discover_experiments import BenchFit, fit_experiments
from service.usecases.identify import load_model, load_records, require_fit_memory
from service.usecases.provenance import imported_datasets, recorded_elsewhere


def model_effects(row: dict) -> list[str]:
    """The effects of a stored model beyond hysteresis, as discovery sees it (the composite it
    starts from: a dynamic PI is hysteresis + rate dependence)."""
    return as_composite(load_model(row)).effects


def block_title(axis: str, split: BlockSplit, sample_rate_hz: float) -> str:
    """A block named by what it is: ``Y 100 Hz sine (held-out cycles 5–5)``, ``Y step (held-out
    last 0.80 s)``; a block that drove only the other axis is named by that axis: ``Z 100 Hz sine, Y
    undriven (held-out cycle 5)``."""
    b = split.block
    kind = b.get("kind") or "block"
    f_hz = b.get("frequency_hz")
    if f_hz:
        period = sample_rate_hz / float(f_hz)
        first = round((split.held_out[0] - split.train[0]) / period) + 1
        last = round((split.held_out[1] - split.train[0]) / period)
        what = f"{f_hz:g} Hz {kind}"
        held = f"held-out cycles {first}–{last}" if last > first else f"held-out cycle {last}"
    else:
        what = kind
        held = f"held-out last {(split.held_out[1] - split.held_out[0]) / sample_rate_hz:.3g} s"
    if together := b.get("frequencies_hz"):  # the axes driven at once, each at its own frequency
        repeats = f", repeating at {f_hz:g} Hz" if f_hz else ", not repeating together"
        own_first = sorted(together.items(), key=lambda item: item[0] != axis)
        return (
            f"{' + '.join(f'{a.upper()} {f:g} Hz' for a, f in own_first)} {kind}{repeats} "
            f"({held.replace('cycle', 'common cycle')})"
        )
    if others := other_axes(b, axis):  # a block of the other axis (cross-coupling shows there)
        return f"{'/'.join(a.upper() for a in others)} {what}, {axis.upper()} undriven ({held})"
    return f"{axis.upper()} {what} ({held})"


def name_failing_blocks(failures: list[dict], records) -> None:
    """Each failure that is a block gains ``block``: the block named by what it is (block_title)."""
    by_label = {r.label: r for r in records}
    for f in failures:
        rec = by_label.get(f.get("record")) if f.get("by") == "frequency" else None
        split = next((s for s in rec.splits if s.block.get("index") == f.get("block_index")), None) if rec else None
        if split is not None:
            f["block"] = block_title(rec.axis or "y", split, rec.sample_rate_hz)


def diagnose_model(
    store: Store,
    model_id: str,
    extra_datasets: list[str] | None = None,
    records=None,
    bench_fit: BenchFit | None = None,
) -> dict:
    """The diagnosis of a stored model on its datasets (plus ``extra_datasets``, refitted on all);
    ``records``: those datasets' records when the caller has loaded them already; ``bench_fit``: the
    bench's check and cut of a sweep (service.usecases.acquire.BenchExperiments), so that every
    experiment proposed for data of this bench is one the bench runs (``fit_experiments``)."""
    row = store.get_model(model_id)
    datasets = list(row["datasets"]) + [d for d in (extra_datasets or []) if d not in row["datasets"]]
    if records is None:
        require_fit_memory(store, datasets, field="extra_datasets" if extra_datasets else "model_id")
        records = load_records(store, datasets, row["axis"], field="extra_datasets")
    n_ops = int(row["options"].get("n_operators", 10))
    basis = as_composite(load_model(row))  # a stored composite fit, or the one a paper's model stands for
    stands_in = not basis.is_fitted
    if not basis.is_fitted or len(datasets) > len(row["datasets"]):  # (re)fitted, warm at its transforms
        basis = fit_composite(records, basis.effects, n_ops, basis.theta)
    out = diagnose(records, basis.effects, n_ops, model=basis)
    name_failing_blocks(out["failures"], records)
    if stands_in:  # a paper's model: say which model the figures are of, beside the stored one's own
        out["diagnosed_as"] = (
            f"the composite {' + '.join(out['effects'])} fitted on the same data, standing for this "
            f"{row['kind']} (held-out {out['residual_rms_um'] * 1e3:.4g} nm; the {row['kind']}'s own "
            f"{(row.get('metrics') or {}).get('validation_rms_um', float('nan')) * 1e3:.4g} nm): its play "
            "operators are fitted jointly with the effects, so a refine or a discover step starts from it"
        )
    imported = imported_datasets(store, datasets)
    out.update(
        {
            "model_id": model_id,
            "datasets": datasets,
            "axis": row["axis"],
            "experiments_run_here": not imported,
            "experiments_note": recorded_elsewhere(
                imported,
                "recorded on another stage, whose experiments this bench cannot run (a different stack behind a "
                "different amplifier). Run the experiment on that stage, over the range it names, and import the result",
            ),
        }
    )
    if bench_fit is not None and not imported:
        fit_experiments(out, bench_fit, records)
    if out.get("ambiguity"):
        out["ambiguity"]["then"] = (
            f"POST /api/sweeps with the experiment body, then GET /api/models/{model_id}"
            "/diagnosis?extra_datasets=<dataset_id> or refine with added datasets"
            if not imported
            else "record the experiment on the stage that recorded the data, import it (POST /api/datasets), then "
            f"GET /api/models/{model_id}/diagnosis?extra_datasets=<dataset_id> or refine with added datasets"
        )
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
    """The lineage root → ``model_id`` with train and validation RMS and the change at each step
    (``step``: 0 is the lineage's first model, as a discover run's step 0 is the model it starts from):
    effects added (+e) or removed (−e), datasets added (+data ds_…: its RMS is over other data, not
    comparable with the step before), else "refit"; and each step like for like (``like_for_like``)."""
    chain, seen = [], set()
    row = store.get_model(model_id)
    while row is not None and row["id"] not in seen:
        seen.add(row["id"])
        chain.append(row)
        row = store.get_model(row["parent_id"]) if row.get("parent_id") else None
    chain.reverse()
    out, prev, prev_data = [], None, []
    for r in chain:
        effects = model_effects(r)
        change = None
        if prev is not None:
            added = [e for e in effects if e not in prev]
            removed = [e for e in prev if e not in effects]
            data = [d for d in r["datasets"] if d not in prev_data]
            change = (
                ", ".join([f"+{e}" for e in added] + [f"-{e}" for e in removed] + [f"+data {d}" for d in data])
                + (" (held-out RMS over more data)" if data else "")
            ) or "refit"
        out.append(
            {
                "step": len(out),
                "model_id": r["id"],
                "parent_id": r["parent_id"],
                "effects": ["hysteresis"] + effects,
                "change": change,
                "datasets": list(r["datasets"]),
                "train_rms_um": r["metrics"].get("train_rms_um"),
                "validation_rms_um": r["metrics"].get("validation_rms_um"),
                "created_at": r["created_at"],
            }
        )
        prev, prev_data = effects, list(r["datasets"])
    like_for_like_history(store, chain, out)
    return out


def like_for_like_history(store: Store, chain: list[dict], steps: list[dict]) -> None:
    """Each of ``steps`` (the lineage ``chain``'s) gains ``like_for_like_rms_um``, its effects scored
    on the last model's datasets (refitted there, transforms kept, where it was fitted on fewer), and
    ``original_data_rms_um``, on the first model's. A lineage on one set of data needs no fit: both
    are its held-out RMS."""
    final, first = list(chain[-1]["datasets"]), list(chain[0]["datasets"])
    if all(list(r["datasets"]) == final for r in chain):
        for step in steps:
            step["like_for_like_rms_um"] = step["original_data_rms_um"] = step["validation_rms_um"]
        return
    ordered_ids = [d for d in first if d in final] + [d for d in final if d not in first]
    require_fit_memory(store, ordered_ids, field="model_id")
    records = load_records(store, ordered_ids, chain[-1]["axis"])
    models = [as_composite(load_model(r)) for r in chain]
    fitted = {
        effects_key(m.effects): m
        for r, m in zip(chain, models)
        if m.is_fitted and sorted(r["datasets"]) == sorted(final)
    }
    n_first = len([d for d in first if d in final]) if set(first) <= set(final) else 0
    figures = like_for_like(
        LineFree.of(records),
        n_first,
        [(m.effects, m.theta) for m in models],
        int(chain[-1]["options"].get("n_operators", 10)),
        fitted,
    )
    for step, f in zip(steps, figures):
        step.update(f if n_first else {**f, "original_data_rms_um": None})


def refine_params(
    store: Store, model_id: str, add: str | None, remove: str | None, effects: list[str] | None, datasets: list[str]
) -> dict:
    """The identification a refine request asks for: the stored model's axis, datasets (plus
    ``datasets``) and operators, with the effect set changed; ``parent_id`` is ``model_id``.
    FieldError names ``add``, ``remove``, ``effects`` or ``datasets`` at fault."""
    row = store.get_model(model_id)
    chosen = ["hysteresis"] + refined_effects(row, add, remove, effects)
    require_fit_memory(
        store,
        list(row["datasets"]) + [d for d in datasets or [] if d not in row["datasets"]],
        field="datasets" if datasets else "model_id",
    )  # before any array is read
    if datasets:
        load_records(store, datasets, row["axis"])  # FieldError naming datasets
    return {
        "axis": row["axis"],
        "datasets": list(row["datasets"]) + [d for d in datasets if d not in row["datasets"]],
        "effects": chosen,
        "model": "composite",
        "n_operators": int(row["options"].get("n_operators", 10)),
        "parent_id": model_id,
    }
