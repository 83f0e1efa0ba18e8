"""POST /api/trajectories: check an ellipse and its controller against the bench, then run it as a
bench job (FF + PID + ILC through service.science.control, the path the control benchmark measures):
the checks and the job live in service.usecases.track."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from drivers.bench import Bench
from service.http.deps import get_bench, get_jobs, get_store
from service.http.schemas.common import JobQueued
from service.http.schemas.datasets import SweepRequest
from service.http.schemas.trajectories import TrackingRecipe, TrajectoryRequest
from service.runtime.jobs import JobManager
from service.store import Store
from service.usecases.prepare_tracking import check_prepare, prepare_tracking
from service.usecases.track import check_trajectory, run_trajectory, span_sweeps, tracking_recipe

router = APIRouter(tags=["trajectories"])


@router.post("/trajectories", status_code=202, response_model=JobQueued)
def start_trajectory(
    body: TrajectoryRequest,
    bench: Bench = Depends(get_bench),
    store: Store = Depends(get_store),
    jobs: JobManager = Depends(get_jobs),
) -> dict:
    """Queue a tracking run; the result has max_error_y_um, max_error_z_um, rms_error_um,
    relative_error_pct, error_per_period_um and dataset_id. Refused with 422 naming the field if the
    mode, the current, the resonance or the voltage forbid it: nothing is queued then."""
    ellipse = body.ellipse()
    controller = check_trajectory(bench, store, ellipse, body.controller.model_dump(), body.mode)
    params = body.model_dump()
    job = jobs.submit(
        "trajectory",
        params,
        lambda ctx: run_trajectory(ctx, bench, store, ellipse, controller, body.mode, params, body.name),
        needs_bench=True,
    )
    return {"job_id": job["id"], "state": job["state"]}


@router.post("/trajectories/span-sweeps", response_model=list[SweepRequest])
def trajectory_span_sweeps(
    body: TrajectoryRequest, bench: Bench = Depends(get_bench), store: Store = Depends(get_store)
) -> list[dict]:
    """The sweeps (one per axis, ready for POST /api/sweeps) over the voltages this ellipse needs by its
    feedforward models, ± 5 V within the bench's limits: identify models on them for the run. Nothing
    runs; 422 naming controller.feedforward_model_<axis> when an axis has no model."""
    return span_sweeps(bench, store, body.ellipse(), body.controller.model_dump())


@router.post("/trajectories/prepare", status_code=202, response_model=JobQueued)
def prepare_trajectory(
    body: TrajectoryRequest,
    bench: Bench = Depends(get_bench),
    store: Store = Depends(get_store),
    jobs: JobManager = Depends(get_jobs),
) -> dict:
    """Queue the recommended path (GET /api/trajectories/recipe) as one job: the first sweep and a
    model where an axis has no feedforward model, then the span sweeps this ellipse needs and models
    on them. Each sweep is a bench job of its own; the result names the models to run with
    (``feedforward_model_<axis>``), the ``controller`` to use, and the ``steps`` done (the partial
    result while it runs, and after a failed step). 409 while another prepare job is unfinished; 422
    naming the field if a given model cannot be used or the ellipse is beyond them."""
    ellipse = body.ellipse()
    controller = body.controller.model_dump()
    check_prepare(jobs, bench, store, ellipse, controller)
    job = jobs.submit(
        "prepare",
        body.model_dump(),
        lambda ctx: prepare_tracking(ctx, jobs, bench, store, ellipse, controller),
        needs_bench=False,
    )
    return {"job_id": job["id"], "state": job["state"]}


@router.get("/trajectories/recipe", response_model=TrackingRecipe)
def trajectory_recipe() -> dict:
    """The path the product recommends from a fresh store to a tracked ellipse: the first sweep, the
    effects of the feedforward models (on it, then on the span sweeps), and the controller."""
    return tracking_recipe()
