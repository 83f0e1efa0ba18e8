"""A lab of benches on one store (issue 21), in process on SQLite: bench identity in the settings,
the bench id on every row and the ``?bench_id=`` filters, recovery and cancel that never touch
another bench's jobs, the bench id claim, the heartbeat (and offline), and GET /api/lab/benches and
/api/lab/compare. Several services on one PostgreSQL: tests/system/test_lab_services.py."""

from __future__ import annotations

import os
import socket
import time
from datetime import UTC, datetime, timedelta

import pytest

from service.http.app import create_app
from service.runtime.heartbeat import (
    OFFLINE_AFTER_HEARTBEATS,
    BenchIdInUse,
    Heartbeat,
    age_s,
    claim,
    is_online,
    new_instance,
    register,
)
from service.runtime.jobs import JobManager, OtherBenchJob
from service.runtime.recovery import INTERRUPTED, recover
from service.runtime.settings import Settings, bench_id_for
from service.science.discovery.composite import as_composite
from service.science.discovery.parameters import physical_parameters
from service.store import Store
from service.usecases.identify import load_model
from tests.support.api_client import authed_client, wait_job


def _store(tmp_path, bench_id: str | None, subdir: str) -> Store:
    """A store on the lab's one database (tmp_path/lab.db) with its own data dir, as bench ``bench_id``."""
    store = Store(f"sqlite:///{tmp_path / 'lab.db'}", tmp_path / subdir)
    store.bench_id = bench_id
    return store


def _dataset(store: Store, name: str) -> dict:
    import numpy as np

    arrays = {"t_s": np.arange(4) / 10.0, "u_y_v": np.zeros(4), "x_y_um": np.zeros(4)}
    return store.add_dataset(arrays, {"name": name, "source": "import", "axes": ["y"], "sample_rate_hz": 10.0})


def _model(store: Store, datasets: list[str]) -> dict:
    return store.add_model({"axis": "y", "kind": "static_pi", "datasets": datasets, "parameters": {"model": "x"}})


def _settings(tmp_path, bench_id: str, **kw) -> Settings:
    return Settings(
        data_dir=tmp_path / bench_id,
        bench="default",
        bench_id=bench_id,
        database_url=f"sqlite:///{tmp_path / 'lab.db'}",
        **kw,
    )


def test_settings_derive_the_bench_id_and_public_url(monkeypatch):
    for name in ("EVCBENCH_BENCH_ID", "EVCBENCH_PUBLIC_URL", "EVCBENCH_HEARTBEAT_S"):
        monkeypatch.delenv(name, raising=False)
    s = Settings(bench="creep", host="10.0.0.5", port=8123)
    assert (s.bench_id, s.public_url, s.heartbeat_s) == ("creep", "http://10.0.0.5:8123", 5.0)
    assert bench_id_for("/etc/benches/Stage 2.toml") == "stage-2" and bench_id_for("default") == "default"
    assert Settings(bench_id="line-3", public_url="http://lab:9000/").public_url == "http://lab:9000"
    assert Settings(host="0.0.0.0", port=8001).public_url == f"http://{socket.gethostname()}:8001"
    monkeypatch.setenv("EVCBENCH_BENCH_ID", "from-env")
    monkeypatch.setenv("EVCBENCH_HEARTBEAT_S", "0.5")
    assert (Settings().bench_id, Settings().heartbeat_s) == ("from-env", 0.5)
    with pytest.raises(ValueError, match="bench_id"):
        Settings(bench_id="Bad Id!")


