"""Benchmark: what the token check costs a cheap read, side by side in one run.

    evcbench bench auth --json

Two apps on the emulated default bench, one with ``auth = "tokens"`` (a Bearer admin token: its
hash looked up in the store, revocation and scope checked) and one with ``auth = "off"``, each
answering GET /api/bench through an in-process client. Requests alternate between the two so both see the same machine load; ``ratio`` is
p50 with auth / p50 without.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

from fastapi.testclient import TestClient

from service.http.app import create_app
from service.runtime.settings import Settings
from service.security import auth

PATH = "/api/bench"


def _client(stack: ExitStack, mode: str) -> TestClient:
    data_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=f"evc-bench-auth-{mode}-")))
    http = stack.enter_context(TestClient(create_app(Settings(data_dir=data_dir, seed=0, auth=mode))))
    if mode == "tokens":
        http.headers["Authorization"] = f"Bearer {auth.read_bootstrap_token(data_dir)}"
    return http


def run_auth_benchmark(requests: int = 400, warmup: int = 20) -> dict:
    with ExitStack() as stack:
        clients = {"tokens": _client(stack, "tokens"), "off": _client(stack, "off")}
        times_ms: dict[str, list[float]] = {"tokens": [], "off": []}
        for i in range(warmup + requests):
            for mode, http in clients.items():
                t0 = time.perf_counter()
                status = http.get(PATH).status_code
                elapsed = (time.perf_counter() - t0) * 1e3
                if status != 200:
                    raise RuntimeError(f"GET {PATH} with auth {mode!r} answered {status}")
                if i >= warmup:
                    times_ms[mode].append(elapsed)
    p50 = {mode: statistics.median(t) for mode, t in times_ms.items()}
    return {
        "path": PATH,
        "requests_each": requests,
        "client": "in-process (httpx via TestClient)",
        "p50_ms_auth_tokens": round(p50["tokens"], 4),
        "p50_ms_auth_off": round(p50["off"], 4),
        "p50_overhead_ms": round(p50["tokens"] - p50["off"], 4),
        "ratio": round(p50["tokens"] / p50["off"], 3),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run_auth_benchmark(), indent=2))
