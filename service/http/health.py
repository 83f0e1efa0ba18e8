"""GET /api/health: is the service up, and which bench does it drive."""

from __future__ import annotations

import time

from fastapi import APIRouter, Request

from service import __version__
from service.http.schemas.bench import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(request: Request) -> dict:
    """Liveness plus the software version and the bench backend."""
    state = request.app.state
    return {
        "status": "ok",
        "version": __version__,
        "backend": state.bench.parts.backend,
        "store": state.store.backend,
        "uptime_s": round(time.time() - state.started_at, 3),
    }
