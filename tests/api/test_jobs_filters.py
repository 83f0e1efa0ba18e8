"""GET /api/jobs?kind=&model_id=&state=: one model's discover runs without every job's result, the
running jobs however old (the Bench page lists them first: a walk's discover dropped off the newest ten),
and a 422 naming the field for a value outside them."""

from __future__ import annotations

from service.http.app import create_app
from service.runtime.settings import Settings
from service.store import utc_now
from tests.support.api_client import authed_client


def _job(store, kind: str, params: dict, result: dict | None, state: str = "succeeded") -> str:
    job = store.add_job(kind, params, needs_bench=False)
    store.update_job(job["id"], state=state, result=result, finished_at=utc_now())
    return job["id"]


def test_jobs_filter_by_kind_and_by_the_model_they_start_from_or_end_at(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=0))
    with authed_client(app) as client:
        store = app.state.store
        from_a = _job(store, "discover", {"model_id": "mdl_a"}, {"steps": [], "final_model_id": "mdl_b"})
        to_a = _job(store, "discover", {"model_id": "mdl_c"}, {"steps": [], "final_model_id": "mdl_a"})
        refine_a = _job(store, "refine", {"model_id": "mdl_a"}, {"model_id": "mdl_d"})
        other = _job(store, "discover", {"model_id": "mdl_e"}, {"steps": [], "final_model_id": "mdl_f"})
        sweep = _job(store, "sweep", {"axis": "y"}, {"dataset_id": "ds_x"})

        ids = lambda query: {j["id"] for j in client.get(f"/api/jobs{query}").json()}  # noqa: E731
        assert ids("") == {from_a, to_a, refine_a, other, sweep}
        assert ids("?kind=discover") == {from_a, to_a, other}
        assert ids("?model_id=mdl_a") == {from_a, to_a, refine_a}
        assert ids("?kind=discover&model_id=mdl_a") == {from_a, to_a}
        assert ids("?kind=discover&model_id=mdl_b") == {from_a}  # the run that ended at mdl_b
        assert ids("?kind=sweep&model_id=mdl_a") == set()
        newest = client.get("/api/jobs?kind=discover&model_id=mdl_a&limit=1").json()
        assert [j["id"] for j in newest] == [to_a]  # newest first

        assert ids("?state=succeeded") == {from_a, to_a, refine_a, other, sweep} and ids("?state=running") == set()

        for query, field in (
            ("?kind=fit", "kind"),
            ("?model_id=a%20b", "model_id"),
            ("?model_id=", "model_id"),
            ("?state=done", "state"),
        ):
            answer = client.get(f"/api/jobs{query}")
            assert answer.status_code == 422 and answer.json()["field"] == field, (query, answer.json())
        assert len(client.get("/api/jobs").json()) == 5  # nothing was lost


def test_the_running_jobs_are_listed_however_old(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=0))
    with authed_client(app) as client:
        store = app.state.store
        old_run = _job(store, "discover", {"model_id": "mdl_a"}, None, state="running")
        newer = [_job(store, "sweep", {"axis": "y"}, {"dataset_id": f"ds_{k}"}) for k in range(10)]
        assert old_run not in {j["id"] for j in client.get("/api/jobs?limit=10").json()}
        running = client.get("/api/jobs?state=running&limit=20").json()
        assert [j["id"] for j in running] == [old_run] and running[0]["state"] == "running"
        assert {j["id"] for j in client.get("/api/jobs?state=succeeded&limit=20").json()} == set(newer)
