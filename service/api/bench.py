"""GET /api/bench: backend, axes, amplifier and sensor state, limits."""
from __future__ import annotations

from fastapi import APIRouter, Request

router = APIRouter(tags=["bench"])


@router.get("/bench")
def bench_state(request: Request) -> dict:
    """The bench's devices, their present state and its hard limits (actuator volts, amperes, hertz)."""
    return request.app.state.bench.describe()
