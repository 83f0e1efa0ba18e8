"""GET /api/bench: backend, axes, amplifier and sensor state, limits; POST /api/bench/stop."""
from __future__ import annotations

from fastapi import APIRouter, Request

router = APIRouter(tags=["bench"])


@router.get("/bench")
def bench_state(request: Request) -> dict:
    """The bench's devices, their present state and its hard limits (actuator volts, amperes, hertz)."""
    state = request.app.state
    return {**state.bench.describe(), "running_job_id": state.jobs.running_bench_job}


@router.post("/bench/stop")
def emergency_stop(request: Request) -> dict:
    """Emergency stop: drive every output to 0 V now and cancel the job that owns the bench
    (its samples so far are kept as a partial dataset)."""
    state = request.app.state
    job_id = state.jobs.cancel_running_bench_job()
    state.bench.stop()
    return {"stopped": True, "cancelled_job_id": job_id, "output_v": state.bench.output_v()}
