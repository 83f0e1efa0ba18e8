"""Discovery routes under /models: diagnosis, refine (a job) and history. No science here."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from service.http.deps import get_jobs, get_store
from service.http.schemas.common import JobQueued
from service.http.schemas.models import Diagnosis, History, RefineRequest
from service.usecases.discover import diagnose_model, history, refine_params
from service.runtime.jobs import JobManager
from service.usecases.identify import identify
from service.store import Store

router = APIRouter(prefix="/models", tags=["discovery"])


@router.get("/{model_id}/diagnosis", response_model=Diagnosis, response_model_exclude_unset=True)
def get_diagnosis(model_id: str, extra_datasets: list[str] = Query(default=[]),
                  store: Store = Depends(get_store)) -> dict:
    """Residual RMS, noise floor, verdict, ranked candidates with evidence, failures, ambiguity."""
    return diagnose_model(store, model_id, extra_datasets)


@router.post("/{model_id}/refine", status_code=202, response_model=JobQueued)
def refine(model_id: str, body: RefineRequest, store: Store = Depends(get_store),
           jobs: JobManager = Depends(get_jobs)) -> dict:
    """Queue a refit with another effect set on the same data; the new model's parent is ``model_id``."""
    params = refine_params(store, model_id, body.add, body.remove, body.effects, body.datasets)
    job = jobs.submit("refine", params, lambda ctx: identify(ctx, store, **params), needs_bench=False)
    return {"job_id": job["id"], "state": job["state"]}


@router.get("/{model_id}/history", response_model=History)
def get_history(model_id: str, store: Store = Depends(get_store)) -> dict:
    """The lineage from the first model to this one, with train and validation RMS at each step."""
    return {"model_id": model_id, "steps": history(store, model_id)}
