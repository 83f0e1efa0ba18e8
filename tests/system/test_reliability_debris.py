"""Crash debris (issue 15): what a kill -9 leaves in the data dir is cleared by start-up recovery and
by ``evcbench store repair``, and a completed dataset always survives byte for byte.

The kills are real: a child process writes through the store and is SIGKILLed by a hook at the
chosen point of the atomic write (mid-write: the zip not finished; or after the rename, before the
row), so the debris is exactly what the writer leaves."""

from __future__ import annotations

import hashlib
import json
import logging
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from service.frontends.cli import main
from service.runtime.recovery import recover
from service.store import Store
from service.store.chunks import ChunkWriter, chunk_dir
from service.store.lock import StoreLock

ROOT = Path(__file__).resolve().parents[2]
META = {"source": "import", "axes": ["y"], "sample_rate_hz": 1000.0}
ROWS = 400_000  # three float64 columns: 9.6 MB of array, as a real import

#: A child that stores one dataset and is SIGKILLed at ``stage``: "mid_write" (the array's zip is
#: written but not finished, nothing renamed) or "before_row" (renamed into arrays/, no row yet).
KILL_SCRIPT = textwrap.dedent("""
    import os, signal, sys, zipfile
    import numpy as np
    from service.store import Store, files

    data_dir, stage, rows = sys.argv[1], sys.argv[2], int(sys.argv[3])
    def die(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGKILL)
    if stage == "mid_write":
        zipfile.ZipFile._write_end_record = die
    else:
        files._fsync_dir = die
    store = Store(f"sqlite:///{data_dir}/evcbench.db", data_dir)
    t = np.arange(rows) / 1000.0
    store.add_dataset({"t_s": t, "u_y_v": 60 + 50 * np.sin(t), "x_y_um": np.cos(t)},
                      {"source": "import", "axes": ["y"], "sample_rate_hz": 1000.0, "name": "killed"})
""")


