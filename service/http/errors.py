"""Error responses: every 4xx carries ``detail`` in words, naming the field at fault in ``field``."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from service.runtime.engine import BenchLatched, EngineUnavailable
from service.runtime.jobs import OtherBenchJob, QueueFull
from service.science.errors import FieldError
from service.store import ArrayStoreUnavailable, IntegrityError, NotFoundError
from service.store.tidy import InUseError

#: the Retry-After (s) of a 503 for an unreachable shared array location
ARRAY_STORE_RETRY_AFTER_S = 30
#: the Retry-After (s) of a 503 while the bench engine is absent or restarting
ENGINE_RETRY_AFTER_S = 5


def engine_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """503 naming the bench engine: its state (absent | restarting), the reason, what to do."""
    bench = getattr(request.app.state, "bench", None)
    return JSONResponse(
        status_code=503,
        headers={"Retry-After": str(ENGINE_RETRY_AFTER_S)},
        content={
            "detail": f"{exc}; the supervisor starts a fresh engine (GET /api/health says when it is back)",
            "field": None,
            "engine": getattr(bench, "engine_state", "absent"),
            "reason": getattr(bench, "absent_reason", None) or str(exc),
        },
    )


def _field_of(loc: tuple | list) -> str:
    """The request field of a pydantic error location: ('body', 'v_max') → 'v_max'."""
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "form", "header")]
    return ".".join(parts) if parts else str(loc[-1]) if loc else "body"


def install(app: FastAPI) -> None:
    """Register the handlers that turn service errors into JSON responses."""

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{"field": _field_of(e.get("loc", ())), "message": e.get("msg", "invalid")} for e in exc.errors()]
        detail = "; ".join(f"{e['field']}: {e['message']}" for e in errors) or "invalid request"
        return JSONResponse(
            status_code=422,
            content={"detail": detail, "field": errors[0]["field"] if errors else None, "errors": errors},
        )

    @app.exception_handler(FieldError)
    async def _field(_request: Request, exc: FieldError) -> JSONResponse:
        return JSONResponse(status_code=exc.status_code, content={"detail": str(exc), "field": exc.field})

    @app.exception_handler(NotFoundError)
    async def _not_found(_request: Request, exc: NotFoundError) -> JSONResponse:
        return JSONResponse(status_code=404, content={"detail": str(exc), "field": exc.field})

    @app.exception_handler(InUseError)
    async def _in_use(_request: Request, exc: InUseError) -> JSONResponse:
        return JSONResponse(
            status_code=409, content={"detail": str(exc), "field": "cascade", "dependents": exc.dependents}
        )

    @app.exception_handler(QueueFull)
    async def _queue_full(_request: Request, exc: QueueFull) -> JSONResponse:
        return JSONResponse(
            status_code=429,
            headers={"Retry-After": str(int(exc.retry_after_s))},
            content={"detail": str(exc), "field": None, "queue": exc.queue, "queued": exc.queued, "limit": exc.limit},
        )

    @app.exception_handler(OtherBenchJob)
    async def _other_bench(_request: Request, exc: OtherBenchJob) -> JSONResponse:
        return JSONResponse(
            status_code=409, content={"detail": str(exc), "field": exc.field, "bench_id": exc.bench_id, "url": exc.url}
        )

    @app.exception_handler(IntegrityError)
    async def _integrity(_request: Request, exc: IntegrityError) -> JSONResponse:
        return JSONResponse(status_code=500, content={"detail": str(exc)})

    @app.exception_handler(EngineUnavailable)
    async def _engine(request: Request, exc: EngineUnavailable) -> JSONResponse:
        return engine_unavailable(request, exc)

    @app.exception_handler(BenchLatched)
    async def _latched(_request: Request, exc: BenchLatched) -> JSONResponse:
        return JSONResponse(status_code=409, content={"detail": str(exc), "field": "bench"})

    @app.exception_handler(ArrayStoreUnavailable)
    async def _array_store(_request: Request, exc: ArrayStoreUnavailable) -> JSONResponse:
        return JSONResponse(
            status_code=503,
            headers={"Retry-After": str(ARRAY_STORE_RETRY_AFTER_S)},
            content={"detail": str(exc), "field": None, "array_store": exc.url},
        )
