"""API tokens: status codes and reasons (401 missing/unknown/revoked, 403 naming the scope), the
hashed store rows (SQLite and PostgreSQL), the bootstrap admin.token (0600), ?token= only on the
SSE stream, the token CLI (create → use → revoke), and the loopback-only bind rule (exit code 2)."""

from __future__ import annotations

import hashlib
import logging
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from service.frontends.cli_tokens import serve_refusal
from service.frontends.client import Client, resolve_token
from service.http.app import create_app
from service.http.auth import RedactQueryToken
from service.runtime.settings import Settings
from service.security import auth
from service.security.binding import bind_refusal, is_loopback
from service.store import Store, tables
from service.store.tokens import tokens as token_table
from tests.support.api_client import authed_client, bearer, issue_token, wait_job
from tests.support.live_server import Server

ROOT = Path(__file__).resolve().parents[2]
SWEEP = {"axes": ["y"], "frequencies_hz": [20], "cycles": 1, "settle_s": 0.0}


def _cli(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EVCBENCH_")}
    result = subprocess.run(
        [sys.executable, "-m", "service.frontends.cli", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if check:
        assert result.returncode == 0, f"evcbench {' '.join(args)}: {result.stdout}{result.stderr}"
    return result


@pytest.fixture
def service(tmp_path):
    """The app on the default emulated bench and a TestClient that sends no token of its own."""
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=0))
    with TestClient(app) as http:
        yield app, http


def _token(http: TestClient, scope: str, name: str | None = None) -> dict:
    """A token of ``scope`` issued over the API with the bootstrap admin token."""
    admin = auth.read_bootstrap_token(http.app.state.settings.data_dir)
    r = http.post("/api/admin/tokens", json={"name": name or scope, "scope": scope}, headers=bearer(admin))
    assert r.status_code == 201, r.text
    return r.json()


# ---------------------------------------------------------------------- pure functions
@pytest.mark.parametrize(
    "host, expected",
    [
        ("127.0.0.1", True),
        ("127.3.2.1", True),
        ("::1", True),
        ("[::1]", True),
        ("localhost", True),
        ("0.0.0.0", False),
        ("::", False),
        ("192.168.1.20", False),
        ("", False),
        ("bench.lab", False),
    ],
)
def test_is_loopback(host, expected):
    assert is_loopback(host) is expected


def test_bind_refusal_rule():
    assert bind_refusal("127.0.0.1", "off", 0) is None
    assert bind_refusal("127.0.0.1", "tokens", 0) is None
    assert "no API token exists besides the local bootstrap one" in bind_refusal("0.0.0.0", "tokens", 0)
    assert "allowed only on loopback" in bind_refusal("0.0.0.0", "off", 3)
    assert bind_refusal("0.0.0.0", "tokens", 1) is None


def test_required_scope_by_method_and_path():
    assert auth.required_scope("GET", "/api/datasets") == "read"
    assert auth.required_scope("HEAD", "/api/bench") == "read"
    assert auth.required_scope("POST", "/api/sweeps") == "operate"
    assert auth.required_scope("DELETE", "/api/jobs/job_1") == "operate"
    assert auth.required_scope("GET", "/api/admin/tokens") == "admin"
    assert auth.required_scope("GET", "/api/administrator") == "read"  # a prefix, not a substring
    assert [auth.scope_allows(g, "operate") for g in auth.SCOPES] == [False, True, True]


# ---------------------------------------------------------------------- the API
def test_every_api_route_but_health_needs_a_token(service):
    """Every operation in the OpenAPI document answers 401 without a token, except /api/health."""
    _, http = service
    open_ops = []
    for path, operations in http.get("/openapi.json").json()["paths"].items():
        url = re.sub(r"\{[^}]+\}", "x", path)
        for method in operations:
            r = http.request(method.upper(), url)
            if r.status_code != 401:
                open_ops.append(f"{method.upper()} {path} {r.status_code}")
            else:
                assert r.json()["detail"].startswith("missing API token"), (method, path)
    assert open_ops == ["GET /api/health 200"]


def test_missing_unknown_and_revoked_tokens_get_401_with_a_reason(service):
    _, http = service
    r = http.get("/api/bench")
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert r.json()["field"] == "authorization" and "missing API token" in r.json()["detail"]
    r = http.post("/api/sweeps", json=SWEEP)
    assert r.status_code == 401 and "missing API token" in r.json()["detail"]
    r = http.get("/api/bench", headers=bearer("evc_" + "x" * 43))
    assert r.status_code == 401 and r.json()["detail"] == "unknown API token"
    assert "malformed" in http.get("/api/bench", headers=bearer("hunter2")).json()["detail"]

    admin = bearer(auth.read_bootstrap_token(http.app.state.settings.data_dir))
    record = _token(http, "operate", "alice")
    assert http.get("/api/bench", headers=bearer(record["token"])).status_code == 200
    r = http.delete(f"/api/admin/tokens/{record['id']}", headers=admin)
    assert r.status_code == 200 and r.json()["revoked"] is True and r.json()["revoked_at"]
    r = http.get("/api/bench", headers=bearer(record["token"]))
    assert r.status_code == 401
    assert r.json()["detail"] == f"API token {record['id']} (alice) has been revoked"
    assert http.delete("/api/admin/tokens/tok_nope", headers=admin).status_code == 404


def test_the_stop_checks_a_token_seen_lately_without_the_store(service, monkeypatch):
    """The emergency stop takes a token this process verified lately from memory (no store read,
    whose lock hand-offs wait behind downloads and imports), refuses it at once when it is revoked
    over the API, and goes back to the store once RecentTokens.trust_s has passed."""
    app, http = service
    record = _token(http, "operate", "bob")
    operate, admin = bearer(record["token"]), bearer(auth.read_bootstrap_token(app.state.settings.data_dir))
    assert http.get("/api/bench", headers=operate).status_code == 200  # verified against the store
    reads = []
    real_by_hash = app.state.store.tokens.by_hash
    monkeypatch.setattr(app.state.store.tokens, "by_hash", lambda digest: reads.append(digest) or real_by_hash(digest))
    r = http.post("/api/bench/stop", headers=operate)
    assert r.status_code == 200 and r.json()["stopped"] is True and reads == []
    app.state.recent_tokens.trust_s = 0.0  # the memory has gone stale
    assert http.post("/api/bench/stop", headers=operate).status_code == 200 and len(reads) == 1
    app.state.recent_tokens.trust_s = 60.0
    assert http.delete(f"/api/admin/tokens/{record['id']}", headers=admin).status_code == 200
    r = http.post("/api/bench/stop", headers=operate)
    assert r.status_code == 401 and "revoked" in r.json()["detail"]


def test_scopes_read_operate_admin(service):
    app, http = service
    read, operate = bearer(_token(http, "read")["token"]), bearer(_token(http, "operate")["token"])
    assert http.get("/api/bench", headers=read).status_code == 200
    r = http.post("/api/sweeps", json=SWEEP, headers=read)
    assert r.status_code == 403 and r.json()["field"] == "scope"
    assert "needs the 'operate' scope" in r.json()["detail"] and "has 'read'" in r.json()["detail"]
    assert http.post("/api/bench/stop", headers=read).status_code == 403
    assert app.state.store.list_jobs() == []  # the refused sweep left nothing behind

    r = http.post("/api/sweeps", json=SWEEP, headers=operate)
    assert r.status_code == 202, r.text
    assert wait_job(http, r.json()["job_id"], headers=operate)["state"] == "succeeded"
    r = http.get("/api/admin/tokens", headers=operate)
    assert r.status_code == 403 and "needs the 'admin' scope" in r.json()["detail"]


def test_token_management_over_the_api_never_returns_a_secret_twice(service):
    app, http = service
    admin = bearer(auth.read_bootstrap_token(app.state.settings.data_dir))
    created = _token(http, "operate", "ci runner")
    assert created["token"].startswith("evc_") and created["origin"] == "api"
    assert created["scopes"] == ["read", "operate"]
    listed = http.get("/api/admin/tokens", headers=admin).json()
    assert [t["origin"] for t in listed] == ["bootstrap", "api"]
    assert all("token" not in t and "sha256" not in t for t in listed)
    r = http.post("/api/admin/tokens", json={"name": "x", "scope": "root"}, headers=admin)
    assert r.status_code == 422 and r.json()["field"] == "scope"
    r = http.post("/api/admin/tokens", json={"name": "   ", "scope": "read"}, headers=admin)
    assert r.status_code == 422 and r.json()["field"] == "name"


def test_tokens_are_stored_as_sha256_only(service):
    app, http = service
    plaintext = _token(http, "admin", "bob")["token"]
    with app.state.store.engine.connect() as conn:
        rows = [dict(r) for r in conn.execute(select(token_table)).mappings()]
    bob = next(r for r in rows if r["name"] == "bob")
    assert bob["sha256"] == hashlib.sha256(plaintext.encode()).hexdigest()
    assert not any(plaintext in str(value) for row in rows for value in row.values())
    raw = b"".join(p.read_bytes() for p in app.state.settings.data_dir.glob("evcbench.db*"))
    assert bob["sha256"].encode() in raw and plaintext.encode() not in raw


def test_bootstrap_admin_token_file(tmp_path):
    settings = Settings(data_dir=tmp_path, bench="default", seed=0)
    path = tmp_path / "admin.token"
    with TestClient(create_app(settings)) as http:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        token = path.read_text().strip()
        r = http.get("/api/admin/tokens", headers=bearer(token))
        assert r.status_code == 200 and r.json()[0]["origin"] == "bootstrap"
        assert r.json()[0]["scope"] == "admin"
        bootstrap_id = r.json()[0]["id"]
    with TestClient(create_app(settings)):
        assert path.read_text().strip() == token  # a valid bootstrap token is kept across restarts
    store = Store(settings.resolved_database_url, tmp_path)
    store.tokens.revoke(bootstrap_id, "2026-01-01T00:00:00Z")
    store.close()
    with TestClient(create_app(settings)) as http:  # a revoked one is replaced at the next start
        assert path.read_text().strip() != token
        assert http.get("/api/bench", headers=bearer(path.read_text().strip())).status_code == 200
        assert stat.S_IMODE(path.stat().st_mode) == 0o600


def test_query_token_only_on_the_event_stream(service):
    _, http = service
    read = _token(http, "read")["token"]
    operate = bearer(_token(http, "operate")["token"])
    job_id = http.post("/api/sweeps", json=SWEEP, headers=operate).json()["job_id"]
    wait_job(http, job_id, headers=operate)
    r = http.get(f"/api/jobs/{job_id}/events", params={"token": read})
    assert r.status_code == 200 and "event: end" in r.text
    assert http.get(f"/api/jobs/{job_id}/events").status_code == 401
    r = http.get(f"/api/jobs/{job_id}", params={"token": read})
    assert r.status_code == 401 and r.json()["field"] == "token"
    assert "accepted only on /api/jobs/{id}/events" in r.json()["detail"]
    r = http.post("/api/bench/stop", params={"token": read})
    assert r.status_code == 401 and r.json()["field"] == "token"


@pytest.mark.realtime
def test_a_revoked_tokens_open_event_stream_ends_with_an_error(tmp_path):
    """A real server and a sweep paced to real time (60 s of plan): the stream of a read token ends
    with ``event: error`` once the token is revoked, long before the job ends."""
    server = Server(tmp_path / "store", tmp_path / "serve.log", bench="default_realtime")
    try:
        with httpx.Client(base_url=server.url, timeout=30, headers=server.headers) as admin:
            read = admin.post("/api/admin/tokens", json={"name": "watcher", "scope": "read"}).json()
            r = admin.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [1.0], "cycles": 60})
            assert r.status_code == 202 and r.json()["duration_s"] > 60
            job_id, events = r.json()["job_id"], []
            # the browser's way: the token in the query, no header; the Python client's SSE parser
            # (Client.events, which raises ApiError if the stream is refused)
            with Client(http=httpx.Client(base_url=server.url, timeout=30, params={"token": read["token"]})) as viewer:
                for event, data in viewer.events(job_id):
                    events.append((event, data))
                    if len(events) == 1:
                        assert admin.delete(f"/api/admin/tokens/{read['id']}").status_code == 200
            assert [e for e, _ in events[:-1]] == ["progress"] * (len(events) - 1)
            assert events[-1] == (
                "error",
                {
                    "detail": f"API token {read['id']} (watcher) has been revoked",
                    "field": "authorization",
                    "status": 401,
                },
            )
            assert admin.get(f"/api/jobs/{job_id}").json()["state"] in ("queued", "running")  # the job goes on
            admin.delete(f"/api/jobs/{job_id}")
    finally:
        assert server.stop()


