"""Where a model's data came from: recorded by a bench of this service, or imported from a file
another stage recorded. A model fitted on imported data describes that other stage, whatever
bench stored it: its ``bench_id`` is where it was fitted, ``origin`` is what it describes."""

from __future__ import annotations

from service.store import NotFoundError, Store


def imported_datasets(store: Store, dataset_ids) -> list[str]:
    """The ids among ``dataset_ids`` that were imported (recorded elsewhere, not by this bench)."""
    return [d for d in dataset_ids if _dataset(store, d).get("source") == "import"]


def _dataset(store: Store, dataset_id: str) -> dict:
    try:
        return store.get_dataset(dataset_id)
    except NotFoundError:  # deleted since: its provenance is unknown, not "imported"
        return {}


def model_origin(store: Store, dataset_ids) -> dict:
    """``{"fitted_on": "this_bench" | "imported" | "mixed", "imported": [{"dataset_id", "name",
    "filename"}]}`` from the model's datasets (their ``source`` and import options)."""
    imported = []
    for d in dataset_ids:
        row = _dataset(store, d)
        if row.get("source") == "import":
            options = (row.get("plan") or {}).get("import") or {}
            imported.append({"dataset_id": d, "name": row.get("name"), "filename": options.get("filename")})
    fitted_on = "this_bench" if not imported else "imported" if len(imported) == len(dataset_ids) else "mixed"
    return {"fitted_on": fitted_on, "imported": imported}


def recorded_elsewhere(imported: list[str], then: str) -> str | None:
    """What to do about an experiment when ``imported`` datasets (ids) were recorded on another stage:
    "<ids> was/were imported: <then>" (None when nothing was imported)."""
    if not imported:
        return None
    return f"{', '.join(imported)} {'was' if len(imported) == 1 else 'were'} imported: {then}"


def imported_name(imported: dict) -> str:
    """An imported dataset of a model's origin by its name as stored now, the file it came from beside
    it where the name is another ('"stage B" from the file b.csv': the file had named it until a rename);
    the file alone where the name is still the file's. The dashboard's provenance.importedDataName."""
    name, filename = imported.get("name") or imported["dataset_id"], imported.get("filename")
    return f"“{name}” from the file {filename}" if filename and filename != name else name


def foreign_model_warning(axis: str, model_id: str, origin: dict) -> str | None:
    """The warning a trajectory run carries when ``axis``'s feedforward model was fitted on imported
    data (None otherwise)."""
    if origin["fitted_on"] == "this_bench":
        return None
    files = ", ".join(imported_name(i) for i in origin["imported"])
    return (
        f"{axis.upper()}: feedforward model {model_id} was fitted on imported data ({files}): the data was "
        "recorded on another stage, so its model may not describe this bench; identify one on this bench's sweeps"
    )
