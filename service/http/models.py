"""Models: POST /api/models (an identification job), GET one or all, and compare with a dataset.

Diagnosis, refine and history live in service.http.discovery under the same ``/models`` prefix.
"""
from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, Query
from pydantic import BaseModel, ConfigDict, Field

from service.http.deps import get_jobs, get_store
from service.runtime.jobs import JobManager
from service.usecases.identify import check_identify_request, compare, identify
from service.store import Store

router = APIRouter(prefix="/models", tags=["models"])


class ModelRequest(BaseModel):
    """Identify a model of one axis from stored datasets."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, protected_namespaces=())

    axis: Literal["y", "z"]
    datasets: list[str] = Field(min_length=1, max_length=100)
    effects: list[str] = Field(default=["hysteresis"])
    model: str = Field(default="static_pi", description="static_pi | dynamic_pi | grpi | composite "
                                                        "(static PI + effects; implied by any effect beyond hysteresis)")
    n_operators: int = Field(default=10, ge=1, le=100)


def model_view(row: dict) -> dict:
    """A model record as the API shows it (units in the field names of parameters and metrics)."""
    return {"id": row["id"], "axis": row["axis"], "kind": row["kind"], "effects": row["effects"],
            "parent_id": row["parent_id"], "datasets": row["datasets"], "options": row["options"],
            "parameters": row["parameters"], "parameters_sha256": row["parameters_sha256"],
            "metrics": row["metrics"], "software_version": row["software_version"], "job_id": row["job_id"],
            "created_at": row["created_at"]}


@router.post("", status_code=202)
def create_model(body: ModelRequest, store: Store = Depends(get_store), jobs: JobManager = Depends(get_jobs)) -> dict:
    """Queue an identification; the job's result is ``{"model_id", "train_rms_um", "validation_rms_um"}``.
    It fits on all but the last ⌈20 %⌉ cycles of every block and validates on those."""
    check_identify_request(store, body.axis, body.datasets, body.effects, body.model)
    params = body.model_dump()
    job = jobs.submit("identify", params, lambda ctx: identify(ctx, store, **params), needs_bench=False)
    return {"job_id": job["id"], "state": job["state"]}


@router.get("")
def list_models(store: Store = Depends(get_store)) -> list[dict]:
    """Every model, oldest first."""
    return [model_view(row) for row in store.list_models()]


@router.get("/{model_id}")
def get_model(model_id: str, store: Store = Depends(get_store)) -> dict:
    """A model: kind, effects, parameters (``model.to_dict()``) and train/held-out metrics."""
    return model_view(store.get_model(model_id))


@router.get("/{model_id}/compare")
def compare_model(model_id: str, dataset: str = Query(..., description="dataset id"),
                  max_points: int | None = Query(None, ge=2, description="decimate the arrays to about this many"),
                  arrays: bool = Query(True, description="false: metrics only"),
                  store: Store = Depends(get_store)) -> dict:
    """Measured vs predicted displacement (µm), the residual, and RMS / max / fit % metrics over
    all blocks and per block, split into training and held-out cycles."""
    return compare(store, model_id, dataset, max_points, arrays)
