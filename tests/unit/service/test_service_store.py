"""The store on SQLite (WAL) and on a real PostgreSQL server: same behaviour, checksummed arrays,
atomic files, and nothing altered by a failed write."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import text, update

from service.runtime.recovery import INTERRUPTED, recover
from service.store import IntegrityError, NotFoundError, Store, tables
from service.store.files import file_sha256, open_arrays, read_arrays, write_arrays


def _open(backend: str, request, directory) -> Store:
    if backend == "sqlite":
        return Store(f"sqlite:///{directory}/evcbench.db", directory)
    return Store(request.getfixturevalue("postgres_url"), directory)


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def store(request, tmp_path):
    s = _open(request.param, request, tmp_path)
    yield s
    tables.metadata.drop_all(s.engine)  # the PostgreSQL database is shared by the session
    s.close()


def _arrays(n=500, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    return {"t_s": t, "u_y_v": 60 - 60 * np.cos(2 * np.pi * 5 * t), "x_y_um": rng.normal(size=n)}


META = {
    "name": "five hertz",
    "source": "sweep",
    "axes": ["y"],
    "sample_rate_hz": 1000.0,
    "blocks": [{"index": 0, "start": 0, "stop": 400, "kind": "sine", "frequency_hz": 5.0, "cycles": 2}],
    "plan": {"waveform": "sine", "frequencies_hz": [5.0]},
    "config": {"gain": 12.0, "nested": {"a": [1, 2]}},
    "units": {"t_s": "s"},
}


def test_dataset_round_trip_and_checksum(store):
    arrays = _arrays()
    row = store.add_dataset(arrays, META)
    again = store.get_dataset(row["id"])
    assert again == row
    assert (again["samples"], again["blocks"], again["config"]) == (500, META["blocks"], META["config"])
    loaded = store.load_arrays(row["id"])
    assert set(loaded) == set(arrays)
    for name in arrays:
        np.testing.assert_array_equal(loaded[name], arrays[name])
    assert [d["id"] for d in store.list_datasets()] == [row["id"]]
    with pytest.raises(NotFoundError) as info:
        store.get_dataset("ds_missing")
    assert info.value.field == "dataset"


def test_corrupt_array_file_is_reported_by_name(store):
    row = store.add_dataset(_arrays(), META)
    path = store.data_dir / row["file"]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(IntegrityError, match=row["id"]):
        store.load_arrays(row["id"])


def test_failed_insert_leaves_no_file_and_no_row(store):
    good = store.add_dataset(_arrays(), META)
    files_before = sorted(p.name for p in store.arrays_dir.iterdir())
    with pytest.raises(Exception):  # noqa: B017 - SQLite and PostgreSQL raise their own kinds
        store.add_dataset(_arrays(seed=1), {**META, "axes": None, "units": None, "name": None, "source": None})
    assert sorted(p.name for p in store.arrays_dir.iterdir()) == files_before
    assert [d["id"] for d in store.list_datasets()] == [good["id"]]
    np.testing.assert_array_equal(store.load_arrays(good["id"])["x_y_um"], _arrays()["x_y_um"])


def test_models_keep_exact_floats_and_detect_tampering(store):
    parameters = {
        "model": "static_pi",
        "weights_um_per_v": [0.1 + 0.2, 1e-17, 123456.789012345678],
        "offset_um": float("nan"),
    }
    row = store.add_model(
        {
            "axis": "y",
            "kind": "static_pi",
            "effects": ["hysteresis"],
            "datasets": ["ds_a"],
            "parameters": parameters,
            "metrics": {"train_rms_um": 0.01, "fit_pct": float("inf")},
        }
    )
    got = store.get_model(row["id"])
    assert got["parameters"]["weights_um_per_v"] == [0.1 + 0.2, 1e-17, 123456.789012345678]
    assert got["parameters"]["offset_um"] is None and got["metrics"]["fit_pct"] is None  # NaN/inf → null
    assert got == row
    with store.engine.begin() as conn:
        conn.execute(
            update(tables.models)
            .where(tables.models.c.id == row["id"])
            .values(parameters={**got["parameters"], "offset_um": 1.0})
        )
    with pytest.raises(IntegrityError, match=row["id"]):
        store.get_model(row["id"])


def test_jobs_life_cycle_and_restart_recovery(store):
    a = store.add_job("sweep", {"cycles": 5}, needs_bench=True)
    b = store.add_job("identify", None, needs_bench=False)
    store.update_job(a["id"], state="running", progress=0.5, message="half", started_at="2026-01-01T00:00:00Z")
    store.update_job(b["id"], state="succeeded", progress=1.0, result={"model_id": "md_x", "rms_um": np.float64(0.5)})
    assert store.get_job(a["id"])["progress"] == 0.5
    assert store.get_job(b["id"])["result"] == {"model_id": "md_x", "rms_um": 0.5}
    assert [j["id"] for j in store.list_jobs()] == [b["id"], a["id"]]  # newest first
    assert recover(store)["failed_jobs"] == [a["id"]]  # the start-up recovery (service.runtime.recovery)
    assert store.get_job(a["id"])["state"] == "failed" and store.get_job(a["id"])["error"] == INTERRUPTED
    assert store.get_job(b["id"])["state"] == "succeeded"


def test_reopened_store_returns_identical_records(store, request, tmp_path):
    row = store.add_dataset(_arrays(), META)
    url = store.engine.url.render_as_string(hide_password=False)
    reopened = Store(url, tmp_path)
    try:
        assert reopened.get_dataset(row["id"]) == row
        np.testing.assert_array_equal(reopened.load_arrays(row["id"])["u_y_v"], _arrays()["u_y_v"])
    finally:
        reopened.close()


def test_sqlite_runs_in_wal_mode(tmp_path):
    s = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    with s.engine.connect() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"
    s.close()


@pytest.mark.postgres
def test_both_backends_store_the_same_records(request, tmp_path):
    """The same writes on SQLite and PostgreSQL read back identically (ids and times aside)."""
    results = []
    for backend in ("sqlite", "postgresql"):
        s = _open(backend, request, tmp_path / backend)
        try:
            d = s.add_dataset(_arrays(), META)
            m = s.add_model(
                {
                    "axis": "z",
                    "kind": "grpi",
                    "effects": ["hysteresis"],
                    "datasets": [d["id"]],
                    "parameters": {"a1": 1.0 / 3.0, "w": [0.25, 2.0**-40]},
                    "metrics": {},
                }
            )
            j = s.add_job("sweep", {"axes": ["y", "z"]}, needs_bench=True)
            s.update_job(j["id"], state="cancelled", result={"dataset_id": d["id"], "partial": True})
            rows = [s.get_dataset(d["id"]), s.get_model(m["id"]), s.get_job(j["id"])]
            results.append(
                [
                    {k: v for k, v in r.items() if k not in ("id", "created_at", "file", "datasets", "result")}
                    for r in rows
                ]
            )
            results[-1].append(s.get_job(j["id"])["result"]["partial"])
        finally:
            tables.metadata.drop_all(s.engine)
            s.close()
    assert results[0] == results[1]


def test_array_files_are_written_atomically(tmp_path):
    path, digest = write_arrays(tmp_path, "ds_x", _arrays())
    assert [p.name for p in tmp_path.iterdir()] == ["ds_x.npz"]  # no temp file left behind
    assert read_arrays(path, digest)["t_s"].shape == (500,)
    with pytest.raises(IntegrityError, match="ds_x.npz"):
        read_arrays(path, "0" * 64)


@pytest.mark.parametrize("legacy", [False, True], ids=["uncompressed", "compressed-before-streaming"])
def test_arrays_open_lazily_memory_mapped_or_a_range_at_a_time(tmp_path, legacy):
    arrays = _arrays(n=300_001)
    if legacy:  # a file written before the store wrote uncompressed members
        path = tmp_path / "old.npz"
        np.savez_compressed(path, **arrays)
        digest = file_sha256(path)
    else:
        path, digest = write_arrays(tmp_path, "ds_new", arrays)
    with open_arrays(path, digest) as stored:
        assert stored.names == list(arrays) and stored.length == 300_001
        assert isinstance(stored.column("u_y_v"), np.memmap) is not legacy
        for start, stop, step in [(0, 10, 1), (5, 300_001, 7), (1000, 299_999, 200_000), (299_990, 10**6, 1)]:
            for name, values in stored.rows(start, stop, step).items():
                np.testing.assert_array_equal(values, arrays[name][start:stop:step])
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(IntegrityError, match="corrupt"):
        open_arrays(path, digest)


@pytest.mark.postgres
def test_the_service_runs_on_postgresql(postgres_url, tmp_path):
    """The whole service with its metadata in PostgreSQL: a sweep (with its nested bench
    configuration), an identification, and a restart that finds both unchanged."""
    from service.frontends.client import Client
    from service.http.app import create_app
    from service.runtime.settings import Settings
    from tests.support.api_client import authed_client

    settings = Settings(data_dir=tmp_path, bench="default", seed=1, database_url=postgres_url)
    try:
        with authed_client(create_app(settings)) as http:
            api = Client(http=http)
            assert api.health()["store"] == "postgresql"
            dataset_id = api.sweep(axes=["z"], frequencies_hz=[20, 80], cycles=3)["result"]["dataset_id"]
            model = api.identify("z", [dataset_id], model="dynamic_pi")
            before = (api.dataset(dataset_id), model, api.compare(model["id"], dataset_id, arrays=False))
        with authed_client(create_app(settings)) as http:
            api = Client(http=http)
            after = (
                api.dataset(dataset_id),
                api.model(model["id"]),
                api.compare(model["id"], dataset_id, arrays=False),
            )
        assert after == before
        assert before[0]["config"]["parameters"]["axes"]["z"]["amplifier"]["gain_v_per_v"] > 0
    finally:
        s = Store(postgres_url, tmp_path)
        tables.metadata.drop_all(s.engine)
        s.close()
