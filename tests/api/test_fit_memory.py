"""A fit or diagnosis whose records would need more memory than the machine has free is refused
before it starts (422 naming the field, with the figures), instead of the kernel killing the
service mid-job; nothing stored changes. The per-sample estimate bounds a real diagnosis's peak."""

from __future__ import annotations

import tracemalloc
import warnings

import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from service.science.discovery.diagnosis import diagnose
from service.science.fitting import memory
from service.science.fitting.memory import available_memory_bytes, fit_memory_bytes, memory_shortfall
from tests.support.api_client import authed_client, wait_job

SWEEP = {"axes": ["y"], "frequencies_hz": [10, 100], "cycles": 4}


def test_shortfall_names_the_samples_the_need_and_what_is_free():
    assert memory_shortfall(1_000_000, available_bytes=8 * 10**9) is None  # 6.2 GB of 8 GB
    text = memory_shortfall(10_000_000, available_bytes=8 * 10**9)  # 62 GB of 8 GB
    assert "10,000,000 samples" in text and "about 62.0 GB" in text
    assert "the 6.4 GB a fit may use (80 % of the 8.0 GB free" in text
    # the usable share: 4.96 GB wanted of 5 GB free is more than the 4 GB (80 %) a fit may use
    assert memory_shortfall(800_000, available_bytes=5 * 10**9) is not None
    assert memory_shortfall(600_000, available_bytes=5 * 10**9) is None  # 3.72 GB


def test_available_memory_is_read_from_meminfo(tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24000000 kB\nMemFree:         1000000 kB\nMemAvailable:   20000000 kB\n")
    assert available_memory_bytes(str(meminfo)) == 20000000 * 1024
    meminfo.write_text("MemTotal:       24000000 kB\n")
    assert available_memory_bytes(str(meminfo)) is None
    assert available_memory_bytes(str(tmp_path / "absent")) is None


def test_requests_that_would_exhaust_memory_are_refused_naming_the_field(tmp_path, monkeypatch):
    warnings.simplefilter("ignore")
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=0))) as http:
        dataset_id = wait_job(http, http.post("/api/sweeps", json=SWEEP).json()["job_id"])["result"]["dataset_id"]
        samples = http.get(f"/api/datasets/{dataset_id}").json()["samples"]
        body = {"axis": "y", "datasets": [dataset_id], "effects": ["hysteresis"]}
        model_id = wait_job(http, http.post("/api/models", json=body).json()["job_id"])["result"]["model_id"]
        before = (http.get("/api/models").json(), http.get("/api/datasets").json(), http.get("/api/jobs").json())

        # a machine with one byte less free than this sweep's fit needs (through the share a fit may use)
        free_needed = int(fit_memory_bytes(samples) / memory.USABLE_SHARE)
        monkeypatch.setattr(memory, "available_memory_bytes", lambda: free_needed - 1)
        refused = [
            ("datasets", http.post("/api/models", json=body)),
            ("model_id", http.get(f"/api/models/{model_id}/diagnosis")),
            ("model_id", http.post(f"/api/models/{model_id}/discover", json={})),
            ("model_id", http.post(f"/api/models/{model_id}/refine", json={"add": "creep"})),
            ("model_id", http.get(f"/api/models/{model_id}/report/figures")),
        ]
        for field, r in refused:
            assert r.status_code == 422, (field, r.text)
            assert r.json()["field"] == field, r.json()
            detail = r.json()["detail"]
            assert f"{samples:,} samples" in detail and "GB free" in detail and dataset_id in detail, detail
        after = (http.get("/api/models").json(), http.get("/api/datasets").json(), http.get("/api/jobs").json())
        assert after == before  # nothing queued, stored or changed

        # with what it needs free, the same requests run
        monkeypatch.setattr(memory, "available_memory_bytes", lambda: free_needed + 1)
        assert http.get(f"/api/models/{model_id}/diagnosis").status_code == 200


@pytest.mark.slow
def test_the_estimate_bounds_a_diagnosis_peak(sweeps):
    """Measured here: a standard sweep's diagnosis (266 000 samples) peaks at 1.44 GB of numpy and
    Python allocations (the description of what remains included), under the 1.65 GB the estimate plans for."""
    warnings.simplefilter("ignore")
    record = sweeps("default", seed=0)["y"]
    tracemalloc.start()
    try:
        diagnose([record])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak <= fit_memory_bytes(record.n_samples), (peak, fit_memory_bytes(record.n_samples))
    assert peak >= 0.2 * fit_memory_bytes(record.n_samples)  # and not so loose that it refuses for nothing
