"""Shared test set-up.

In-process apps (``create_app`` under TestClient) keep the bench in the test's own process
(``EVCBENCH_ENGINE=inline``) so that tests can reach into the emulator (fault injection, output
log). Services started as real processes (tests/live_server.py, service_load.spawn_service) run
the product's default, the bench engine in its own process; tests/test_engine_process.py drives
that path through the API as well.
"""
import os

os.environ.setdefault("EVCBENCH_ENGINE", "inline")