def test_rows_carry_their_bench_and_lists_filter_by_it(tmp_path):
    a, b = _store(tmp_path, "a", "va"), _store(tmp_path, "b", "vb")
    try:
        da, db = _dataset(a, "on a"), _dataset(b, "on b")
        assert (a.get_dataset(da["id"])["bench_id"], b.get_dataset(db["id"])["bench_id"]) == ("a", "b")
        # a model's bench is its datasets' (fitted anywhere); mixed datasets: the fitting service's
        assert _model(b, [da["id"]])["bench_id"] == "a"
        assert _model(a, [da["id"], db["id"]])["bench_id"] == "a" and _model(b, [da["id"], db["id"]])["bench_id"] == "b"
        job = b.add_job("sweep", {}, needs_bench=True)
        assert b.get_job(job["id"])["bench_id"] == "b"
        # each service lists everything; the filter narrows to one bench
        assert {d["id"] for d in a.list_datasets()} == {da["id"], db["id"]}
        assert [d["id"] for d in a.list_datasets("b")] == [db["id"]]
        assert len(a.list_models()) == 3 and len(a.list_models("a")) == 2
        assert [j["id"] for j in a.list_jobs(bench_id="b")] == [job["id"]] and a.list_jobs(bench_id="a") == []
    finally:
        a.close()
        b.close()


def test_recovery_fails_only_this_benchs_jobs(tmp_path):
    a, b = _store(tmp_path, "a", "va"), _store(tmp_path, "b", "vb")
    try:
        mine, theirs = a.add_job("sweep", {}, True), b.add_job("sweep", {}, True)
        a.bench_id = None
        legacy = a.add_job("sweep", {}, True)  # a row from before benches had ids
        a.bench_id = "a"
        for job in (mine, theirs, legacy):
            a.update_job(job["id"], state="running")
        register(b.benches, _settings(tmp_path, "b"), new_instance(), "busy")  # b's service is online
        assert sorted(recover(a)["failed_jobs"]) == sorted([mine["id"], legacy["id"]])
        assert a.get_job(mine["id"])["error"] == INTERRUPTED
        assert a.get_job(theirs["id"])["state"] == "running"
        # a store without a bench (store repair) leaves an online bench's jobs alone too ...
        a.bench_id = None
        assert recover(a)["failed_jobs"] == [] and a.get_job(theirs["id"])["state"] == "running"
        # ... and recovers them once that bench's service is gone
        b.benches.beat("b", b.benches.get("b")["instance"], state="stopped")
        assert recover(a)["failed_jobs"] == [theirs["id"]]
    finally:
        a.close()
        b.close()


def test_a_manager_never_cancels_another_benchs_job(tmp_path):
    a, b = _store(tmp_path, "a", "va"), _store(tmp_path, "b", "vb")
    register(b.benches, _settings(tmp_path, "b", public_url="http://bench-b:8000"), new_instance(), "busy")
    manager = JobManager(a)
    try:
        theirs = b.add_job("sweep", {}, True)
        with pytest.raises(OtherBenchJob) as caught:
            manager.cancel(theirs["id"])
        assert caught.value.url == "http://bench-b:8000" and "bench 'b'" in str(caught.value)
        assert b.get_job(theirs["id"])["state"] == "queued"
        assert manager.get(theirs["id"])["bench_id"] == "b"
        mine = manager.submit("compute", {}, lambda ctx: {"ok": 1}, needs_bench=False)
        assert wait_job(manager.get, mine["id"], timeout_s=30)["bench_id"] == "a"
    finally:
        manager.shutdown()
        a.close()
        b.close()


def test_a_bench_id_held_by_a_live_service_is_refused(tmp_path):
    store = _store(tmp_path, "a", "va")
    settings = _settings(tmp_path, "a")
    try:
        register(store.benches, settings, "elsewhere:4242:abcd", "idle")  # live, on another machine
        with pytest.raises(BenchIdInUse, match="held by a running service"):
            claim(store, settings, new_instance())
        # `evcbench serve` says it before uvicorn starts (exit 2), not inside a start-up traceback
        from service.frontends.cli_tokens import serve_refusal

        assert "bench id 'a' is held by a running service" in serve_refusal(settings)
        dead = _dead_pid()
        register(store.benches, settings, f"{socket.gethostname()}:{dead}:abcd", "busy")  # this host, crashed
        claim(store, settings, new_instance())
        assert store.benches.get("a")["state"] == "starting"
        register(store.benches, settings, "elsewhere:4242:abcd", "idle")
        stale = datetime.now(UTC) - timedelta(seconds=OFFLINE_AFTER_HEARTBEATS * settings.heartbeat_s + 1)
        store.benches.beat("a", "elsewhere:4242:abcd", heartbeat_at=stale.isoformat().replace("+00:00", "Z"))
        claim(store, settings, new_instance())  # silent: offline, taken over
    finally:
        store.close()


