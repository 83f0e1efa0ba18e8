"""Arrays every service of a lab can read (issue 21): a shared directory or an S3-compatible store.

The object store is real: moto's server mode on a loopback port (tests/support/s3_server.py), reached over
HTTP through boto3 like any S3 endpoint, stopped and started again to play an outage. The two
"services" of the concurrency test are two processes with their own data dirs, one database and one
array location between them."""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import numpy as np
import pytest

from service.runtime.repair import repair_store
from service.store import ArrayStoreUnavailable, IntegrityError, Store, placement
from service.store.check import check_store

ROOT = Path(__file__).resolve().parents[3]
META = {"source": "import", "axes": ["y"], "sample_rate_hz": 1000.0}


@pytest.fixture(scope="module")
def s3():
    """One S3-compatible server for the module (each test makes its own bucket)."""
    from tests.support.s3_server import S3Server

    server = S3Server()
    server.start()
    yield server
    server.stop()


@pytest.fixture
def bucket_url(s3, monkeypatch):
    """``s3://<fresh bucket>/lab``, with the endpoint and credentials in this process's environment."""
    for name, value in s3.env.items():
        monkeypatch.setenv(name, value)
    name = s3.make_bucket(f"evc-{uuid.uuid4().hex[:12]}")
    return f"s3://{name}/lab"


def _arrays(seed: int, n: int = 20_000) -> dict[str, np.ndarray]:
    """A dataset's columns, different for every seed (so a mix-up between datasets shows)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    return {"t_s": t, "u_y_v": 60 + 50 * np.sin(2 * np.pi * t) + rng.normal(0, 0.1, n), "x_y_um": rng.normal(0, 1, n)}


def _store(tmp_path: Path, name: str, array_url: str, db: str | None = None) -> Store:
    return Store(db or f"sqlite:///{tmp_path}/lab.db", tmp_path / name, array_url=array_url)


def _bucket(url: str) -> str:
    return url[len("s3://") :].split("/", 1)[0]


def _object_sha256(s3, url: str, key: str) -> str:
    bucket, prefix = url[len("s3://") :].split("/", 1)
    body = s3.client().get_object(Bucket=bucket, Key=f"{prefix}/{key}")["Body"].read()
    return hashlib.sha256(body).hexdigest()


def test_a_dataset_round_trips_through_s3_with_its_checksum(tmp_path, s3, bucket_url, monkeypatch):
    writer, reader = _store(tmp_path, "bench-a", bucket_url), _store(tmp_path, "bench-b", bucket_url)
    arrays = _arrays(1)
    row = writer.add_dataset(arrays, META)
    assert row["file"] == f"{row['id']}.npz"  # a key relative to the location
    assert _object_sha256(s3, bucket_url, row["file"]) == row["sha256"]
    assert not any((tmp_path / "bench-a" / "outbox").glob("*.npz"))  # the upload's file became the cache
    loaded = reader.load_arrays(row["id"])  # another service: downloaded, verified
    for name, values in arrays.items():
        np.testing.assert_array_equal(loaded[name], values)
    cached = tmp_path / "bench-b" / "cache" / "arrays" / f"{row['sha256']}.npz"
    assert hashlib.sha256(cached.read_bytes()).hexdigest() == row["sha256"]
    with reader.open_arrays(row["id"]) as stored:  # memory-mapped columns, range reads
        np.testing.assert_array_equal(stored.rows(1000, 1010)["x_y_um"], arrays["x_y_um"][1000:1010])
    cached.write_bytes(b"bit rot")  # a damaged cache entry is fetched again
    np.testing.assert_array_equal(reader.load_arrays(row["id"])["u_y_v"], arrays["u_y_v"])
    assert hashlib.sha256(cached.read_bytes()).hexdigest() == row["sha256"]
    second = writer.add_dataset(_arrays(5), META)
    monkeypatch.setenv("EVCBENCH_ARRAY_CACHE_BYTES", str(cached.stat().st_size))  # room for one copy
    np.testing.assert_array_equal(reader.load_arrays(second["id"])["x_y_um"], _arrays(5)["x_y_um"])
    assert [p.name for p in cached.parent.glob("*.npz")] == [f"{second['sha256']}.npz"]  # the older one went
    np.testing.assert_array_equal(reader.load_arrays(row["id"])["x_y_um"], arrays["x_y_um"])  # fetched again
    size = cached.stat().st_size
    assert reader.delete_dataset(row["id"])["freed_bytes"] == size
    listing = s3.client().list_objects_v2(Bucket=_bucket(bucket_url), Prefix="lab/")
    assert [o["Key"] for o in listing["Contents"]] == [f"lab/{second['id']}.npz"]  # delete removed the object
    assert not cached.exists()  # and the local copy
    writer.close(), reader.close()


WRITER = textwrap.dedent("""
    import json, sys
    from tests.unit.service.test_lab_arrays import _arrays
    from service.store import Store
    import pathlib, time
    database_url, data_dir, array_url, first, count = sys.argv[1:6]
    store = Store(database_url, data_dir, array_url=array_url)
    ready = pathlib.Path(data_dir).parent / "ready"
    ready.mkdir(exist_ok=True)
    (ready / first).touch()
    while len(list(ready.iterdir())) < 2:     # both services write at the same time
        time.sleep(0.01)
    rows = [store.add_dataset(_arrays(seed), {"source": "import", "axes": ["y"], "sample_rate_hz": 1000.0,
                                              "name": f"seed-{seed}"})
            for seed in range(int(first), int(first) + int(count))]
    print(json.dumps({r["name"]: [r["id"], r["sha256"]] for r in rows}))
