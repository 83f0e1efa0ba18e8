"""Batch discovery (issue 21, service/lab/batch.py): one task per dataset and axis, in process or on
a Dask LocalCluster of two worker processes, with the same numbers either way; a worker killed
mid-batch loses no result; the hidden-effect benches' effects are named.

The store holds one short sweep (10 and 50 Hz, 4 cycles, both axes) of each of three emulated
benches: default, creep and dynamics (fixtures/benches), each dataset with its bench id.
"""

from __future__ import annotations

import json
import os
import pickle
import signal
import warnings
from pathlib import Path

import pytest

from service.frontends.cli import main as cli_main
from service.lab.address import StoreAddress, open_store
from service.lab.batch import batch_discover, comparable, discover_one, plan_batch
from service.lab.emulated import record_emulated_sweep
from service.science.errors import FieldError

BENCHES = ("default", "creep", "dynamics")


@pytest.fixture
def y_only(tmp_path):
    """A store with one short sweep that drives Y only of the default bench (bench id ``bench-a``)."""
    address = StoreAddress.of(None, tmp_path / "store")
    row = record_emulated_sweep(open_store(address), "default", 0, bench_id="bench-a", axes=("y",))
    return address, row


def test_a_dataset_the_worker_has_no_memory_for_is_skipped_saying_why(y_only, monkeypatch):
    from service.science.fitting import memory

    address, row = y_only
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: 10**6)  # 1 MB free
    out = discover_one(address, row["id"], "y")
    assert out["status"] == "skipped" and f"{row['samples']:,} samples" in out["reason"], out
    assert (
        "0.0 GB free" in out["reason"]
        and "GB a fit may use" in out["reason"]
        and open_store(address).list_models() == []
    )


def test_plan_skips_what_cannot_be_diagnosed_and_names_bad_fields(y_only):
    address, row = y_only
    plan = plan_batch(open_store(address))
    assert [(p["dataset_id"], p["axis"], p.get("status")) for p in plan] == [
        (row["id"], "y", None),
        (row["id"], "z", "skipped"),
    ]
    assert plan[1]["reason"] == "no block drives axis z"  # the bench records Z at 0 V
    assert {p["bench_id"] for p in plan} == {"bench-a"}
    with pytest.raises(FieldError) as bad_axis:
        plan_batch(open_store(address), axes=("x",))
    assert bad_axis.value.field == "axes"
    with pytest.raises(FieldError) as unknown:
        plan_batch(open_store(address), dataset_ids=["ds_nope"])
    assert unknown.value.field == "dataset_ids"
    assert pickle.loads(pickle.dumps(address)) == address  # what travels to a worker


def test_a_dataset_whose_arrays_fail_their_checksum_is_a_failed_row_and_the_batch_goes_on(y_only):
    address, row = y_only
    path = Path(address.data_dir) / row["file"]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    result = batch_discover(address)
    assert (result["ran"], result["ok"], result["skipped"], result["failed"]) == (1, 0, 1, 1)
    failed = result["results"][0]
    assert failed["status"] == "failed" and failed["error"].startswith("IntegrityError")
    assert open_store(address).get_dataset(row["id"])["sha256"] == row["sha256"]  # the row is as it was
    assert open_store(address).list_models() == []


def test_a_batch_cancelled_before_it_starts_runs_nothing(y_only):
    address, _ = y_only
    result = batch_discover(address, cancelled=lambda: True)
    assert (result["ran"], result["ok"], result["cancelled"], result["skipped"]) == (1, 0, 1, 1)
    assert open_store(address).list_models() == []


def test_the_config_file_for_workers_started_by_hand_says_what_the_local_cluster_uses():
    import yaml

    from service.lab.cluster import CONFIG_DIR, WORKER_CONFIG

    def flat(tree: dict, prefix: str = "") -> dict:
        out = {}
        for key, value in tree.items():
            out.update(flat(value, f"{prefix}{key}.") if isinstance(value, dict) else {prefix + key: value})
        return out

    assert flat(yaml.safe_load((CONFIG_DIR / "evcbench.yaml").read_text())) == WORKER_CONFIG


