"""POST /api/sweeps: check a characterisation plan against the bench, then queue it as a bench job."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from drivers.bench import Bench
from service.http.deps import get_bench, get_jobs, get_store
from service.http.schemas.datasets import SweepQueued, SweepRequest
from service.runtime.jobs import JobManager
from service.science.errors import FieldError
from service.store import NotFoundError, Store
from service.usecases.acquire import queue_sweep

router = APIRouter(tags=["sweeps"])


@router.post("/sweeps", status_code=202, response_model=SweepQueued)
def start_sweep(
    body: SweepRequest,
    bench: Bench = Depends(get_bench),
    store: Store = Depends(get_store),
    jobs: JobManager = Depends(get_jobs),
) -> dict:
    """Queue a sweep; the job's result is ``{"dataset_id"}``. Refused with 422 (naming the field)
    if the plan leaves the bench's voltage, current or slew limits (or ``experiment_of`` names no
    stored model): nothing is queued then."""
    values = body.model_dump()
    name = values.pop("name")
    if body.experiment_of is not None:
        try:
            store.get_model(body.experiment_of.model_id)
        except NotFoundError:
            raise FieldError("experiment_of", f"no model {body.experiment_of.model_id}") from None
    job, planned = queue_sweep(jobs, bench, store, values, name)
    return {
        "job_id": job["id"],
        "state": job["state"],
        "samples": planned.samples,
        "duration_s": planned.duration_s,
        "blocks": planned.blocks,
    }
