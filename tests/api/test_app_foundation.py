"""The service skeleton: /api/health and /api/bench on the emulated bench, and 0 V at shut-down."""

from __future__ import annotations

from service.http.app import create_app
from service.runtime.settings import Settings
from tests.support.api_client import authed_client


def test_health_and_bench_describe_the_emulated_bench(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, bench="default", seed=0))
    with authed_client(app) as client:
        health = client.get("/api/health")
        assert health.status_code == 200
        assert health.json()["status"] == "ok"
        assert health.json()["backend"] == "emulated:default"

        bench = client.get("/api/bench").json()
        assert bench["axes"] == ["y", "z"]
        for axis in ("y", "z"):
            limits = bench["limits"][axis]
            assert (limits["v_min_v"], limits["v_max_v"]) == (0.0, 150.0)  # the stacks' rating
            # I = C·π·f·Vpp: 150 Vpp into 1.8 µF at 200 mA allows about 236 Hz; and a sine stays below half
            # the first resonance (Z: 145.35 Hz), the limit a sweep is refused by
            expected_hz = limits["current_limit_a"] / (3.141592653589793 * limits["capacitance_f"] * 150.0)
            slew_hz = limits["slew_limit_v_per_s"] / (3.141592653589793 * 150.0)
            highest = min(expected_hz, slew_hz, 0.5 * limits["first_resonance_hz"])
            assert abs(limits["max_frequency_hz_at_full_range"] - highest) < 1e-6
        assert bench["limits"]["y"]["first_resonance_hz"] == 482.6
        assert bench["limits"]["z"]["first_resonance_hz"] == 290.7
        assert bench["limits"]["z"]["max_frequency_hz_at_full_range"] == 0.5 * 290.7
        assert bench["modes"]["point_by_point"] is True
        assert bench["daq"]["resolution_bits"] == 16
        bench_object = app.state.bench
    # Leaving the context runs the shut-down: the bench is closed with its output at 0 V.
    assert all(abs(v) < 0.05 for v in bench_object.output_v().values())


def test_docs_are_served(tmp_path):
    with authed_client(create_app(Settings(data_dir=tmp_path, seed=0))) as client:
        assert client.get("/docs").status_code == 200
        spec = client.get("/openapi.json").json()
        assert "/api/health" in spec["paths"] and "/api/bench" in spec["paths"]


def test_the_web_process_starts_without_scipy_signal_or_stats(tmp_path):
    """scipy.signal and scipy.stats (0.4-0.5 s of a service's start-up) are imported where the
    science uses them, not by the app as it starts: a fresh process that builds the app and answers
    /api/health has neither loaded."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from fastapi.testclient import TestClient\n"
        "from service.http.app import create_app\n"
        "from service.runtime.settings import Settings\n"
        f"app = create_app(Settings(data_dir={str(tmp_path)!r}, bench='default', seed=0, auth='off'))\n"
        "with TestClient(app) as client:\n"
        "    assert client.get('/api/health').status_code == 200\n"
        "print(sorted({m.split('.')[1] for m in sys.modules if m.startswith(('scipy.signal', 'scipy.stats'))}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "[]"