def _dead_pid() -> int:
    pid = os.getpid() + 100_000
    while True:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            pass
        pid += 1


def test_heartbeat_writes_state_and_stops(tmp_path):
    store = _store(tmp_path, "a", "va")
    settings = _settings(tmp_path, "a", heartbeat_s=0.05)
    instance = new_instance()
    try:
        register(store.benches, settings, instance, "idle")
        first = store.benches.get("a")["heartbeat_at"]
        beat = Heartbeat(settings.resolved_database_url, "a", instance, 0.05, lambda: ("busy", "job_x")).start()
        deadline = time.monotonic() + 30
        while beat.beats < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
        row = store.benches.get("a")
        assert beat.beats >= 3 and beat.failures == 0
        assert (row["state"], row["running_job_id"]) == ("busy", "job_x") and row["heartbeat_at"] > first
        assert is_online(row)
        beat.stop()
        row = store.benches.get("a")
        assert (row["state"], row["running_job_id"]) == ("stopped", None) and not is_online(row)
        later = datetime.now(UTC) + timedelta(seconds=OFFLINE_AFTER_HEARTBEATS * 0.05 + 0.01)
        assert not is_online({**row, "state": "idle"}, later)  # silent for 3 intervals
        # a database that cannot be written: the beat says so and raises nothing
        broken = Heartbeat(f"sqlite:///{tmp_path / 'missing' / 'x.db'}", "a", instance, 0.05, lambda: ("idle", None))
        assert broken.beat() is False and broken.failures == 1
    finally:
        store.close()