""")


def _two_services_write_at_once(tmp_path: Path, database_url: str, array_url: str, env: dict, per_service: int):
    """Two processes (services a and b, own data dirs) each store ``per_service`` datasets at the same
    time into one database and one array location; every dataset is then read back by the other."""
    import os

    Store(database_url, tmp_path / "setup").close()  # the tables exist before the services start
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WRITER, database_url, str(tmp_path / name), array_url, str(first), str(per_service)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **env, "PYTHONPATH": str(ROOT)},
        )
        for name, first in (("a", 0), ("b", 1000))
    ]
    written = []
    for proc in procs:
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        written.append(json.loads(out))
    stores = {name: Store(database_url, tmp_path / name, array_url=array_url) for name in ("a", "b")}
    try:
        rows = stores["a"].list_datasets()
        assert len(rows) == 2 * per_service
        times = [sorted(r["created_at"] for r in rows if r["id"] in {i for i, _ in w.values()}) for w in written]
        assert times[0][0] < times[1][-1] and times[1][0] < times[0][-1]  # the writes interleaved
        for reader, rows in (("b", written[0]), ("a", written[1])):  # each reads the other's
            for name, (dataset_id, sha256) in rows.items():
                expected = _arrays(int(name.split("-")[1]))
                loaded = stores[reader].load_arrays(dataset_id)
                assert stores[reader].get_dataset(dataset_id)["sha256"] == sha256
                assert all(np.array_equal(loaded[k], v) for k, v in expected.items()), name
        for store in stores.values():
            report = check_store(store)
            assert report["ok"], report["problems"]
    finally:
        for store in stores.values():
            store.close()
    return written


@pytest.mark.slow
def test_two_services_share_one_bucket_and_one_database(tmp_path, s3, bucket_url):
    written = _two_services_write_at_once(tmp_path, f"sqlite:///{tmp_path}/lab.db", bucket_url, s3.env, 12)
    keys = s3.client().list_objects_v2(Bucket=_bucket(bucket_url), Prefix="lab/")["KeyCount"]
    assert keys == 24 and len({i for rows in written for i, _ in rows.values()}) == 24


@pytest.mark.slow
def test_two_services_share_one_directory(tmp_path):
    shared = tmp_path / "nfs" / "arrays"
    shared.mkdir(parents=True)
    _two_services_write_at_once(tmp_path, f"sqlite:///{tmp_path}/lab.db", f"file://{shared}", {}, 12)
    assert len(list(shared.glob("ds_*.npz"))) == 24 and not list(shared.glob(".*.tmp"))


@pytest.mark.slow
@pytest.mark.postgres
def test_two_services_share_postgresql_and_one_bucket(tmp_path, s3, bucket_url, postgres_url):
    from service.store import tables

    try:
        _two_services_write_at_once(tmp_path, postgres_url, bucket_url, s3.env, 8)
    finally:
        store = Store(postgres_url, tmp_path / "cleanup")
        tables.metadata.drop_all(store.engine)  # the PostgreSQL database is shared by the session
        store.close()


def test_an_unmounted_share_is_refused_not_filled_on_local_disk(tmp_path):
    store = Store(f"sqlite:///{tmp_path}/db.sqlite", tmp_path / "svc", array_url=str(tmp_path / "not-mounted"))
    with pytest.raises(ArrayStoreUnavailable, match="not-mounted is unavailable: the directory does not exist"):
        store.add_dataset(_arrays(2), META)
    assert store.list_datasets() == [] and not list((tmp_path / "svc").rglob("*.npz"))
    row = store.add_dataset(_arrays(2), {**META, "source": "sweep"}, keep_if_unreachable=True)
    assert row["file"] == f"outbox/{row['id']}.npz"  # a measurement waits on local disk
    waiting, unreachable = check_store(store)["problems"]
    assert (waiting["kind"], waiting["id"]) == ("pending_upload", row["id"])
    assert (unreachable["kind"], unreachable["id"]) == ("array_store_unavailable", str(tmp_path / "not-mounted"))
    (tmp_path / "not-mounted").mkdir()  # the share is mounted
    repaired = repair_store(store)  # as the next start-up would, uploads it
    assert {
        "kind": "pending_upload",
        "id": row["id"],
        "action": f"uploaded from the outbox as {row['id']}.npz",
    } in repaired["actions"] and repaired["after"]["ok"]
    assert store.get_dataset(row["id"])["file"] == f"{row['id']}.npz"
    assert not list((tmp_path / "svc" / "outbox").glob("*.npz"))
    np.testing.assert_array_equal(store.load_arrays(row["id"])["x_y_um"], _arrays(2)["x_y_um"])
    assert check_store(store)["ok"]
    store.close()


def _sweep(http) -> dict:
    from tests.support.api_client import wait_job

    r = http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [10], "cycles": 2})
    assert r.status_code == 202, r.text
    return wait_job(http, r.json()["job_id"])


def _csv(seed: int) -> bytes:
    arrays = _arrays(seed, n=2000)
    rows = np.column_stack([arrays["t_s"], arrays["u_y_v"], arrays["x_y_um"]])
    text = io.StringIO()
    np.savetxt(text, rows, delimiter=",", header="t,u_y,x_y", comments="", fmt="%.9g")
    return text.getvalue().encode()


@pytest.mark.slow
def test_the_store_going_away_gives_503_naming_it_and_loses_nothing(tmp_path, s3, bucket_url):
    from service.http.app import create_app
    from service.runtime.settings import Settings
    from tests.support.api_client import authed_client

    db = f"sqlite:///{tmp_path}/lab.db"
    apps = [
        create_app(Settings(data_dir=tmp_path / name, database_url=db, seed=0, array_url=bucket_url))
        for name in ("bench-a", "bench-b")
    ]
    with authed_client(apps[0]) as a, authed_client(apps[1]) as b:
        imported = a.post("/api/datasets", files={"file": ("one.csv", _csv(1))}).json()["id"]
        swept = _sweep(a)["result"]["dataset_id"]
        before = {i: a.get(f"/api/datasets/{i}").json()["sha256"] for i in (imported, swept)}
        data = {i: b.get(f"/api/datasets/{i}/data?format=csv").content for i in (imported, swept)}
        for sha256 in before.values():  # b has them in its cache now; a new reader has not
            (tmp_path / "bench-b" / "cache" / "arrays" / f"{sha256}.npz").unlink()
        s3.stop()
        try:
            r = b.get(f"/api/datasets/{imported}/data?format=csv")
            assert r.status_code == 503 and r.headers["retry-after"] == "30"
            assert r.json()["array_store"] == bucket_url
            assert r.json()["detail"].startswith(f"array store {bucket_url} is unavailable: reading {imported}.npz")
            count = len(a.get("/api/datasets").json())
            r = a.post("/api/datasets", files={"file": ("two.csv", _csv(2))})  # an import: refused whole
            assert r.status_code == 503 and bucket_url in r.json()["detail"]
            assert len(a.get("/api/datasets").json()) == count
            assert not list((tmp_path / "bench-a" / "outbox").glob("*"))
            r = a.delete(f"/api/datasets/{imported}")  # a delete: refused whole
            assert r.status_code == 503 and a.get(f"/api/datasets/{imported}").status_code == 200
            job = _sweep(a)  # a sweep: kept on a's disk, said so
            assert job["state"] == "succeeded"
            waiting = job["result"]["dataset_id"]
            assert any("wait on this service's disk" in w and bucket_url in w for w in job["result"]["warnings"])
            assert a.get(f"/api/datasets/{waiting}").json()["file"] == f"outbox/{waiting}.npz"
            assert a.get(f"/api/datasets/{waiting}/data?format=csv").status_code == 200  # a reads its own
            r = b.get(f"/api/datasets/{waiting}/data?format=csv")
            assert r.status_code == 503 and "still in the outbox of the service that recorded it" in r.json()["detail"]
            pending = [p for p in check_store(apps[0].state.store)["problems"] if p["kind"] == "pending_upload"]
            assert [p["id"] for p in pending] == [waiting]
        finally:
            s3.start()
        for i, sha256 in before.items():  # everything stored before is intact
            assert b.get(f"/api/datasets/{i}").json()["sha256"] == sha256
            assert b.get(f"/api/datasets/{i}/data?format=csv").content == data[i]
            assert _object_sha256(s3, bucket_url, f"{i}.npz") == sha256
        assert a.post("/api/datasets", files={"file": ("two.csv", _csv(2))}).status_code == 201  # flushes the outbox
        row = a.get(f"/api/datasets/{waiting}").json()
        assert row["file"] == f"{waiting}.npz" and _object_sha256(s3, bucket_url, row["file"]) == row["sha256"]
        assert b.get(f"/api/datasets/{waiting}/data?format=csv").status_code == 200
        for app in apps:
            report = check_store(app.state.store)
            assert report["ok"], report["problems"]
        rows = a.get("/api/datasets").json()
        listing = s3.client().list_objects_v2(Bucket=_bucket(bucket_url), Prefix="lab/")
        assert len(rows) == 4 and listing["KeyCount"] == 4  # nothing half-stored, nothing left behind


def test_check_finds_a_corrupted_object_and_repair_sets_it_aside(tmp_path, s3, bucket_url):
    store = _store(tmp_path, "bench-a", bucket_url)
    good, bad, lost = (store.add_dataset(_arrays(seed), META) for seed in (1, 2, 3))
    bucket, key = _bucket(bucket_url), f"lab/{bad['id']}.npz"
    s3.client().put_object(Bucket=bucket, Key=key, Body=b"PK not the dataset any more")  # replaced behind our back
    report = check_store(store)
    assert [(p["kind"], p["id"]) for p in report["problems"]] == [("corrupt_array", bad["id"])]
    assert f"{bucket_url}/{bad['id']}.npz does not match its sha256" in report["problems"][0]["detail"]
    assert check_store(store, quick=True)["ok"]  # quick: the object exists
    reader = _store(tmp_path, "bench-b", bucket_url)
    with pytest.raises(IntegrityError, match="is corrupt: sha256"):
        reader.load_arrays(bad["id"])
    np.testing.assert_array_equal(reader.load_arrays(good["id"])["u_y_v"], _arrays(1)["u_y_v"])
    for gone in (good, lost):  # the store lost two objects
        s3.client().delete_object(Bucket=bucket, Key=f"lab/{gone['id']}.npz")
    (store.data_dir / placement.CACHE_DIR / f"{lost['sha256']}.npz").unlink()  # of one, no cached copy is left
    assert {(p["kind"], p["id"]) for p in check_store(store)["problems"]} == {
        ("corrupt_array", bad["id"]),
        ("missing_array", good["id"]),
        ("missing_array", lost["id"]),
    }
    result = repair_store(store)
    # the object of which this service holds a verified copy is put back; the others are kept, in quarantine
    assert result["after"]["ok"] and {q["id"] for q in result["after"]["quarantined"]} == {lost["id"], bad["id"]}
    assert _object_sha256(s3, bucket_url, f"{good['id']}.npz") == good["sha256"]
    assert any(
        "from this service's verified cache copy" in a["action"] for a in result["actions"] if a["id"] == good["id"]
    )
    aside = s3.client().get_object(Bucket=bucket, Key=f"lab/quarantine/{bad['id']}.npz")["Body"].read()
    assert aside == b"PK not the dataset any more"  # kept for inspection, not deleted
    assert len(store.list_datasets()) == 3  # no row is ever deleted
    reader.close(), store.close()


def test_an_old_object_no_row_names_is_listed_and_set_aside(tmp_path, s3, bucket_url, monkeypatch):
    from service.store import placement

    store = _store(tmp_path, "bench-a", bucket_url)
    row = store.add_dataset(_arrays(1), META)
    s3.client().put_object(Bucket=_bucket(bucket_url), Key="lab/ds_stray.npz", Body=b"x" * 100)
    assert check_store(store)["ok"]  # young: maybe another service's upload in flight
    monkeypatch.setattr(placement, "ORPHAN_GRACE_S", -1.0)
    [problem] = check_store(store)["problems"]
    assert problem == {
        "kind": "orphan_array",
        "id": "ds_stray",
        "detail": f"{bucket_url}/ds_stray.npz belongs to no dataset (100 B)",
    }
    assert repair_store(store)["after"]["ok"]
    keys = {o["Key"] for o in s3.client().list_objects_v2(Bucket=_bucket(bucket_url))["Contents"]}
    assert keys == {f"lab/{row['id']}.npz", "lab/quarantine/ds_stray.npz"}
    store.close()


def test_store_check_on_the_command_line_reads_the_shared_location(tmp_path, s3, bucket_url, capsys):
    from service.frontends.cli import main

    store = _store(tmp_path, "bench-a", bucket_url)
    row = store.add_dataset(_arrays(1), META)
    store.close()
    args = [
        "store",
        "check",
        "--data-dir",
        str(tmp_path / "bench-a"),
        "--database-url",
        f"sqlite:///{tmp_path}/lab.db",
        "--array-url",
        bucket_url,
        "--json",
    ]
    assert main(args) == 0 and json.loads(capsys.readouterr().out)["counts"]["datasets"] == 1
    s3.client().delete_object(Bucket=_bucket(bucket_url), Key=f"lab/{row['id']}.npz")
    assert main(args) == 1
    assert json.loads(capsys.readouterr().out)["problems"][0]["kind"] == "missing_array"


def test_chunks_of_a_killed_sweep_are_kept_when_the_store_is_down_at_restart(tmp_path, s3, bucket_url):
    """Start-up recovery rebuilds an interrupted acquisition into the outbox while S3 is away, and
    the next start-up (S3 back) uploads it: the samples are never only in memory or lost."""
    from service.runtime.recovery import recover
    from service.store.chunks import ChunkWriter, chunk_dir

    data_dir = tmp_path / "bench-a"
    store = _store(tmp_path, "bench-a", bucket_url)
    job = store.add_job("sweep", {}, needs_bench=True)
    store.update_job(job["id"], state="running", started_at="2026-01-01T00:00:00Z")
    writer = ChunkWriter(
        data_dir,
        job["id"],
        {
            "name": "sweep",
            "source": "sweep",
            "axes": ["y"],
            "sample_rate_hz": 1000.0,
            "blocks": [],
            "job_id": job["id"],
        },
    )
    rows = np.arange(3000)
    writer.append({"t_s": rows / 1000.0, "u_y_v": rows * 0.01, "x_y_um": rows * 0.001})
    writer.flush()
    store.close()  # the service was killed here
    s3.stop()
    try:
        restarted = _store(tmp_path, "bench-a", bucket_url)
        report = recover(restarted)
        [dataset_id] = report["datasets"]
        assert report["uploaded"] == [] and any(bucket_url in p for p in report["problems"])
        assert restarted.get_dataset(dataset_id)["file"] == f"outbox/{dataset_id}.npz"
        assert not chunk_dir(data_dir, job["id"]).exists()  # the chunks are in the outbox file now
        np.testing.assert_array_equal(restarted.load_arrays(dataset_id)["x_y_um"], rows * 0.001)
        restarted.close()
    finally:
        s3.start()
    again = _store(tmp_path, "bench-a", bucket_url)
    report = recover(again)
    assert [u["id"] for u in report["uploaded"]] == [dataset_id]
    row = again.get_dataset(dataset_id)
    assert row["file"] == f"{dataset_id}.npz" and _object_sha256(s3, bucket_url, row["file"]) == row["sha256"]
    other = _store(tmp_path, "bench-b", bucket_url)
    np.testing.assert_array_equal(other.load_arrays(dataset_id)["u_y_v"], rows * 0.01)
    assert check_store(again)["ok"]
    again.close(), other.close()