def test_auth_off_is_open_and_loopback_only(tmp_path):
    with TestClient(create_app(Settings(data_dir=tmp_path, seed=0, auth="off"))) as http:
        assert http.get("/api/bench").status_code == 200
    assert not (tmp_path / "admin.token").exists()
    with pytest.raises(ValueError, match="only on loopback"):
        create_app(Settings(data_dir=tmp_path, seed=0, auth="off", host="0.0.0.0"))
    with pytest.raises(ValueError, match="'tokens' or 'off'"):
        Settings(data_dir=tmp_path, auth="maybe")


@pytest.mark.postgres
def test_tokens_on_postgresql(postgres_url, tmp_path):
    store = Store(postgres_url, tmp_path)
    try:
        plaintext, record = auth.issue(store, "pg", "operate", "cli")
        assert auth.authenticate(store, plaintext)["id"] == record["id"]
        assert store.tokens.by_hash(auth.hash_token(plaintext))["sha256"] != plaintext
        store.tokens.revoke(record["id"], "2026-01-01T00:00:00Z")
        with pytest.raises(auth.AuthError, match="revoked"):
            auth.authenticate(store, plaintext)
    finally:
        tables.metadata.drop_all(store.engine)
        store.close()


# ---------------------------------------------------------------------- CLI, bind rule, client
@pytest.mark.slow  # several `evcbench` processes
def test_cli_create_use_list_revoke(tmp_path):
    out = _cli("token", "create", "--name", "lab pc", "--scope", "operate", "--data-dir", str(tmp_path))
    plaintext = out.stdout.strip()
    assert plaintext.startswith("evc_") and "shown once" in out.stderr
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=0))
    with TestClient(app) as http:
        assert http.post("/api/bench/stop", headers=bearer(plaintext)).status_code == 200
        listed = _cli("token", "list", "--data-dir", str(tmp_path)).stdout
        line = next(ln for ln in listed.splitlines() if ln.endswith("lab pc"))
        token_id = line.split()[0]
        assert "operate" in line and " cli " in line and "active" in line and plaintext not in listed
        assert (
            _cli("token", "revoke", token_id, "--data-dir", str(tmp_path)).stdout.strip() == f"token {token_id} revoked"
        )
        r = http.get("/api/bench", headers=bearer(plaintext))  # no restart needed
        assert r.status_code == 401 and "revoked" in r.json()["detail"]
        # the stop takes tokens verified lately from memory; a request that found this one revoked
        # has dropped it there too (else it would be refused after RecentTokens.trust_s)
        r = http.post("/api/bench/stop", headers=bearer(plaintext))
        assert r.status_code == 401 and "revoked" in r.json()["detail"]
    assert _cli("token", "revoke", "tok_nope", "--data-dir", str(tmp_path), check=False).returncode == 2