@pytest.mark.slow
def test_lab_routes_in_process(tmp_path, monkeypatch):
    """One service (the creep bench) and a second bench registered on its database that went silent."""
    monkeypatch.delenv("EVCBENCH_BENCH_ID", raising=False)
    app = create_app(
        Settings(data_dir=tmp_path / "creep", bench="creep", seed=1, database_url=f"sqlite:///{tmp_path / 'lab.db'}")
    )
    other = _store(tmp_path, "stage-2", "other")
    with authed_client(app) as http:
        job_of = lambda job_id: http.get(f"/api/jobs/{job_id}").json()  # noqa: E731
        sweep = wait_job(
            job_of,
            http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [10], "cycles": 4}).json()["job_id"],
            timeout_s=120,
        )
        assert sweep["state"] == "succeeded" and sweep["bench_id"] == "creep"
        dataset = sweep["result"]["dataset_id"]
        models = {}
        for effects in (["hysteresis"], ["hysteresis", "creep"]):
            job = wait_job(
                job_of,
                http.post("/api/models", json={"axis": "y", "datasets": [dataset], "effects": effects}).json()[
                    "job_id"
                ],
                timeout_s=300,
            )
            models[len(effects)] = job["result"]["model_id"]
        register(
            other.benches,
            Settings(bench="dynamics", bench_id="stage-2", public_url="http://b2:8000"),
            "elsewhere:1:x",
            "busy",
        )
        stale = datetime.now(UTC) - timedelta(seconds=60)
        other.benches.beat("stage-2", "elsewhere:1:x", heartbeat_at=stale.isoformat().replace("+00:00", "Z"))
        foreign = other.add_job("sweep", {}, True)

        lab = http.get("/api/lab/benches").json()
        assert lab["this_bench_id"] == "creep" and [b["id"] for b in lab["benches"]] == ["creep", "stage-2"]
        me, silent = lab["benches"]
        assert (me["online"], me["state"], me["name"], me["datasets"]) == (True, "idle", "creep", 1)
        assert me["latest_models"]["y"]["id"] == models[2] and me["latest_models"]["z"] is None
        stored = http.get(f"/api/models/{models[2]}").json()
        assert me["latest_models"]["y"]["validation_rms_um"] == stored["metrics"]["validation_rms_um"]
        assert me["latest_models"]["y"]["effects"] == ["hysteresis", "creep"]
        assert (silent["online"], silent["state"], silent["url"]) == (False, "busy", "http://b2:8000")
        assert silent["heartbeat_age_s"] >= 60 and silent["latest_models"] == {"y": None, "z": None}

        compared = http.get("/api/lab/compare", params={"axis": "y"}).json()
        row = next(b for b in compared["benches"] if b["id"] == "creep")
        expected = physical_parameters(as_composite(load_model(app.state.store.get_model(models[2]))))
        assert row["model"]["parameters"]["creep"] == pytest.approx(expected["creep"], rel=1e-12)
        assert 2.0 < row["model"]["parameters"]["creep"]["creep_pct_per_decade"] < 4.5  # the bench has 3 %/decade
        assert "creep.creep_pct_per_decade" in compared["parameter_names"]
        # every identified model knows its data's noise floor: the creep bench's gauge noise is nanometres,
        # and the refined model's held-out error is within a few times of it
        floor = row["model"]["noise_floor_um"]
        assert 0.0005 < floor < row["model"]["validation_rms_um"] < 10 * floor
        assert next(b for b in compared["benches"] if b["id"] == "stage-2")["model"] is None

        bad = http.get("/api/lab/compare", params={"axis": "x"})
        assert bad.status_code == 422 and bad.json()["field"] == "axis"
        assert http.get("/api/lab/compare").json()["field"] == "axis"
        assert [d["id"] for d in http.get("/api/datasets", params={"bench_id": "creep"}).json()] == [dataset]
        assert http.get("/api/datasets", params={"bench_id": "stage-2"}).json() == []
        assert http.get("/api/datasets", params={"bench_id": "Bad Id"}).json()["field"] == "bench_id"
        assert {m["bench_id"] for m in http.get("/api/models").json()} == {"creep"}
        refused = http.delete(f"/api/jobs/{foreign['id']}")
        assert refused.status_code == 409 and refused.json()["field"] == "job_id"
        assert refused.json()["url"] == "http://b2:8000" and other.get_job(foreign["id"])["state"] == "queued"
        # a model of another bench: its discovery may not run experiments on this bench's hardware
        theirs = _model(other, [])
        sent = http.post(f"/api/models/{theirs['id']}/discover", json={"allow_experiments": True})
        assert sent.status_code == 422 and sent.json()["field"] == "allow_experiments"
        assert "http://b2:8000" in sent.json()["detail"]
    assert app.state.store.benches.get("creep")["state"] == "stopped"  # a clean shut-down
    other.close()


@pytest.mark.parametrize("late_s", [0.0004, 0.0006, 0.2])
def test_an_offline_bench_never_reports_an_age_within_the_limit(late_s):
    """A bench offline after 3 silent heartbeats of 0.5 s reports an age above 1.5 s: the lab view's age
    is rounded to the ms and the online test read the unrounded one (1.5004 s: offline, shown as 1.5 s)."""
    now = datetime(2026, 12, 6, 12, 0, 0, tzinfo=UTC)
    limit_s = OFFLINE_AFTER_HEARTBEATS * 0.5
    row = {"state": "idle", "heartbeat_s": 0.5, "heartbeat_at": (now - timedelta(seconds=limit_s + late_s)).isoformat()}
    age = age_s(row, now)
    assert is_online(row, now) == (age <= limit_s)
    assert age == round(limit_s + late_s, 3)
