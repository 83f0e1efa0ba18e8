"""GET /api/health: is the service up, and which bench does it drive."""

from __future__ import annotations

import time

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service import __version__
from service.http.schemas.bench import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health, responses={503: {"model": Health}})
def health(request: Request):
    """Liveness plus the software version and the bench backend. 503 with ``"status": "degraded"``
    and the reason while the bench engine is absent or restarting (service.runtime.supervisor);
    ``latched_fault`` names a restart that awaits POST /api/bench/reset."""
    state = request.app.state
    bench = state.bench
    engine = getattr(bench, "engine_state", "running")
    body = {
        "status": "ok" if engine == "running" else "degraded",
        "engine": engine,
        "reason": getattr(bench, "absent_reason", None),
        "latched_fault": getattr(bench, "latched", None),
        "version": __version__,
        "backend": bench.parts.backend,
        "store": state.store.backend,
        "uptime_s": round(time.time() - state.started_at, 3),
    }
    return body if engine == "running" else JSONResponse(status_code=503, content=body)