@pytest.mark.slow  # several `evcbench` processes
def test_serve_refuses_a_non_loopback_bind_without_a_token(tmp_path):
    for extra, reason in (
        ((), "no API token exists besides the local bootstrap one"),
        (("--auth", "off"), "allowed only on loopback"),
    ):
        r = _cli("serve", "--host", "0.0.0.0", "--port", "9", "--data-dir", str(tmp_path), *extra, check=False)
        assert r.returncode == 2 and "refusing to listen on 0.0.0.0" in r.stderr and reason in r.stderr
    settings = Settings(data_dir=tmp_path, host="0.0.0.0")
    issue_token(settings, "operate", name="remote")
    assert serve_refusal(settings) is None
    assert serve_refusal(Settings(data_dir=tmp_path, host="0.0.0.0", auth="off")) is not None
    out = _cli(
        "token",
        "create",
        "--name",
        "c",
        "--if-missing",
        "--output",
        str(tmp_path / "c.token"),
        "--data-dir",
        str(tmp_path),
    )
    assert "none created" in out.stderr and not (tmp_path / "c.token").exists()


def test_client_token_from_argument_environment_or_local_admin_file(tmp_path, monkeypatch):
    monkeypatch.delenv("EVCBENCH_TOKEN", raising=False)
    auth.write_secret(tmp_path / "admin.token", "evc_local")
    assert resolve_token("http://127.0.0.1:8000", data_dir=tmp_path) == "evc_local"
    assert resolve_token("http://bench.lab:8000", data_dir=tmp_path) is None  # never sent elsewhere
    assert resolve_token("http://bench.lab:8000", token="evc_arg", data_dir=tmp_path) == "evc_arg"
    monkeypatch.setenv("EVCBENCH_TOKEN", "evc_env")
    assert resolve_token("http://127.0.0.1:8000", data_dir=tmp_path) == "evc_env"
    with Client("http://127.0.0.1:8000", token="evc_arg") as api:
        assert api.http.headers["Authorization"] == "Bearer evc_arg"


def test_authed_client_helper_carries_an_admin_token(tmp_path):
    with authed_client(create_app(Settings(data_dir=tmp_path, seed=0))) as http:
        assert http.get("/api/admin/tokens").status_code == 200


def test_access_log_never_shows_a_query_token():
    record = logging.LogRecord(
        "uvicorn.access",
        logging.INFO,
        __file__,
        1,
        '%s - "%s %s HTTP/%s" %d',
        ("127.0.0.1:5", "GET", "/api/jobs/j/events?token=evc_secret&x=1", "1.1", 200),
        None,
    )
    assert RedactQueryToken().filter(record)
    assert record.getMessage() == '127.0.0.1:5 - "GET /api/jobs/j/events?token=***&x=1 HTTP/1.1" 200'
