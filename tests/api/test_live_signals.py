"""Live signals: the LiveMonitor ring buffer (drivers/live.py) and GET /api/bench/live during jobs."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.live import LiveMonitor
from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client


def test_monitor_decimates_evenly_across_blocks_and_keeps_the_latest():
    live = LiveMonitor(("y", "z"), rate_hz=1000.0, capacity=50)
    live.begin(10_000.0)  # stride 10
    t = np.arange(1234)
    for chunk in np.array_split(t, 7):  # odd block sizes: the stride carries over
        live.push({"y": chunk.astype(float)}, {"y": 2.0 * chunk, "z": -chunk.astype(float)})
    got = live.since(0, max_points=1000)
    kept = np.arange(0, 1234, 10)
    assert got["cursor"] == len(kept)
    assert got["first"] == len(kept) - 50 and got["dropped"] == len(kept) - 50  # a cursor too old
    assert got["u_y_v"] == kept[-50:].tolist()
    assert got["x_y_um"] == (2.0 * kept[-50:]).tolist() and got["x_z_um"] == (-kept[-50:]).tolist()
    assert got["u_z_v"] == [None] * 50  # not streamed: null
    assert got["t_s"] == pytest.approx((kept[-50:] / 10_000.0).tolist())
    assert set(got["runs"]) == {1}
    # Nothing new after the cursor; a new run restarts its time at 0 s.
    assert live.since(got["cursor"])["t_s"] == []
    live.begin(1000.0, "second")
    live.push({"y": np.ones(5)}, {"y": np.ones(5)})
    new = live.since(got["cursor"])
    assert new["t_s"] == [0.0, 0.001, 0.002, 0.003, 0.004] and new["runs"] == [2] * 5 and new["label"] == "second"
    # Thinned to max_points by a stride; None asks for the latest.
    assert len(live.since(0, max_points=7)["t_s"]) <= 7
    assert live.since(None, max_points=3)["u_y_v"] == [1.0, 1.0, 1.0]


def test_columns_and_mappings_keep_the_same_samples_across_the_ring():
    """push_columns (the tracking loop's, once per period) keeps what push keeps, wrap-around included."""
    rng = np.random.default_rng(4)
    by_mapping, by_columns = (LiveMonitor(("y", "z"), rate_hz=1000.0, capacity=37) for _ in range(2))
    for live in (by_mapping, by_columns):
        live.begin(20_000.0)  # stride 20
    sizes = (200, 7, 13, 200, 1, 0, 450, 19, 200)
    for n in sizes:
        u, x = rng.standard_normal((n, 2)), rng.standard_normal((n, 2))
        by_mapping.push({"y": u[:, 0], "z": u[:, 1]}, {"y": x[:, 0], "z": x[:, 1]})
        by_columns.push_columns(u, x)
        assert by_columns.since(0, 1000) == by_mapping.since(0, 1000)
    assert by_columns.since(0, 1000)["cursor"] == len(range(0, sum(sizes), 20))


def test_live_endpoint_follows_a_sweep(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=1))
    with authed_client(app) as http:
        assert http.get("/api/bench/live").json()["t_s"] == []
        job = http.post("/api/sweeps", json={"axes": ["y"], "frequencies_hz": [2.0], "cycles": 4}).json()
        cursor, t, u, x = 0, [], [], []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            state = http.get(f"/api/jobs/{job['job_id']}").json()["state"]
            live = http.get("/api/bench/live", params={"since": cursor, "max_points": 20_000}).json()
            assert live["cursor"] >= cursor
            cursor = live["cursor"]
            t += live["t_s"]
            u += live["u_y_v"]
            x += live["x_y_um"]
            if state in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.1)
        assert state == "succeeded"
        assert live["axes"] == ["y", "z"] and live["rate_hz"] <= 1000.0
        # The whole 2 s of drive arrived in order, in volts and micrometres, decimated to ≤ 1 kHz.
        assert np.all(np.diff(t) > 0) and t[-1] >= 1.9
        assert max(u) > 100 and min(u) < 20 and max(x) > 3.0
        assert 1500 <= len(t) <= 2100 * (t[-1] / 2.0 + 1)
        # Bad input in words.
        bad = http.get("/api/bench/live", params={"max_points": 0})
        assert bad.status_code in (400, 422) and "max_points" in bad.text
