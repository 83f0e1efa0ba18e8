"""Discovery benchmark: time one full diagnosis (every candidate fitted and validated) of a
hysteresis-only model on a 4-frequency two-axis sine sweep of the default bench. ``diagnosis_s`` is
wall time; ``diagnosis_cpu_s`` this process's CPU time over the same call (on a shared machine the
wall time also counts other processes' turns; one BLAS thread, so CPU ≈ wall when the machine is idle).

``subnormal_design``: the exact solve of a design whose columns end in a filter's ring-down tail
(subnormal floats, as a mode's output at rest was before the kernels flushed them) against the
same design with that tail at 0, side by side; and a bare Gram of each, which pays the tail.
``solve_ratio`` ≈ 1 says the flush works; ``bare_gram_ratio`` is what it spares."""

from __future__ import annotations

import time
import warnings

import numpy as np

from service.lab.emulated import sweep_records
from service.science.discovery.composite import CompositeModel
from service.science.discovery.diagnosis import diagnose
from service.science.fitting.lsq import Block, solve_blocks


def _best_of(fn, repeats: int = 5) -> float:
    """The fastest of ``repeats`` calls of ``fn`` (s)."""
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def subnormal_design_figures(n_rows: int = 11_200, n_columns: int = 86) -> dict:
    """Solve and bare-Gram times (s) of a design 40 % ring-down tail against the same with zeros."""
    rng = np.random.default_rng(0)
    tail = rng.normal(size=(n_rows, n_columns))
    tail[int(0.6 * n_rows) :, ::2] = rng.uniform(5e-324, 1e-310, size=(n_rows - int(0.6 * n_rows), n_columns // 2))
    zeroed = np.where(np.abs(tail) < np.finfo(float).tiny, 0.0, tail)
    target = tail.sum(axis=1)
    solve = {
        k: _best_of(lambda a=a: solve_blocks([Block.make("c", a)], target))
        for k, a in (("tail", tail), ("zeroed", zeroed))
    }
    gram = {k: _best_of(lambda a=np.asfortranarray(a): a.T @ a) for k, a in (("tail", tail), ("zeroed", zeroed))}
    return {
        "shape": [n_rows, n_columns],
        "solve_tail_s": solve["tail"],
        "solve_zeroed_s": solve["zeroed"],
        "solve_ratio": solve["tail"] / solve["zeroed"],
        "bare_gram_tail_s": gram["tail"],
        "bare_gram_zeroed_s": gram["zeroed"],
        "bare_gram_ratio": gram["tail"] / gram["zeroed"],
    }


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
        out["per_axis"][axis] = {
            "fit_s": fit_s,
            "diagnosis_s": time.perf_counter() - t,
            "diagnosis_cpu_s": time.process_time() - cpu,
            "candidates": len(d["candidates"]),
            "top": d["candidates"][0]["effect"],
        }
    out["diagnosis_s"] = max(v["diagnosis_s"] for v in out["per_axis"].values())
    out["budget_s"] = 5.0
    out["subnormal_design"] = subnormal_design_figures()
    return out
