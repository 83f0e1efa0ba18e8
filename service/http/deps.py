"""Request dependencies: the store, the job manager and the bench of the running app."""

from __future__ import annotations

from fastapi import Request

from drivers.bench import Bench
from service.runtime.jobs import JobManager
from service.store import Store


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_jobs(request: Request) -> JobManager:
    return request.app.state.jobs


def get_bench(request: Request) -> Bench:
    return request.app.state.bench