@pytest.mark.slow
def test_cli_batch_in_process_prints_a_row_per_dataset_and_axis(y_only, capsys):
    address, row = y_only
    code = cli_main(["lab", "batch", "--data-dir", address.data_dir, "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0
    assert (result["ran"], result["ok"], result["skipped"], result["failed"]) == (1, 1, 1, 0)
    y = result["results"][0]
    assert (y["bench_id"], y["dataset_id"], y["axis"], y["status"]) == ("bench-a", row["id"], "y", "ok")
    assert 0 < y["noise_floor_um"] < y["held_out_rms_um"] < 0.5  # µm: a fitted loop, above the gauge noise
    stored = open_store(address).get_model(y["model_id"])
    assert (stored["axis"], stored["datasets"], stored["bench_id"]) == ("y", [row["id"]], "bench-a")
    assert cli_main(["lab", "batch", "--data-dir", address.data_dir]) == 0
    text = capsys.readouterr().out
    assert "1 ok, 1 skipped, 0 failed" in text and "no block drives axis z" in text
    assert cli_main(["lab", "batch", "--data-dir", address.data_dir, "--local-workers", "0"]) == 2
    assert "local_workers" in capsys.readouterr().err


# ------------------------------------------------------------------ three benches, in process and on Dask


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The three benches' store and the in-process batch over it (one added effect at most)."""
    warnings.simplefilter("ignore")
    address = StoreAddress.of(None, tmp_path_factory.mktemp("lab") / "store")
    store = open_store(address)
    for seed, bench in enumerate(BENCHES):
        record_emulated_sweep(store, bench, seed, bench_id=f"bench-{bench}")
    return address, batch_discover(address, steps=1, continue_past_ambiguity=True)


@pytest.fixture(scope="module")
def client():
    from service.lab.cluster import dask_client

    with dask_client(local_workers=2) as c:
        yield c


def _by_bench(result: dict) -> dict:
    return {(r["bench_id"], r["axis"]): r for r in result["results"]}


@pytest.mark.slow
@pytest.mark.xdist_group("lab_batch")
def test_in_process_batch_names_the_hidden_effects(lab):
    address, result = lab
    assert (result["ran"], result["ok"], result["skipped"], result["failed"]) == (6, 6, 0, 0)
    rows = _by_bench(result)
    assert set(rows) == {(f"bench-{b}", a) for b in BENCHES for a in ("y", "z")}
    creep = rows[("bench-creep", "y")]
    assert creep["claimed_effects"][0] == "creep" and creep["effects_found"] == ["creep"]
    assert 2.0 < creep["physical_parameters"]["creep"]["creep_pct_per_decade"] < 4.0  # the bench's 3 %/decade
    assert creep["held_out_rms_after_um"] < 0.5 * creep["held_out_rms_um"]
    for axis, resonance_hz in (("y", 482.6), ("z", 290.7)):  # the flexure's
        dyn = rows[("bench-dynamics", axis)]
        assert dyn["claimed_effects"][0] == "dynamics" and dyn["effects_found"] == ["dynamics"]
        assert abs(dyn["physical_parameters"]["dynamics"]["resonance_hz"] / resonance_hz - 1) < 0.15
        assert dyn["held_out_rms_after_um"] < 0.6 * dyn["held_out_rms_um"]
    for r in result["results"]:
        assert 1e-3 < r["noise_floor_um"] < 1e-2  # the gauges' few nm
        assert "creep" not in r["effects_found"] or r["bench_id"] == "bench-creep"
    store = open_store(address)
    model = store.get_model(creep["final_model_id"])
    assert model["parent_id"] == creep["model_id"] and model["bench_id"] == "bench-creep"
    assert f"batch:{result['batch_id']}" in model["tags"]


@pytest.mark.slow
@pytest.mark.xdist_group("lab_batch")
def test_dask_batch_gives_the_in_process_results(lab, client):
    address, in_process = lab
    on_dask = batch_discover(address, steps=1, client=client, continue_past_ambiguity=True)
    assert on_dask["ok"] == 6
    assert comparable(on_dask["results"]) == comparable(in_process["results"])  # every number, exactly
    store = open_store(address)
    for mine, theirs in zip(on_dask["results"], in_process["results"]):
        assert mine["model_id"] != theirs["model_id"]  # stored again, by a worker
        assert (
            store.get_model(mine["final_model_id"])["parameters"]
            == store.get_model(theirs["final_model_id"])["parameters"]
        )


@pytest.mark.slow
@pytest.mark.xdist_group("lab_batch")
def test_cancel_stops_the_remaining_tasks(lab, client):
    address, in_process = lab
    flag = []
    result = batch_discover(
        address,
        steps=1,
        client=client,
        continue_past_ambiguity=True,
        on_result=lambda row, done, total: flag.append(done),
        cancelled=lambda: bool(flag),
    )
    assert result["ok"] >= 1 and result["cancelled"] >= 1 and result["ok"] + result["cancelled"] == 6
    assert result["failed"] == 0
    expected = {(r["dataset_id"], r["axis"]): r for r in comparable(in_process["results"])}
    for row in comparable(result["results"]):
        if row["status"] == "ok":
            assert row == expected[(row["dataset_id"], row["axis"])]
        else:
            assert set(row) == {"bench_id", "dataset_id", "dataset_name", "axis", "status"}


@pytest.mark.slow
@pytest.mark.xdist_group("lab_batch")
def test_a_worker_killed_mid_batch_loses_no_result(lab, client):
    address, in_process = lab
    killed = []

    def kill_a_busy_worker(row: dict, done: int, total: int) -> None:
        if killed:
            return
        busy = {addr: keys for addr, keys in client.processing().items() if keys}
        pids = client.run(os.getpid)
        victim = next(iter(busy))
        os.kill(pids[victim], signal.SIGKILL)
        killed.append({"worker": victim, "pid": pids[victim], "tasks": list(busy[victim]), "after": done})

    result = batch_discover(address, steps=1, client=client, continue_past_ambiguity=True, on_result=kill_a_busy_worker)
    assert len(killed) == 1 and killed[0]["tasks"] and killed[0]["after"] == 1
    assert (result["ok"], result["failed"]) == (6, 0)
    assert comparable(result["results"]) == comparable(in_process["results"])
    client.wait_for_workers(2, timeout=60)
    assert killed[0]["pid"] not in client.run(os.getpid).values()  # it did die; its nanny restarted it


@pytest.mark.slow
def test_workers_read_the_arrays_from_the_shared_s3_location(tmp_path, monkeypatch):
    """The arrays in an S3-compatible store (moto's server, tests/support/s3_server.py): with the local
    copies removed, the LocalCluster's workers fetch them and give the in-process numbers."""
    import shutil
    import uuid

    from service.lab.cluster import dask_client
    from service.store.placement import CACHE_DIR
    from tests.support.s3_server import s3_server

    with s3_server() as s3:
        for name, value in s3.env.items():  # the workers inherit this environment
            monkeypatch.setenv(name, value)
        bucket = s3.make_bucket(f"evc-{uuid.uuid4().hex[:12]}")
        address = StoreAddress.of(None, tmp_path / "store", f"s3://{bucket}/lab")
        row = record_emulated_sweep(open_store(address), "creep", 1, bench_id="bench-creep")
        keys = [o["Key"] for o in s3.client().list_objects_v2(Bucket=bucket).get("Contents", [])]
        assert any(row["id"] in key for key in keys)
        in_process = batch_discover(address, axes=("y",))
        shutil.rmtree(tmp_path / "store" / CACHE_DIR, ignore_errors=True)
        assert not list((tmp_path / "store").rglob(f"*{row['id']}*"))  # no local copy left anywhere
        with dask_client(local_workers=2) as client:
            on_dask = batch_discover(address, axes=("y",), client=client)
    assert (in_process["ok"], on_dask["ok"]) == (1, 1)
    assert comparable(on_dask["results"]) == comparable(in_process["results"])
    assert on_dask["results"][0]["claimed_effects"][0] == "creep"
