"""Crash safety (issue 9 §4): kill -9 the service during a sweep, restart it on the same store.

The bench is the default one with its DAQ paced to real time (fixtures/benches/default_realtime.toml),
so the sweep's samples take wall time and the number kept can be checked against the time it ran.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import httpx
import pytest

from tests.support.api_client import job_running, wait_job
from tests.support.live_server import ROOT, Server

SAMPLE_RATE_HZ = 20_000.0
CHUNK_S = 1.0  # service.store.chunks.CHUNK_S: at most this much is lost at a kill


def _store_check(data_dir, *flags) -> tuple[int, dict]:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "service.frontends.cli",
            "store",
            "check",
            "--data-dir",
            str(data_dir),
            "--json",
            *flags,
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    return proc.returncode, json.loads(proc.stdout)


@pytest.mark.realtime
def test_kill_9_during_a_sweep_keeps_the_samples_as_a_partial_dataset(tmp_path):
    data_dir = tmp_path / "store"
    server = Server(data_dir, tmp_path / "serve1.log", bench="default_realtime")
    try:
        with httpx.Client(base_url=server.url, timeout=30, headers=server.headers) as client:
            r = client.post(
                "/api/sweeps",
                json={"axes": ["y", "z"], "frequencies_hz": [1.0], "cycles": 30, "sample_rate_hz": SAMPLE_RATE_HZ},
            )
            assert r.status_code == 202, r.text
            job_id = r.json()["job_id"]
            assert r.json()["duration_s"] > 30
            wait_job(client, job_id, until=job_running(), timeout_s=60)
            started = time.monotonic()
            time.sleep(4.5)
            elapsed_s = time.monotonic() - started
            chunks = sorted((data_dir / "partial" / job_id).glob("chunk_*.npz"))
            assert len(chunks) >= 2, "a running sweep writes a chunk about every second"
            server.proc.kill()  # SIGKILL: no shut-down code runs
            server.proc.wait(timeout=30)
    finally:
        if server.proc.poll() is None:
            server.proc.kill()

    # Offline, before the restart, the check sees the job the dead process left running.
    code, report = _store_check(data_dir, "--offline")
    assert code == 1 and {p["kind"] for p in report["problems"]} == {"unfinished_job", "orphan_chunks"}

    server = Server(data_dir, tmp_path / "serve2.log", bench="default_realtime")
    try:
        with httpx.Client(base_url=server.url, timeout=30, headers=server.headers) as client:
            job = client.get(f"/api/jobs/{job_id}").json()
            assert job["state"] == "failed" and job["error"] == "interrupted by restart"
            dataset_id = job["result"]["dataset_id"]
            assert job["result"]["partial"] is True

            ds = client.get(f"/api/datasets/{dataset_id}").json()
            assert ds["partial"] is True and ds["partial_reason"] == "interrupted by restart"
            assert ds["job_id"] == job_id and ds["source"] == "sweep" and ds["axes"] == ["y", "z"]
            n = ds["samples"]
            # every whole second written before the kill is kept; at most the last chunk is lost
            assert SAMPLE_RATE_HZ * (elapsed_s - CHUNK_S - 1.0) <= n <= SAMPLE_RATE_HZ * (elapsed_s + 0.5), (
                n,
                elapsed_s,
            )
            assert all(block["complete"] is False for block in ds["blocks"])  # the one block was cut short

            data = client.get(f"/api/datasets/{dataset_id}/data", params={"max_points": n}).json()  # every sample
            t_s = data["t_s"]
            assert len(t_s) == n and t_s[0] == 0.0
            assert abs(t_s[-1] - (n - 1) / SAMPLE_RATE_HZ) < 1e-9  # no gap, no duplicate rows

            listed = [d for d in client.get("/api/datasets").json() if d["job_id"] == job_id]
            assert [(d["id"], d["partial"]) for d in listed] == [(dataset_id, True)]  # never shown complete
            assert not (data_dir / "partial" / job_id).exists()

            code, report = _store_check(data_dir)
            assert code == 0 and report["ok"], report
            assert report["counts"]["partial_datasets"] == 1
    finally:
        assert server.stop()
    code, report = _store_check(data_dir, "--offline")
    assert code == 0, report


def test_store_check_names_each_inconsistency_and_exits_1(tmp_path, capsys):
    import numpy as np

    from service.frontends.cli import main
    from service.store import Store
    from service.store.chunks import ChunkWriter

    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    meta = {"source": "import", "axes": ["y"], "sample_rate_hz": 10.0}
    kept = store.add_dataset({"t_s": np.arange(5.0)}, {**meta, "name": "kept"})
    lost = store.add_dataset({"t_s": np.arange(5.0)}, {**meta, "name": "lost"})
    assert main(["store", "check", "--data-dir", str(tmp_path), "--offline"]) == 0
    assert "consistent" in capsys.readouterr().out

    (tmp_path / lost["file"]).unlink()  # a row without its file
    (tmp_path / "arrays" / "ds_stray.npz").write_bytes(b"x")  # a file without its row
    (tmp_path / "arrays" / ".ds_half.123.tmp").write_bytes(b"x")  # an unfinished atomic write
    done = store.add_job("sweep", None, needs_bench=True)
    store.update_job(done["id"], state="succeeded", progress=0.5, result={"dataset_id": "ds_gone"})
    ChunkWriter(tmp_path, done["id"], meta).append({"t_s": np.arange(3.0)})  # chunks of a finished job
    store.close()

    assert main(["store", "check", "--data-dir", str(tmp_path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    found = {(p["kind"], p["id"]) for p in report["problems"]}
    assert found == {
        ("missing_array", lost["id"]),
        ("orphan_array", "ds_stray"),
        ("temp_file", ".ds_half.123.tmp"),
        ("orphan_chunks", done["id"]),
        ("impossible_job", done["id"]),
    }
    details = " ".join(p["detail"] for p in report["problems"] if p["kind"] == "impossible_job")
    assert "no finished_at" in details and "progress 0.50" in details and "ds_gone" in details
    assert kept["id"] not in {p["id"] for p in report["problems"]}


def test_chunks_are_a_gapless_prefix_and_recovery_rebuilds_a_trajectory_once(tmp_path):
    """A trajectory's chunks (u, x and the reference per axis) become one partial dataset with their
    units; a torn chunk (the temporary file of a write cut short) is ignored; a second recovery
    creates nothing more."""
    import numpy as np

    from service.runtime.recovery import INTERRUPTED, recover
    from service.store import Store
    from service.store.chunks import ChunkWriter, chunk_dir

    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    job = store.add_job("trajectory", {"frequency_hz": 100.0}, needs_bench=True)
    store.update_job(job["id"], state="running", started_at="2026-01-01T00:00:00Z")
    columns = ("u_y_v", "x_y_um", "ref_y_um", "u_z_v", "x_z_um", "ref_z_um")
    units = {"t_s": "s", **{c: c.rsplit("_", 1)[-1] for c in columns}}
    writer = ChunkWriter(
        tmp_path,
        job["id"],
        {
            "name": "ellipse",
            "source": "trajectory",
            "axes": ["y", "z"],
            "sample_rate_hz": 1000.0,
            "blocks": [],
            "units": units,
            "plan": {"frequency_hz": 100.0},
            "job_id": job["id"],
        },
    )
    for p in range(25):  # 25 periods of 100 samples at 1 kHz: two whole chunks and 500 rows pending
        rows = np.arange(p * 100, (p + 1) * 100)
        writer.append({"t_s": rows / 1000.0, **{c: rows * 1.0 for c in columns}})
    writer.flush()  # what a second more of running would have written ...
    (chunk_dir(tmp_path, job["id"]) / ".chunk_000004.abc.tmp").write_bytes(b"torn")  # ... and a write cut short
    assert writer.chunks == 3 and writer.rows_written == 2500

    report = recover(store)
    assert report["failed_jobs"] == [job["id"]] and len(report["datasets"]) == 1
    ds = store.get_dataset(report["datasets"][0])
    assert ds["partial"] and ds["partial_reason"] == INTERRUPTED and ds["samples"] == 2500
    assert ds["source"] == "trajectory" and ds["units"] == units
    arrays = store.load_arrays(ds["id"])
    np.testing.assert_array_equal(arrays["x_z_um"], np.arange(2500.0))  # in order, no gap, no repeat
    assert store.get_job(job["id"])["result"] == {"dataset_id": ds["id"], "samples": 2500, "partial": True}
    assert not chunk_dir(tmp_path, job["id"]).exists()
    [cleared] = report["cleaned"]  # the chunk directory, torn chunk included, is accounted for
    assert (cleared["kind"], cleared["path"], cleared["dataset"]) == ("chunks", f"partial/{job['id']}", ds["id"])
    assert cleared["bytes"] == report["freed_bytes"] > 2500 * 7 * 8
    assert recover(store) == {"failed_jobs": [], "datasets": [], "problems": [], "cleaned": [], "freed_bytes": 0}
    assert len(store.list_datasets()) == 1
    store.close()


def test_a_finished_sweep_leaves_no_chunks(tmp_path):
    from service.http.app import create_app
    from service.runtime.settings import Settings
    from tests.support.api_client import authed_client

    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=1))) as client:
        r = client.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [20.0], "cycles": 40})
        job_id = r.json()["job_id"]
        job = wait_job(client, job_id, poll_s=0.05)
        assert job["state"] == "succeeded" and job["result"]["partial"] is False
        assert client.get(f"/api/datasets/{job['result']['dataset_id']}").json()["partial"] is False
    assert not (tmp_path / "partial" / job_id).exists()
