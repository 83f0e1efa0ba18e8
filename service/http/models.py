"""Models: POST /api/models (an identification job), GET one or all, and compare with a dataset.

Diagnosis, refine and history live in service.http.discovery under the same ``/models`` prefix.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from service.http.deps import get_jobs, get_store
from service.http.schemas.common import BENCH_FILTER, Deleted, JobQueued, LabelsUpdate, with_figures
from service.http.schemas.models import Comparison, Model, ModelRequest
from service.runtime.jobs import JobManager
from service.science.data.export import JSON_DEFAULT_MAX_POINTS
from service.store import ModelRow, Store
from service.usecases.identify import check_identify_request, compare, identify
from service.usecases.provenance import model_origin

router = APIRouter(prefix="/models", tags=["models"])


def model_view(row: ModelRow, store: Store) -> dict:
    """A model record as the API shows it (units in the field names of parameters and metrics), with
    the ``origin`` of its data (service.usecases.provenance.model_origin)."""
    return {
        "id": row["id"],
        "axis": row["axis"],
        "kind": row["kind"],
        "effects": row["effects"],
        "parent_id": row["parent_id"],
        "datasets": row["datasets"],
        "options": row["options"],
        "parameters": row["parameters"],
        "parameters_sha256": row["parameters_sha256"],
        "metrics": row["metrics"],
        "software_version": row["software_version"],
        "job_id": row["job_id"],
        "created_at": row["created_at"],
        "name": row["name"],
        "tags": row["tags"],
        "notes": row["notes"],
        "bench_id": row.get("bench_id"),
        "origin": model_origin(store, row["datasets"]),
    }


@router.post("", status_code=202, response_model=JobQueued)
def create_model(body: ModelRequest, store: Store = Depends(get_store), jobs: JobManager = Depends(get_jobs)) -> dict:
    """Queue an identification; the job's result is ``{"model_id", "train_rms_um", "validation_rms_um"}``.
    It fits on all but the last ⌈20 %⌉ cycles of every block and validates on those."""
    check_identify_request(store, body.axis, body.datasets, body.effects, body.model)
    params = body.model_dump()
    job = jobs.submit("identify", params, lambda ctx: identify(ctx, store, **params), needs_bench=False)
    return {"job_id": job["id"], "state": job["state"]}


@router.get("", response_model=list[Model], response_model_exclude_unset=True)
def list_models(bench_id: str | None = BENCH_FILTER, store: Store = Depends(get_store)) -> list[dict]:
    """Every model of every bench of the lab (``bench_id``: that bench's), oldest first."""
    return [model_view(row, store) for row in store.list_models(bench_id)]


@router.get("/{model_id}", response_model=Model, response_model_exclude_unset=True)
def get_model(model_id: str, store: Store = Depends(get_store)) -> dict:
    """A model: kind, effects, parameters (``model.to_dict()``) and train/held-out metrics."""
    return model_view(store.get_model(model_id), store)


@router.patch("/{model_id}", response_model=Model, response_model_exclude_unset=True)
def label_model(model_id: str, body: LabelsUpdate, store: Store = Depends(get_store)) -> dict:
    """Rename, tag or annotate a model (the fields given; its parameters never change)."""
    return model_view(store.label_model(model_id, **body.model_dump(exclude_unset=True)), store)


@router.delete("/{model_id}", response_model=Deleted)
def delete_model(
    model_id: str,
    cascade: bool = Query(False, description="also delete every model refined from it"),
    store: Store = Depends(get_store),
) -> dict:
    """Delete a model. Refused with 409 naming its children (``dependents``) unless ``cascade=true``."""
    return store.delete_model(model_id, cascade)


@router.get("/{model_id}/compare", response_model=Comparison, response_model_exclude_unset=True)
@with_figures(json_max_points=JSON_DEFAULT_MAX_POINTS)
def compare_model(
    model_id: str,
    dataset: str = Query(..., description="dataset id"),
    max_points: int | None = Query(
        None, ge=2, description=(f"at most this many points per array (default {JSON_DEFAULT_MAX_POINTS})")
    ),
    arrays: bool = Query(True, description="false: metrics only"),
    store: Store = Depends(get_store),
) -> dict:
    """Measured vs predicted displacement (µm), the residual, and RMS / max / fit % metrics over
    all blocks and per block, split into training and held-out cycles.

    The arrays are every ``stride``-th sample, at most ``max_points`` per array: by default {json_max_points},
    the decimation of ``GET /api/datasets/{{id}}/data``, so a long record is never built as JSON whole
    (ask for ``max_points`` ≥ ``samples`` to get every sample). The metrics always use every sample.
    """
    return compare(store, model_id, dataset, max_points, arrays)
