"""The FastAPI application: opens the store (registering its bench in the lab's table, then recovering
what a killed process of this bench left: see service.runtime.heartbeat and service.runtime.recovery)
and the bench at start-up, mounts the routers, and at shut-down stops the jobs (a running sweep keeps
its partial data), closes the bench at 0 V and marks the bench stopped."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI

from drivers.bench import Bench
from service import __version__
from service.http import admin as admin_api
from service.http import auth as auth_api
from service.http import bench as bench_api
from service.http import datasets as datasets_api
from service.http import discovery as discovery_api
from service.http import effects as effects_api
from service.http import errors as errors_api
from service.http import health as health_api
from service.http import jobs as jobs_api
from service.http import lab as lab_api
from service.http import models as models_api
from service.http import paper as paper_api
from service.http import reports as reports_api
from service.http import sweeps as sweeps_api
from service.http import tokens as tokens_api
from service.http import trajectories as trajectories_api
from service.http import web as web_api
from service.runtime.heap import freeze_heap
from service.runtime.heartbeat import Heartbeat, claim, new_instance, register, running_state
from service.runtime.jobs import JobManager
from service.runtime.recovery import recover
from service.runtime.settings import Settings
from service.runtime.stop_port_link import StopPortLink
from service.runtime.supervisor import supervise
from service.science.effects import REGISTRY as EFFECTS_REGISTRY
from service.security.auth import ensure_bootstrap_token
from service.security.binding import auth_refusal
from service.store import Store
from service.usecases.recorder import bench_snapshot

#: Routers mounted under /api, in the order they appear in the docs. Every one but health needs a
#: token (service/http/auth.py): read for GET/HEAD, operate for writes, admin under /api/admin.
ROUTERS = (
    health_api.router,
    bench_api.stop_router,
    bench_api.router,
    jobs_api.router,
    sweeps_api.router,
    datasets_api.router,
    models_api.router,
    discovery_api.router,
    effects_api.router,
    reports_api.router,
    trajectories_api.router,
    lab_api.router,
    paper_api.router,
    tokens_api.router,
    admin_api.router,
)
#: Mounted without the router-level token check: health needs none; the emergency stop checks its
#: token itself, on its own thread (service/http/bench.py)
OPEN_ROUTERS = (health_api.router, bench_api.stop_router)


def open_configured_bench(settings: Settings) -> Bench:
    """Open the bench the settings name (the emulated backend unless a config says otherwise): in
    the bench engine's own process (``engine = process``, the default) or in this one (``inline``)."""
    if settings.engine == "process":
        from service.runtime.engine import EngineBench, start_engine

        def start(restart: bool = False):
            return start_engine(
                settings.bench,
                seed=settings.seed,
                stop_address=(settings.host, settings.stop_port),
                bench_id=settings.bench_id,
                restart=restart,
            )

        bench = EngineBench(start())
        bench.start_again = start  # the supervisor's fresh engine (service.runtime.supervisor)
        return bench
    from drivers.factory import open_bench

    return open_bench(settings.bench, seed=settings.seed)


def _stop_port_link(app: FastAPI, store: Store, settings: Settings) -> StopPortLink | None:
    """The engine's stop port (an engine in its own process has one), told the service's tokens and
    jobs; None for a bench in this process."""
    if getattr(app.state.bench, "stop_port", None) is None:
        return None
    return StopPortLink(
        app.state.bench,
        store,
        app.state.jobs,
        settings.auth == "off",
        announce=(settings.data_dir, settings.port, settings.bench_id),
    ).start()


def _load_effect_plugins(settings: Settings) -> None:
    """The plug-in effects (entry points, then the settings' directories); a refused one is logged by
    name with its error and listed by GET /api/effects, and the service starts without it."""
    EFFECTS_REGISTRY.load_plugins(settings.effects_dir)
    for failure in EFFECTS_REGISTRY.failed:
        logging.getLogger("evcbench.effects").warning(
            "effect plug-in %s refused (%s): %s", failure["name"], failure["origin"], failure["error"]
        )
    loaded = [n for n, o in EFFECTS_REGISTRY.origins.items() if o != "builtin"]
    if loaded:
        logging.getLogger("evcbench.effects").info("effect plug-ins loaded: %s", ", ".join(loaded))


def create_app(settings: Settings | None = None, bench_factory: Callable[[Settings], Bench] | None = None) -> FastAPI:
    """Build the app. The bench is opened on start-up and left at 0 V and closed on shut-down.
    With auth on, start-up also writes the bootstrap admin token to <data_dir>/admin.token."""
    settings = settings or Settings()
    refusal = auth_refusal(settings.host, settings.auth)
    if refusal:
        raise ValueError(refusal)
    factory = bench_factory or open_configured_bench

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
        app.state.settings = settings
        app.state.started_at = time.time()
        app.state.store = store = Store(settings.resolved_database_url, settings.data_dir, array_url=settings.array_url)
        store.bench_id = settings.bench_id  # every row it adds carries it; it recovers only its own
        app.state.instance = instance = new_instance()
        heartbeat = None
        try:
            claim(store, settings, instance)  # BenchIdInUse before anything is recovered
            app.state.recovery = recover(store)
            if settings.auth == "tokens":
                token_path = ensure_bootstrap_token(store, settings.data_dir, settings.bench_id)
                logging.getLogger("uvicorn.error").info(  # printed with uvicorn's own start-up lines
                    "API token: paste the content of %s under the dashboard's Settings (top right)", token_path
                )
            _load_effect_plugins(settings)
            app.state.bench = factory(settings)
            try:
                app.state.jobs = JobManager(
                    store,
                    on_cancel_bench=app.state.bench.cancel_plan,
                    bench_gate=getattr(app.state.bench, "admit_job", None),
                )
                app.state.stop_port_link = link = _stop_port_link(app, store, settings)
                register(store.benches, settings, instance, "idle", bench_snapshot(app.state.bench))
                heartbeat = Heartbeat(
                    settings.resolved_database_url,
                    settings.bench_id,
                    instance,
                    settings.heartbeat_s,
                    lambda: running_state(app.state.jobs),
                ).start()
                app.state.supervisor = supervisor = supervise(app.state.bench, app.state.jobs)
                freeze_heap()  # what start-up loaded is never scanned again by the collector
                try:
                    yield
                finally:
                    if supervisor is not None:
                        supervisor.close()  # before the engine is closed: that exit is no death
                    if link is not None:
                        link.close()
                    app.state.jobs.shutdown()
            finally:
                app.state.bench.close()
        finally:
            if heartbeat is not None:
                heartbeat.stop()  # after the bench is at 0 V and closed: state "stopped"
            store.close()

    app = FastAPI(
        title="EVC Bench",
        version=__version__,
        lifespan=lifespan,
        description="Characterise, model and control a two-axis piezo EVC bench. Units live in "
        "field names: _v volts at the actuator, _um micrometres, _hz, _s.",
    )
    app.state.settings = settings  # also before start-up, for tests that seed tokens
    errors_api.install(app)
    auth_api.install(app)
    for router in ROUTERS:
        app.include_router(router, prefix="/api", dependencies=[] if router in OPEN_ROUTERS else auth_api.REQUIRE_TOKEN)
    web_api.mount(app)  # the dashboard's static files at /web, after the API routes
    return app
