"""Jobs: GET /api/jobs, GET /api/jobs/{id}, GET /api/jobs/{id}/events (SSE), DELETE /api/jobs/{id}."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import StreamingResponse

from service.http.auth import require_token, token_recheck
from service.http.deps import get_jobs
from service.http.schemas.common import BENCH_FILTER, Job, JobKind, JobState
from service.http.schemas.streams import JOB_EVENTS
from service.runtime.jobs import JobManager
from service.store import TERMINAL_STATES

router = APIRouter(prefix="/jobs", tags=["jobs"])


@router.get("", response_model=list[Job])
def list_jobs(
    limit: int = Query(100, ge=1, le=1000),
    bench_id: str | None = BENCH_FILTER,
    kind: JobKind | None = Query(None, description="only the jobs of this kind"),
    state: JobState | None = Query(None, description="only the jobs in this state (e.g. running)"),
    model_id: str | None = Query(
        None,
        min_length=1,
        max_length=40,
        pattern=r"^[A-Za-z0-9][A-Za-z0-9_-]*$",
        description="only the jobs started from this model (params.model_id) or that ended at it (a "
        "discover run's result.final_model_id)",
    ),
    jobs: JobManager = Depends(get_jobs),
) -> list[dict]:
    """The newest jobs first (of every bench of the lab): id, kind, state, progress (0..1), message,
    result, error, timestamps, bench_id. ``kind`` and ``model_id`` narrow the list (a dashboard page
    asks for one model's discover runs, not every job's result), ``state`` to the jobs in one state
    (the Bench page lists the running ones, however old, above the newest)."""
    return jobs.list(limit, bench_id=bench_id, kind=kind, model_id=model_id, state=state)


@router.get("/{job_id}", response_model=Job)
def get_job(job_id: str, jobs: JobManager = Depends(get_jobs)) -> dict:
    """One job: ``state`` is queued | running | succeeded | failed | cancelled; ``progress`` 0..1."""
    return jobs.get(job_id)


@router.get("/{job_id}/events", response_class=StreamingResponse, responses=JOB_EVENTS)
async def job_events(
    job_id: str, request: Request, token: dict = Depends(require_token), jobs: JobManager = Depends(get_jobs)
) -> StreamingResponse:
    """Server-sent events: ``progress`` on every change (data: the job as JSON), then ``end``. If the
    token is revoked meanwhile, the stream ends with ``error`` (data: ``{"detail", "field", "status"}``)."""
    jobs.store.get_job(job_id)  # 404 before the stream opens
    events = jobs.events(job_id, recheck=token_recheck(request, token))  # ends if the token is revoked
    return StreamingResponse(
        events, media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    )


@router.delete(
    "/{job_id}",
    status_code=202,
    response_model=Job,
    responses={200: {"model": Job, "description": "The job had already ended; it is left as it was."}},
)
def cancel_job(job_id: str, response: Response, jobs: JobManager = Depends(get_jobs)) -> dict:
    """Cancel: a queued job is cancelled at once; a running sweep stops at its next block,
    leaves the output at 0 V and keeps the samples so far as a partial dataset (202). A job that
    had already ended is left as it was and answered with its final state (200). 409 (``field``
    job_id, with the ``bench_id`` and ``url`` of its service) for another bench's unfinished job."""
    was_over = jobs.get(job_id)["state"] in TERMINAL_STATES
    job = jobs.cancel(job_id)
    if was_over:
        response.status_code = 200
    return job
