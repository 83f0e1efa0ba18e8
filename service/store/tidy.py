"""Keeping the store tidy: labels (name, tags, notes) of datasets and models, and deletion.

A record others derive from is not deleted unless asked to ``cascade``: a dataset that models were
fitted on, a model that others were refined from (its children). With ``cascade`` the records that
derive from it go too: every model fitted on the dataset and every descendant of a deleted model,
so no row is left naming one that is gone (``evcbench store check`` stays clean). The rows go in
one transaction; then the arrays' files (or objects of the shared location, which is asked first:
if it cannot be reached nothing is deleted). A job whose result names a deleted dataset keeps the id as
``deleted_dataset_id`` (its ``dataset_id`` becomes null, as the check expects), and quarantine
entries of deleted records are lifted.
"""

from __future__ import annotations

from sqlalchemy import delete, select, update

from service.store import placement, tables

#: the labels a user may change, and their defaults as shown for rows written before they existed
LABELS = ("name", "tags", "notes")


class InUseError(Exception):
    """Deleting ``record_id`` (a dataset or model, ``field``) was refused: ``dependents`` (``{"models":
    [ids]}``) derive from it; ``cascade`` would delete them too."""

    def __init__(self, field: str, record_id: str, dependents: dict[str, list[str]], why: str):
        names = ", ".join(i for ids in dependents.values() for i in ids)
        super().__init__(
            f"{field} {record_id} is in use: {why} {names}; nothing was deleted "
            "(ask with cascade=true to delete them as well)"
        )
        self.field, self.record_id, self.dependents = field, record_id, dependents

    def __str__(self) -> str:
        return self.args[0]


def with_labels(row: dict | None) -> dict | None:
    """A dataset or model row with its labels as the API shows them (tags a list, never null)."""
    if row is not None and "tags" in row:
        row["tags"] = list(row["tags"] or [])
    return row


def set_labels(store, table, record_id: str, labels: dict) -> None:
    """Write the labels given (keys of LABELS); NotFoundError if there is no such record."""
    field = "dataset" if table is tables.datasets else "model"
    store._get(table, record_id, field)
    values = {k: v for k, v in labels.items() if k in LABELS}
    if values:
        with store.engine.begin() as conn:
            conn.execute(update(table).where(table.c.id == record_id).values(**values))


def models_using(models: list[dict], dataset_id: str) -> list[str]:
    """Ids of the models fitted on ``dataset_id``."""
    return [m["id"] for m in models if dataset_id in (m["datasets"] or [])]


def descendants(models: list[dict], model_ids: list[str]) -> list[str]:
    """``model_ids`` and every model refined from them (children, their children, …), parents first."""
    children: dict[str, list[str]] = {}
    for m in models:
        if m["parent_id"]:
            children.setdefault(m["parent_id"], []).append(m["id"])
    out, queue = [], list(model_ids)
    while queue:
        current = queue.pop(0)
        if current not in out:
            out.append(current)
            queue += children.get(current, [])
    return out


def delete_dataset(store, dataset_id: str, cascade: bool = False) -> dict:
    """Delete a dataset, its arrays and (``cascade``) the models fitted on it and their descendants;
    InUseError naming the models if any use it and not ``cascade``. Returns ``{"datasets", "models",
    "freed_bytes"}`` (what was deleted)."""
    row = store.get_dataset(dataset_id)
    models = store.list_models()
    using = models_using(models, dataset_id)
    if using and not cascade:
        raise InUseError("dataset", dataset_id, {"models": using}, "models were fitted on it:")
    model_ids = descendants(models, using)
    freed = placement.size(store, row)  # asks a shared location first: unreachable, nothing is deleted
    with store.engine.begin() as conn:
        _delete_rows(conn, model_ids, [dataset_id])
    placement.remove(store, row)
    return {"datasets": [dataset_id], "models": model_ids, "freed_bytes": freed}


def delete_model(store, model_id: str, cascade: bool = False) -> dict:
    """Delete a model and (``cascade``) its descendants; InUseError naming its children if it has any
    and not ``cascade``. Returns ``{"datasets": [], "models", "freed_bytes": 0}``."""
    store.get_model(model_id)
    models = store.list_models()
    children = [m["id"] for m in models if m["parent_id"] == model_id]
    if children and not cascade:
        raise InUseError("model", model_id, {"models": children}, "models were refined from it:")
    model_ids = descendants(models, [model_id])
    with store.engine.begin() as conn:
        _delete_rows(conn, model_ids, [])
    return {"datasets": [], "models": model_ids, "freed_bytes": 0}


def _delete_rows(conn, model_ids: list[str], dataset_ids: list[str]) -> None:
    """In one transaction: the rows, their quarantine entries, and job results naming the datasets."""
    if model_ids:
        conn.execute(delete(tables.models).where(tables.models.c.id.in_(model_ids)))
    if dataset_ids:
        conn.execute(delete(tables.datasets).where(tables.datasets.c.id.in_(dataset_ids)))
        jobs = (
            conn.execute(select(tables.jobs.c.id, tables.jobs.c.result).where(tables.jobs.c.result.is_not(None)))
            .mappings()
            .all()
        )
        for job in jobs:
            result = job["result"] if isinstance(job["result"], dict) else {}
            if result.get("dataset_id") in dataset_ids:
                conn.execute(
                    update(tables.jobs)
                    .where(tables.jobs.c.id == job["id"])
                    .values(result={**result, "dataset_id": None, "deleted_dataset_id": result["dataset_id"]})
                )
    conn.execute(delete(tables.quarantine).where(tables.quarantine.c.record_id.in_(model_ids + dataset_ids)))
