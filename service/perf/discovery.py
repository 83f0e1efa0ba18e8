"""Discovery benchmark: time one full diagnosis (every candidate fitted and validated) of a
hysteresis-only model on a 4-frequency two-axis sine sweep of the default bench. ``diagnosis_s`` is
wall time; ``diagnosis_cpu_s`` this process's CPU time over the same call (on a shared machine the
wall time also counts other processes' turns; one BLAS thread, so CPU ≈ wall when the machine is idle)."""
from __future__ import annotations

import time
import warnings

from service.science.discovery.composite import CompositeModel
from service.science.discovery.diagnosis import diagnose
from service.science.discovery.records import sweep_records


def run_discovery_benchmark() -> dict:
    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    records = sweep_records("default", seed=0, frequencies_hz=(1.0, 10.0, 50.0, 100.0), cycles=5)
    sweep_s = time.perf_counter() - t0
    out = {"sweep_s": sweep_s, "samples": records["y"].n_samples, "per_axis": {}}
    for axis, rec in records.items():
        t = time.perf_counter()
        model = CompositeModel([]).fit([rec])
        fit_s = time.perf_counter() - t
        t, cpu = time.perf_counter(), time.process_time()
        d = diagnose([rec], model=model)
        out["per_axis"][axis] = {"fit_s": fit_s, "diagnosis_s": time.perf_counter() - t,
                                 "diagnosis_cpu_s": time.process_time() - cpu,
                                 "candidates": len(d["candidates"]), "top": d["candidates"][0]["effect"]}
    out["diagnosis_s"] = max(v["diagnosis_s"] for v in out["per_axis"].values())
    out["budget_s"] = 5.0
    return out
