"""In-process API clients that carry a token, for the tests that call the API through TestClient.

    app = create_app(Settings(data_dir=tmp_path, seed=0))
    with authed_client(app) as http:          # admin scope unless scope= says otherwise
        http.get("/api/bench")

The token is issued in the app's store before start-up (as ``evcbench token create`` would).
"""
from __future__ import annotations

import time

from fastapi import FastAPI
from fastapi.testclient import TestClient

from service.security import auth
from service.runtime.settings import Settings
from service.store import Store


def issue_token(settings: Settings, scope: str = "admin", name: str = "tests") -> str:
    """A new token of ``scope`` in the store of ``settings``; returns its plaintext."""
    store = Store(settings.resolved_database_url, settings.data_dir)
    try:
        return auth.issue(store, name, scope, "cli")[0]
    finally:
        store.close()


def bearer(token: str) -> dict:
    """The request header that carries ``token``."""
    return {"Authorization": f"Bearer {token}"}


def authed_client(app: FastAPI, scope: str = "admin", **kwargs) -> TestClient:
    """A TestClient of ``app`` sending a fresh token of ``scope`` (also in ``client.token``)."""
    token = issue_token(app.state.settings, scope)
    client = TestClient(app, headers=bearer(token), **kwargs)
    client.token = token
    return client


def job_ended(job: dict) -> bool:
    return job["state"] in ("succeeded", "failed", "cancelled")


def wait_job(http, job_id: str, until=job_ended, timeout_s: float = 120.0, headers: dict | None = None,
             poll_s: float = 0.02) -> dict:
    """Poll ``GET /api/jobs/{job_id}`` on ``http`` (a TestClient or an httpx client on the service
    root) until ``until(job)``; the job, or AssertionError naming its last state after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        job = http.get(f"/api/jobs/{job_id}", headers=headers).json()
        if until(job):
            return job
        assert time.monotonic() < deadline, f"job {job_id} still {job.get('state')} after {timeout_s:g} s: {job}"
        time.sleep(poll_s)