def _kill_during_write(data_dir: Path, stage: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", KILL_SCRIPT, str(data_dir), stage, str(ROWS)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == -9, proc.stderr  # SIGKILL: no clean-up code ran


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check(data_dir: Path, capsys, *flags: str) -> tuple[int, dict]:
    code = main(["store", "check", "--data-dir", str(data_dir), "--json", *flags])
    return code, json.loads(capsys.readouterr().out)


def _crashed_store(data_dir: Path) -> dict:
    """A store with one completed import, one finished sweep whose chunk directory stayed behind
    (killed between storing its dataset and removing its chunks), then two kills during imports."""
    store = Store(f"sqlite:///{data_dir}/evcbench.db", data_dir)
    rng = np.random.default_rng(1)
    arrays = {"t_s": np.arange(5000) / 1000.0, "u_y_v": rng.uniform(0, 120, 5000), "x_y_um": rng.normal(size=5000)}
    kept = store.add_dataset(arrays, {**META, "name": "completed"})
    job = store.add_job("sweep", None, needs_bench=True)
    writer = ChunkWriter(data_dir, job["id"], {**META, "source": "sweep", "name": "sweep"})
    writer.append({k: v[:3000] for k, v in arrays.items()})
    writer.flush()
    (chunk_dir(data_dir, job["id"]) / ".chunk_000004.x1y2.tmp").write_bytes(b"torn")
    swept = store.add_dataset(arrays, {**META, "source": "sweep", "name": "sweep", "job_id": job["id"]})
    store.update_job(
        job["id"],
        state="succeeded",
        progress=1.0,
        finished_at="2026-01-01T00:00:01Z",
        result={"dataset_id": swept["id"]},
    )
    store.close()
    _kill_during_write(data_dir, "mid_write")
    _kill_during_write(data_dir, "before_row")
    temps = list((data_dir / "arrays").glob(".ds_*.tmp"))
    assert len(temps) == 1 and temps[0].stat().st_size > 0.9 * ROWS * 3 * 8  # the half-written array
    return {
        "kept": kept,
        "swept": swept,
        "job": job,
        "arrays": arrays,
        "temp": temps[0],
        "files": {row["id"]: _sha256(data_dir / row["file"]) for row in (kept, swept)},
    }


def _assert_datasets_intact(data_dir: Path, crash: dict) -> None:
    store = Store(f"sqlite:///{data_dir}/evcbench.db", data_dir)
    try:
        for row in (crash["kept"], crash["swept"]):
            stored_sha = store.get_dataset(row["id"])["sha256"]
            assert _sha256(data_dir / row["file"]) == crash["files"][row["id"]] == stored_sha
        loaded = store.load_arrays(crash["kept"]["id"])
        for name, values in crash["arrays"].items():
            np.testing.assert_array_equal(loaded[name], values)
    finally:
        store.close()


def test_start_up_recovery_clears_kill_9_debris_and_keeps_completed_datasets(tmp_path, capsys, caplog):
    crash = _crashed_store(tmp_path)
    code, report = _check(tmp_path, capsys)
    assert code == 1
    assert sorted(p["kind"] for p in report["problems"]) == ["orphan_array", "orphan_chunks", "temp_file"]

    temp_bytes = crash["temp"].stat().st_size
    chunk_bytes = sum(p.stat().st_size for p in chunk_dir(tmp_path, crash["job"]["id"]).iterdir())
    [orphan] = [p for p in (tmp_path / "arrays").glob("ds_*.npz") if p.stem not in crash["files"]]
    orphan_sha = _sha256(orphan)
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    with caplog.at_level(logging.WARNING, logger="evcbench.recovery"):
        recovered = recover(store)  # what the app runs at start-up
    store.close()
    done = {(a["action"], a["kind"], a["path"]): a for a in recovered["cleaned"]}
    assert set(done) == {
        ("delete", "temp_file", f"arrays/{crash['temp'].name}"),
        ("quarantine", "orphan_array", f"arrays/{orphan.name}"),
        ("delete", "chunks", f"partial/{crash['job']['id']}"),
    }
    assert all(a["done"] for a in recovered["cleaned"])
    assert recovered["freed_bytes"] == temp_bytes + chunk_bytes
    assert recovered["datasets"] == [] and recovered["failed_jobs"] == []  # the sweep had its dataset
    assert done[("delete", "chunks", f"partial/{crash['job']['id']}")]["dataset"] == crash["swept"]["id"]
    logged = caplog.text
    assert f"arrays/{crash['temp'].name}: deleted ({temp_bytes / 1e6:.1f} MB)" in logged
    assert f"arrays/{orphan.name}: moved aside to quarantine/arrays/{orphan.name}" in logged
    assert "freed" in logged

    assert not crash["temp"].exists() and not chunk_dir(tmp_path, crash["job"]["id"]).exists()
    assert _sha256(tmp_path / "quarantine" / "arrays" / orphan.name) == orphan_sha  # kept, not deleted
    code, report = _check(tmp_path, capsys, "--offline")
    assert code == 0 and report["problems"] == [] and report["counts"]["quarantine_files"] == 1
    _assert_datasets_intact(tmp_path, crash)


def test_store_repair_fixes_what_check_finds_without_losing_a_dataset(tmp_path, capsys):
    crash = _crashed_store(tmp_path)
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    rng = np.random.default_rng(2)
    lost = store.add_dataset({"t_s": np.arange(100.0), "u_y_v": rng.uniform(0, 120, 100)}, {**META, "name": "lost"})
    bad = store.add_dataset({"t_s": np.arange(100.0), "u_y_v": rng.uniform(0, 120, 100)}, {**META, "name": "bad"})
    odd = store.add_job("identify", None, needs_bench=False)
    store.update_job(odd["id"], state="failed")  # no error, no finished_at
    model = store.add_model({"axis": "y", "kind": "static_pi", "datasets": ["ds_gone"], "parameters": {"w": [1.0]}})
    store.close()
    (tmp_path / lost["file"]).unlink()
    good_bytes = (tmp_path / bad["file"]).read_bytes()
    (tmp_path / bad["file"]).write_bytes(good_bytes[:-1] + bytes([good_bytes[-1] ^ 0xFF]))
    temp_bytes = crash["temp"].stat().st_size
    code, report = _check(tmp_path, capsys, "--offline")
    kinds = sorted(p["kind"] for p in report["problems"])
    assert code == 1 and kinds == [
        "corrupt_array",
        "dangling_reference",
        "impossible_job",
        "impossible_job",
        "missing_array",
        "orphan_array",
        "orphan_chunks",
        "temp_file",
    ]

    # --dry-run says what it would do and changes nothing
    assert main(["store", "repair", "--data-dir", str(tmp_path), "--dry-run", "--json"]) == 0
    planned = json.loads(capsys.readouterr().out)
    assert planned["dry_run"] and {a["kind"] for a in planned["actions"]} == {
        "temp_file",
        "orphan_array",
        "orphan_chunks",
        "corrupt_array",
        "missing_array",
        "impossible_job",
        "dangling_reference",
    }
    assert _check(tmp_path, capsys, "--offline") == (code, report)

    # refused while another process owns the data dir (the running service holds this lock)
    lock = StoreLock(tmp_path)
    assert lock.acquire()
    try:
        assert main(["store", "repair", "--data-dir", str(tmp_path)]) == 2
        assert "stop the service first" in capsys.readouterr().err
    finally:
        lock.release()

    assert main(["store", "repair", "--data-dir", str(tmp_path), "--json"]) == 0
    repaired = json.loads(capsys.readouterr().out)
    after = repaired["after"]
    assert after["ok"] and after["problems"] == []
    assert repaired["freed_bytes"] >= temp_bytes and not crash["temp"].exists()
    assert {(q["kind"], q["id"]) for q in after["quarantined"]} == {
        ("missing_array", lost["id"]),
        ("corrupt_array", bad["id"]),
        ("dangling_reference", model["id"]),
    }
    assert (after["counts"]["datasets"], after["counts"]["models"]) == (4, 1)  # no row was deleted
    moved = tmp_path / "quarantine" / "arrays" / Path(bad["file"]).name
    assert moved.read_bytes()[:-1] == good_bytes[:-1]  # the damaged file is kept aside
    assert main(["store", "check", "--data-dir", str(tmp_path), "--offline"]) == 0
    text = capsys.readouterr().out
    assert "consistent" in text and "3 record(s) in quarantine" in text and lost["id"] in text
    _assert_datasets_intact(tmp_path, crash)
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    job = store.get_job(odd["id"])
    store.close()
    assert job["error"] and job["finished_at"]

    # the right file put back: the next repair lifts the quarantine
    (tmp_path / bad["file"]).write_bytes(good_bytes)
    code, report = _check(tmp_path, capsys, "--offline")
    assert code == 0 and [q["resolved"] for q in report["quarantined"] if q["id"] == bad["id"]] == [True]
    assert main(["store", "repair", "--data-dir", str(tmp_path), "--json"]) == 0
    repaired = json.loads(capsys.readouterr().out)
    assert {q["id"] for q in repaired["after"]["quarantined"]} == {lost["id"], model["id"]}
    assert any(a["action"].startswith("lifted") and a["id"] == bad["id"] for a in repaired["actions"])


def test_a_store_opened_with_the_wrong_database_loses_no_array(tmp_path, capsys):
    """Every array looks orphaned to another database: recovery moves them aside, never deletes
    them, and the next start on the right database moves them back."""
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    rows = [store.add_dataset({"t_s": np.arange(50.0) + k}, {**META, "name": f"d{k}"}) for k in range(3)]
    store.close()
    shas = {row["id"]: _sha256(tmp_path / row["file"]) for row in rows}

    wrong = Store(f"sqlite:///{tmp_path}/other.db", tmp_path)
    moved = recover(wrong)["cleaned"]
    wrong.close()
    assert sorted(a["action"] for a in moved) == ["quarantine"] * 3
    right = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    restored = recover(right)["cleaned"]
    right.close()
    assert sorted((a["action"], a["id"]) for a in restored) == sorted(("restore", i) for i in shas)
    assert {row["id"]: _sha256(tmp_path / row["file"]) for row in rows} == shas
    code, report = _check(tmp_path, capsys)
    assert code == 0 and report["counts"]["quarantine_files"] == 0


@pytest.mark.realtime
def test_kill_9_of_the_service_mid_import_is_clean_after_the_next_start(tmp_path, monkeypatch):
    """A real ``evcbench serve``: an import is SIGKILLed while its array file is being written (a
    start-up hook holds the write there); the next start clears the temporary file and logs it."""
    import threading

    import httpx

    from tests.support.live_server import Server

    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(
        textwrap.dedent("""
        import os, time, zipfile
        MARKER = os.environ.get("EVC_TEST_STALL_MARKER")
        if MARKER:
            finish = zipfile.ZipFile._write_end_record
            def stall(self):  # a big array of an import, all members written: hold it here
                path = os.readlink(f"/proc/self/fd/{self.fp.fileno()}")
                if "/arrays/.ds_" in path and self.fp.tell() > 1_000_000:
                    self.fp.flush()
                    open(MARKER, "w").write(path)
                    time.sleep(600)
                return finish(self)
            zipfile.ZipFile._write_end_record = stall
    """)
    )
    marker, data_dir = tmp_path / "stalled", tmp_path / "store"
    monkeypatch.setenv("PYTHONPATH", f"{hook}:{ROOT}")
    monkeypatch.setenv("EVC_TEST_STALL_MARKER", str(marker))
    t = np.arange(100_000) / 1000.0
    small = "t,u_y,x_y\n" + "\n".join(f"{a:.3f},{60 + 50 * np.sin(a):.4f},{np.cos(a):.4f}" for a in t[:2000])
    big = "t,u_y,x_y\n" + "\n".join(f"{a:.3f},{60 + 50 * np.sin(a):.4f},{np.cos(a):.4f}" for a in t)

    server = Server(data_dir, tmp_path / "serve1.log")
    try:
        with httpx.Client(base_url=server.url, timeout=120, headers=server.headers) as client:
            r = client.post("/api/datasets", files={"file": ("small.csv", small)}, data={"name": "completed"})
            assert r.status_code == 201, r.text
            kept = r.json()["id"]
            kept_file = data_dir / client.get(f"/api/datasets/{kept}").json()["file"]
            kept_sha = _sha256(kept_file)
            killed = threading.Thread(target=lambda: _post_quietly(client, big), daemon=True)
            killed.start()
            deadline = time.monotonic() + 120
            while not marker.exists():
                assert time.monotonic() < deadline, "the import never reached its array write"
                time.sleep(0.05)
            server.proc.kill()  # SIGKILL mid-write
            server.proc.wait(timeout=30)
    finally:
        if server.proc.poll() is None:
            server.proc.kill()
    temps = list((data_dir / "arrays").glob(".ds_*.tmp"))
    assert len(temps) == 1 and temps[0].stat().st_size > 1_000_000, (temps, (tmp_path / "serve1.log").read_text())
    size_mb = temps[0].stat().st_size / 1e6
    code = subprocess.run(
        [sys.executable, "-m", "service.frontends.cli", "store", "check", "--data-dir", str(data_dir), "--offline"],
        cwd=ROOT,
        capture_output=True,
        timeout=120,
    ).returncode
    assert code == 1

    monkeypatch.delenv("EVC_TEST_STALL_MARKER")
    server = Server(data_dir, tmp_path / "serve2.log")
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "service.frontends.cli", "store", "check", "--data-dir", str(data_dir), "--json"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stdout + (tmp_path / "serve2.log").read_text()
        assert not temps[0].exists() and _sha256(kept_file) == kept_sha
        busy = subprocess.run(
            [sys.executable, "-m", "service.frontends.cli", "store", "repair", "--data-dir", str(data_dir)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert busy.returncode == 2 and "stop the service first" in busy.stderr  # the service holds the store
        with httpx.Client(base_url=server.url, timeout=60, headers=server.headers) as client:
            assert [d["id"] for d in client.get("/api/datasets").json()] == [kept]
            assert len(client.get(f"/api/datasets/{kept}/data").json()["t_s"]) == 2000
    finally:
        assert server.stop()
    log = (tmp_path / "serve2.log").read_text()
    assert f"recovery: arrays/{temps[0].name}: deleted ({size_mb:.1f} MB)" in log


def _post_quietly(client, text: str) -> None:
    try:
        client.post("/api/datasets", files={"file": ("big.csv", text)}, data={"name": "killed"})
    except Exception:  # noqa: BLE001 - the server dies under it
        pass


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
