"""Benchmarks: each measures figures side by side in one run and returns one JSON-able dict.

They are run by ``evcbench bench <name> --json``, never as timed assertions in the tests.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

# name -> "module:function"; imported lazily so one benchmark's dependencies never slow another.
BENCHMARKS: dict[str, str] = {
    "emulator": "drivers.emulated.benchmark:run_emulator_benchmark",
    "identification": "service.perf.identification:run_identification_benchmark",
    "control": "service.perf.control:run_control_benchmark",
    "discovery": "service.perf.discovery:run_discovery_benchmark",
    "service": "service.perf.service_load:run_service_benchmark",
    "safety": "service.perf.safety:run_safety_benchmark",
    "auth": "service.perf.auth:run_auth_benchmark",
    "batch": "service.perf.batch:run_batch_benchmark",
}


def get_benchmark(name: str) -> Callable[[], dict]:
    """The benchmark function registered under ``name``; KeyError lists the known names."""
    try:
        target = BENCHMARKS[name]
    except KeyError:
        raise KeyError(f"unknown benchmark {name!r}; known: {', '.join(sorted(BENCHMARKS))}") from None
    module, function = target.split(":")
    return getattr(importlib.import_module(module), function)
