"""The FastAPI application: opens the bench at start-up, mounts the routers, closes it at 0 V."""
from __future__ import annotations

import time
from contextlib import asynccontextmanager
from typing import Callable

from fastapi import FastAPI

from drivers.bench import Bench
from service import __version__
from service.api import bench as bench_api
from service.api import health as health_api
from service.settings import Settings


def open_configured_bench(settings: Settings) -> Bench:
    """Open the bench the settings name (the emulated backend unless a config says otherwise)."""
    from drivers.emulated import open_bench

    return open_bench(settings.bench, seed=settings.seed)


def create_app(settings: Settings | None = None, bench_factory: Callable[[Settings], Bench] | None = None) -> FastAPI:
    """Build the app. The bench is opened on start-up and left at 0 V and closed on shut-down."""
    settings = settings or Settings()
    factory = bench_factory or open_configured_bench

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        app.state.settings = settings
        app.state.started_at = time.time()
        app.state.bench = factory(settings)
        try:
            yield
        finally:
            app.state.bench.close()

    app = FastAPI(title="EVC Bench", version=__version__, lifespan=lifespan,
                  description="Characterise, model and control a two-axis piezo EVC bench.")
    app.include_router(health_api.router, prefix="/api")
    app.include_router(bench_api.router, prefix="/api")
    return app
