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

from service.runtime.settings import Settings
from service.security import auth
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


ENDED = ("succeeded", "failed", "cancelled")


def job_ended(job: dict) -> bool:
    return job["state"] in ENDED


def job_running(progress: float = 0.0, message: str | None = None):
    """``until`` for wait_job: the job runs, has reached ``progress`` (and its message contains
    ``message``). A job that ends first fails the wait at once, naming its state."""

    def until(job: dict) -> bool:
        assert job["state"] in ("queued", "running"), f"job {job.get('id')} ended before it ran far enough: {job}"
        return (
            job["state"] == "running"
            and job["progress"] >= progress
            and (message is None or message in (job.get("message") or ""))
        )

    return until


def _reader(source, headers: dict | None):
    """``job_id -> job dict`` for ``source``: a callable (JobManager.get, Client.job, ...) is used as
    it is; anything else is an HTTP client on the service root (TestClient, httpx.Client)."""
    if callable(source) and not hasattr(source, "get"):
        return source
    return lambda job_id: source.get(f"/api/jobs/{job_id}", headers=headers).json()


def wait_job(
    source, job_id: str, until=job_ended, timeout_s: float = 120.0, headers: dict | None = None, poll_s: float = 0.02
) -> dict:
    """The one job poller of the tests: read the job from ``source`` until ``until(job)``; the job,
    or AssertionError naming its last state after ``timeout_s``.

    ``source`` is an HTTP client on the service root (a TestClient or an httpx client: ``GET
    /api/jobs/{job_id}``, with ``headers`` if given) or a callable ``job_id -> job`` (the in-process
    ``JobManager.get``, the Python client's ``Client.job``, a lambda on a client with another root).
    ``until`` may raise to fail fast (``job_running`` does when the job ends first)."""
    read = _reader(source, headers)
    deadline = time.monotonic() + timeout_s
    while True:
        job = read(job_id)
        if until(job):
            return job
        assert time.monotonic() < deadline, f"job {job_id} still {job.get('state')} after {timeout_s:g} s: {job}"
        time.sleep(poll_s)
