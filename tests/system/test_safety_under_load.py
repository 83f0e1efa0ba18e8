"""The emergency stop and a sweep while others load the service: behaviour, not timing.

A real ``evcbench serve`` (engine in its own process) runs sweeps while four clients stream
full-resolution CSV downloads and one imports a CSV, each client its own process; the stop is
pressed at random moments. The latencies are figures of ``evcbench bench safety --json``; here the
stop must always land, the sweep must never be tripped by others' requests, and memory stays bounded.
The benchmark's 1 Hz block (10 s of real time over both axes) is left out of this run's sweep, and
the stops come 0.1–0.6 s into each long sweep rather than 0.3–1.8 s: the same doors, the same load.
"""

import pytest

from service.perf.safety_load import run_safety_under_load

pytestmark = [pytest.mark.slow, pytest.mark.realtime]  # live services and their clients


def test_stop_lands_and_sweep_survives_under_load():
    out = run_safety_under_load(
        presses=3,
        import_mb=10.0,
        seed=1,
        press_window_s=(0.1, 0.6),
        sweep={"axes": ["y", "z"], "frequencies_hz": [10, 50, 100], "cycles": 5},
    )
    for phase in ("stop_idle", "stop_under_load", "stop_idle_service_route", "stop_under_load_service_route"):
        assert out[phase]["every_stop_landed"], out[phase]["not_landed"]
        assert out[phase]["zero_ms"]["n"] >= 3
        # every stop reports a 0 V write that came after the request was sent
        assert 0.0 <= out[phase]["zero_ms"]["max"] < float("inf")
    # the client's stop took the engine's port every time (no fallback), the route stayed the route
    assert out["stop_idle"]["doors"] == out["stop_under_load"]["doors"] == ["stop port"]
    assert out["stop_under_load_service_route"]["doors"] == ["service route"]
    sweep = out["sweep_under_load"]
    assert sweep["state"] == "succeeded", sweep["error"]
    # never tripped by others' requests; the real-time overruns are the benchmark's figure (a shared
    # CI machine's own load can make a period late without any request's help)
    assert sweep["watchdog_trips"] == 0 and sweep["periods"] > 0
    load = out["load"]
    # the load really ran (how much of it depends on the machine) and every import that ended succeeded
    assert load["download_mb"] > 0 and set(load["import_status"]) <= {201}
    # memory does not grow with what is streamed: the web process stays far below the data it served
    assert out["rss_mb"]["web"] < 1024 and out["rss_mb"]["engine"] < 1024
