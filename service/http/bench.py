"""GET /api/bench: backend, axes, amplifier and sensor state, limits; POST /api/bench/stop;
POST /api/bench/reset; GET /api/bench/live."""

from __future__ import annotations

import asyncio
from concurrent.futures import ThreadPoolExecutor

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.security import HTTPAuthorizationCredentials

from drivers.bench import BenchBusy
from service.http.auth import AUTH_ERRORS, BEARER, require_token_for_stop
from service.http.schemas.bench import BenchState, EmergencyStop, FaultsReset, LiveSignals
from service.runtime.priority import SAFETY_NICE, set_thread_nice
from service.runtime.safe_shutdown import safe_state
from service.runtime.stop_port import EMERGENCY_STOP

router = APIRouter(tags=["bench"])


@router.get("/bench", response_model=BenchState, response_model_exclude_unset=True)
def bench_state(request: Request) -> dict:
    """The bench's devices, their present state and its hard limits (actuator volts, amperes, hertz)."""
    state = request.app.state
    return {
        **state.bench.describe(),
        "bench_id": state.settings.bench_id,
        "running_job_id": state.jobs.running_bench_job,
    }


#: The emergency stop's own thread: it never waits for the request thread pool that downloads,
#: imports and other routes share.
_STOP_EXECUTOR = ThreadPoolExecutor(
    max_workers=1, thread_name_prefix="evc-estop", initializer=set_thread_nice, initargs=(SAFETY_NICE,)
)


#: The stop's own router: its token is checked on the stop's thread (require_token_for_stop inside
#: the handler: from memory if this process verified it lately), not by a router dependency, which FastAPI runs on the request thread pool that a busy
#: service's downloads and imports hold (app.py mounts it without the router-level check).
stop_router = APIRouter(tags=["bench"])


def _authorized_stop(request: Request, credentials: HTTPAuthorizationCredentials | None) -> dict:
    require_token_for_stop(request, credentials)  # 401/403 as every route: nothing moves without a token
    return safe_state(request.app, EMERGENCY_STOP)


@stop_router.post("/bench/stop", response_model=EmergencyStop, responses=AUTH_ERRORS)
async def emergency_stop(request: Request, credentials: HTTPAuthorizationCredentials | None = Depends(BEARER)) -> dict:
    """Emergency stop: drive every output to 0 V first (the bench engine aborts the running block, the
    loop writes 0 V within one control period, or 0 V is written from the engine's stop thread),
    then cancel the job that owns the bench with the reason "emergency stop" (its samples so far are
    kept as a partial dataset) and the bench jobs queued behind it, so the bench stays still. Jobs
    submitted afterwards run normally. With no bench engine (dead, hung or restarting) it still
    answers 200: the jobs are cancelled and ``engine_note`` says what was done about the outputs. ``zero_after_request_ms`` is the engine's measured time from
    receiving the stop to the 0 V write. Needs an ``operate`` token, checked on the stop's own thread."""
    out = await asyncio.get_running_loop().run_in_executor(_STOP_EXECUTOR, _authorized_stop, request, credentials)
    return {
        "stopped": True,
        "door": "service route",
        **{
            k: out[k]
            for k in (
                "cancelled_job_id",
                "cancelled_queued_job_ids",
                "loop_answered",
                "output_v",
                "zero_after_request_ms",
            )
        },
        "zero_monotonic_s": out["stop"]["zero_monotonic_s"],
        "engine_note": out.get("engine_note"),
    }


@router.post("/bench/reset", response_model=FaultsReset)
def reset_faults(request: Request) -> dict:
    """Clear latched amplifier faults (e.g. an over-current trip) and the watchdog's trip, with the
    outputs at 0 V, so jobs can run again. 409 while a job owns the bench. The answer lists what was
    cleared and what remains (a lost sensor is not mended by a reset)."""
    state = request.app.state
    if state.jobs.running_bench_job is not None:
        raise HTTPException(409, detail=f"job {state.jobs.running_bench_job} owns the bench; stop it first")
    try:
        out = state.bench.clear_faults()
    except BenchBusy as exc:
        raise HTTPException(409, detail=str(exc)) from None
    return {**out, "output_v": state.bench.output_v()}


@router.get("/bench/live", response_model=LiveSignals, response_model_exclude_unset=True)
def bench_live(
    request: Request,
    since: int | None = Query(
        default=None, ge=0, description=("cursor from the previous answer; omitted: the latest max_points samples")
    ),
    max_points: int = Query(default=2000, ge=1, le=20_000),
) -> dict:
    """Live signals of whatever the bench streams (any job): decimated t_s, u_<axis>_v and
    x_<axis>_um since ``since``, with the cursor for the next call. ``runs`` numbers each
    sample's run (time restarts at 0 s with every run); ``running_job_id`` names the job."""
    state = request.app.state
    return {
        **state.bench.live.since(since, max_points),
        "axes": list(state.bench.axes),
        "running_job_id": state.jobs.running_bench_job,
    }
