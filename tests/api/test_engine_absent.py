"""Nothing pretends (issue 42 §2): while no bench engine is attached, health is degraded and every bench
path answers 503 naming the engine; the emergency stop answers with what it could do; after a
restart the fault stays latched (409) until the reset. The engine here is real (its own process),
detached and attached again as the supervisor does (service/runtime/supervisor.py)."""

from __future__ import annotations

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client

REASON = "the bench engine process was killed by SIGKILL"
LATCHED = f"engine restarted: {REASON}, outputs set to 0 V at 2026-01-01T00:00:00.000Z"


def test_without_an_engine_every_bench_path_says_so_and_a_restart_stays_latched(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=1, engine="process"))
    with authed_client(app) as http:
        bench = app.state.bench
        assert http.get("/api/health").json()["status"] == "ok"
        jobs_before = len(http.get("/api/jobs").json())
        link = bench.detach(REASON)
        try:
            health = http.get("/api/health")
            assert health.status_code == 503
            assert health.json()["status"] == "degraded" and health.json()["reason"] == REASON
            for method, path, body in (
                ("GET", "/api/bench", None),
                ("GET", "/api/bench/live", None),
                ("POST", "/api/bench/reset", None),
                ("POST", "/api/sweeps", {"axes": ["y"], "frequencies_hz": [1.0], "cycles": 1}),
            ):
                r = http.request(method, path, json=body)
                assert r.status_code == 503, (path, r.text)
                assert r.json()["engine"] == "restarting" and r.json()["reason"] == REASON
                assert "bench engine" in r.json()["detail"] and r.headers["Retry-After"] == "5"
            assert len(http.get("/api/jobs").json()) == jobs_before  # the sweep was refused, not queued
            stop = http.post("/api/bench/stop")
            assert stop.status_code == 200 and stop.json()["output_v"] == {}
            assert REASON in stop.json()["engine_note"] and "0 V" in stop.json()["engine_note"]
        finally:
            bench.attach(link, latched=LATCHED)
        health = http.get("/api/health")
        assert health.status_code == 200 and health.json()["latched_fault"] == LATCHED
        assert http.get("/api/bench").json()["engine"]["latched_fault"] == LATCHED
        r = http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [1.0], "cycles": 1})
        assert r.status_code == 409 and r.json()["field"] == "bench" and LATCHED in r.json()["detail"]
        reset = http.post("/api/bench/reset")
        assert reset.status_code == 200 and reset.json()["cleared"][0] == LATCHED
        assert http.get("/api/health").json()["latched_fault"] is None
        assert http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [1.0], "cycles": 1}).status_code == 202
