"""Keeping the store tidy (issue 20 §4): datasets and models renamed, tagged, annotated and deleted;
a record others derive from is refused with 409 naming them unless ``cascade``; deletion removes
the arrays and leaves ``evcbench store check`` clean; an older database gains the new columns."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from sqlalchemy import Column, MetaData, Table, insert, inspect

from service.http.app import create_app
from service.runtime.settings import Settings
from service.store import Store, tables
from service.store.check import check_store
from service.store.schema import ADDED_COLUMNS
from service.store.tidy import InUseError
from tests.support.api_client import authed_client, wait_job


def _open(backend: str, request, directory) -> Store:
    if backend == "sqlite":
        return Store(f"sqlite:///{directory}/evcbench.db", directory)
    return Store(request.getfixturevalue("postgres_url"), directory)


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def backend(request):
    return request.param


@pytest.fixture
def store(backend, request, tmp_path):
    s = _open(backend, request, tmp_path)
    yield s
    tables.metadata.drop_all(s.engine)  # the PostgreSQL database is shared by the session
    s.close()


META = {
    "name": "five hertz",
    "source": "sweep",
    "axes": ["y"],
    "sample_rate_hz": 1000.0,
    "blocks": [{"index": 0, "start": 0, "stop": 400, "kind": "sine", "frequency_hz": 5.0, "cycles": 2}],
}


def _dataset(store: Store, job_id: str | None = None) -> dict:
    t = np.arange(500) / 1000.0
    return store.add_dataset(
        {"t_s": t, "u_y_v": 60 - 60 * np.cos(2 * np.pi * 5 * t), "x_y_um": 0.05 * t}, {**META, "job_id": job_id}
    )


def _model(store: Store, datasets: list[str], parent_id: str | None = None) -> str:
    return store.add_model(
        {
            "axis": "y",
            "kind": "static_pi",
            "effects": ["hysteresis"],
            "parent_id": parent_id,
            "datasets": datasets,
            "parameters": {"model": "static_pi", "w": [0.1]},
            "metrics": {},
        }
    )["id"]


def test_labels_are_set_kept_and_cleared(store):
    ds = _dataset(store)
    assert ds["tags"] == [] and ds["notes"] is None
    row = store.label_dataset(ds["id"], name="Y 10–100 Hz", tags=["calibration", "2026"], notes="after re-gluing")
    assert (row["name"], row["tags"], row["notes"]) == ("Y 10–100 Hz", ["calibration", "2026"], "after re-gluing")
    assert store.label_dataset(ds["id"], notes=None)["notes"] is None
    assert store.get_dataset(ds["id"])["tags"] == ["calibration", "2026"]
    model_id = _model(store, [ds["id"]])
    before = store.get_model(model_id)
    assert before["name"] is None and before["tags"] == []
    after = store.label_model(model_id, name="creep found", tags=["discovery"])
    assert (after["name"], after["tags"]) == ("creep found", ["discovery"])
    assert after["parameters_sha256"] == before["parameters_sha256"]  # the parameters never change


def test_a_used_dataset_and_a_parent_model_are_refused_then_cascaded(store):
    sweep_job = store.add_job("sweep", {}, needs_bench=True)
    ds = _dataset(store, job_id=sweep_job["id"])
    store.update_job(
        sweep_job["id"],
        state="succeeded",
        progress=1.0,
        finished_at=sweep_job["created_at"],
        result={"dataset_id": ds["id"]},
    )
    other = _dataset(store)
    root = _model(store, [ds["id"]])
    child = _model(store, [ds["id"]], parent_id=root)
    grandchild = _model(store, [ds["id"]], parent_id=child)
    elsewhere = _model(store, [other["id"]])

    with pytest.raises(InUseError) as refused:
        store.delete_dataset(ds["id"])
    assert refused.value.dependents == {"models": [root, child, grandchild]}
    assert all(m in str(refused.value) for m in (root, child, grandchild))
    with pytest.raises(InUseError) as refused:
        store.delete_model(child)
    assert refused.value.dependents == {"models": [grandchild]}
    assert len(store.list_models()) == 4 and (store.data_dir / ds["file"]).is_file()  # nothing deleted

    assert store.delete_model(child, cascade=True) == {"datasets": [], "models": [child, grandchild], "freed_bytes": 0}
    size = (store.data_dir / ds["file"]).stat().st_size
    gone = store.delete_dataset(ds["id"], cascade=True)
    assert gone == {"datasets": [ds["id"]], "models": [root], "freed_bytes": size}
    assert not (store.data_dir / ds["file"]).exists()
    assert [m["id"] for m in store.list_models()] == [elsewhere]
    assert [d["id"] for d in store.list_datasets()] == [other["id"]]
    result = store.get_job(sweep_job["id"])["result"]
    assert result == {"dataset_id": None, "deleted_dataset_id": ds["id"]}
    report = check_store(store, offline=True)
    assert report["ok"], report["problems"]

    assert store.delete_model(elsewhere)["models"] == [elsewhere]
    assert store.delete_dataset(other["id"])["datasets"] == [other["id"]]
    assert check_store(store, offline=True)["ok"] and not list((store.data_dir / "arrays").glob("*"))


def test_an_older_database_gains_the_new_columns(backend, request, tmp_path):
    """A database written before the labels existed: opening it adds the columns (ALTER TABLE on
    SQLite and PostgreSQL alike), and its rows read as unlabelled."""
    url = f"sqlite:///{tmp_path}/evcbench.db" if backend == "sqlite" else request.getfixturevalue("postgres_url")
    first = Store(url, tmp_path)
    tables.metadata.drop_all(first.engine)
    old = MetaData()
    for name in ("datasets", "models"):
        Table(
            name,
            old,
            *[
                Column(c.name, c.type, primary_key=c.primary_key, nullable=c.nullable)
                for c in tables.metadata.tables[name].columns
                if c.name not in ADDED_COLUMNS[name]
            ],
        )
    old.create_all(first.engine)
    row = {c.name: None for c in old.tables["datasets"].columns}
    row.update(
        id="ds_old",
        name="old",
        source="import",
        axes=["y"],
        samples=0,
        sample_rate_hz=1.0,
        blocks=[],
        units={},
        software_version="0",
        partial=False,
        file="arrays/ds_old.npz",
        sha256="0" * 64,
        created_at="2026-01-01T00:00:00Z",
    )
    with first.engine.begin() as conn:
        conn.execute(insert(old.tables["datasets"]).values(**row))
    first.close()

    upgraded = Store(url, tmp_path)
    try:
        inspector = inspect(upgraded.engine)
        for name, added in ADDED_COLUMNS.items():
            assert set(added) <= {c["name"] for c in inspector.get_columns(name)}
        ds = upgraded.get_dataset("ds_old")
        assert ds["tags"] == [] and ds["notes"] is None
        assert upgraded.label_dataset("ds_old", tags=["legacy"])["tags"] == ["legacy"]
        Store(url, tmp_path).close()  # a second opening finds nothing to add
    finally:
        tables.metadata.drop_all(upgraded.engine)
        upgraded.close()


@pytest.fixture
def http(tmp_path):
    warnings.simplefilter("ignore")
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=0))) as client:
        yield client


def _ok(http, job_id) -> dict:
    job = wait_job(http, job_id)
    assert job["state"] == "succeeded", job
    return job["result"]


def test_rename_tag_annotate_and_delete_over_rest(http):
    r = http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [10, 100], "cycles": 3})
    dataset_id = _ok(http, r.json()["job_id"])["dataset_id"]
    r = http.post("/api/models", json={"axis": "y", "datasets": [dataset_id]})
    parent = _ok(http, r.json()["job_id"])["model_id"]
    r = http.post(f"/api/models/{parent}/refine", json={"effects": ["hysteresis"]})
    child = _ok(http, r.json()["job_id"])["model_id"]

    r = http.patch(
        f"/api/datasets/{dataset_id}", json={"name": "Y quick", "tags": ["demo", "demo", " y "], "notes": "3 cycles"}
    )
    assert r.status_code == 200, r.text
    assert (r.json()["name"], r.json()["tags"], r.json()["notes"]) == ("Y quick", ["demo", "y"], "3 cycles")
    r = http.patch(f"/api/datasets/{dataset_id}", json={"name": None})
    assert r.status_code == 422 and r.json()["field"] == "name"
    listed = {d["id"]: d for d in http.get("/api/datasets").json()}
    assert listed[dataset_id]["tags"] == ["demo", "y"]
    r = http.patch(f"/api/models/{parent}", json={"name": "base", "notes": "PI only"})
    assert r.status_code == 200 and r.json()["name"] == "base" and r.json()["tags"] == []
    assert http.patch(f"/api/models/{parent}", json={"name": None}).json()["name"] is None  # a model's may go
    for body, field in (
        ({"colour": "red"}, "colour"),
        ({"tags": "demo"}, "tags"),
        ({"tags": [""]}, "tags"),
        ({"name": ""}, "name"),
    ):
        r = http.patch(f"/api/models/{parent}", json=body)
        assert r.status_code == 422 and r.json()["field"] == field, (body, r.text)
    assert http.patch("/api/models/md_nope", json={"name": "x"}).status_code == 404

    reader = authed_client(http.app, scope="read")
    assert reader.delete(f"/api/models/{child}").status_code == 403
    assert reader.patch(f"/api/datasets/{dataset_id}", json={"name": "x"}).status_code == 403

    r = http.delete(f"/api/datasets/{dataset_id}")
    assert r.status_code == 409 and r.json()["field"] == "cascade"
    assert r.json()["dependents"] == {"models": [parent, child]} and parent in r.json()["detail"]
    r = http.delete(f"/api/models/{parent}")
    assert r.status_code == 409 and r.json()["dependents"] == {"models": [child]} and child in r.json()["detail"]
    assert http.get(f"/api/models/{child}").status_code == 200

    r = http.delete(f"/api/datasets/{dataset_id}", params={"cascade": "true"})
    assert r.status_code == 200, r.text
    assert r.json()["datasets"] == [dataset_id] and r.json()["models"] == [parent, child]
    assert r.json()["freed_bytes"] > 0
    assert http.get(f"/api/datasets/{dataset_id}").status_code == 404
    assert http.get(f"/api/models/{child}").status_code == 404
    store = http.app.state.store
    report = check_store(store)
    assert report["ok"], report["problems"]
    assert not list((store.data_dir / "arrays").glob("*"))
