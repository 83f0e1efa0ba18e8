"""Batch benchmark: the same batch diagnosis on a Dask LocalCluster of 1 and of 2 worker processes
(1 thread each), side by side in one run.

    evcbench bench batch --json

A temporary store gets ``n_datasets`` short emulated sweeps (10 and 50 Hz, 4 cycles each, axis Y;
the default, creep and dynamics benches in turn, seed = the dataset's number). Each cluster first
runs one diagnosis on every worker (imports and compiled kernels loaded: start-up is not
throughput), then the timed batch: identify + diagnose each dataset's Y axis, one task per dataset,
every model stored. Figures: wall time per cluster, datasets per second, the 1→2 worker
``speedup`` (time with 1 / time with 2), and ``identical``: both runs gave the same numbers (every
row but the stored models' ids; the models' parameters by their SHA-256). ``load_average`` is the
machine's before and after: on a shared machine other processes take their turns too.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
import warnings

from service.lab.address import StoreAddress, close_stores, open_store
from service.lab.batch import batch_discover, comparable
from service.lab.cluster import dask_client
from service.lab.emulated import record_emulated_sweep

BENCHES = ("default", "creep", "dynamics")


def warm_up(address: StoreAddress, dataset_id: str) -> int:
    """One diagnosis of ``dataset_id``'s Y axis without storing anything (loads the modules and the
    compiled kernels a task needs); the worker's pid."""
    from service.science.discovery.composite import CompositeModel
    from service.science.discovery.diagnosis import diagnose
    from service.usecases.identify import load_record

    warnings.simplefilter("ignore")
    record = load_record(open_store(address), dataset_id, "y")
    diagnose([record], model=CompositeModel([]).fit([record]))
    return os.getpid()


def run_batch_benchmark(n_datasets: int = 64, workers=(1, 2)) -> dict:
    warnings.simplefilter("ignore")
    root = tempfile.mkdtemp(prefix="evcbench-batch-")
    try:
        address = StoreAddress.of(None, root)
        store = open_store(address)
        t0 = time.perf_counter()
        ids = []
        for i in range(n_datasets):
            bench = BENCHES[i % len(BENCHES)]
            ids.append(record_emulated_sweep(store, bench, seed=i, bench_id=f"bench-{bench}", axes=("y",))["id"])
        out = {"datasets": n_datasets, "axes": ["y"], "sweep": "10, 50 Hz x 4 cycles", "seed_s": time.perf_counter() - t0,
               "load_average": {"before": list(os.getloadavg())}, "runs": {}}
        results = {}
        for n in workers:
            with dask_client(local_workers=n) as client:
                client.run(warm_up, address, ids[0])
                t = time.perf_counter()
                result = batch_discover(address, ids, axes=("y",), client=client)
                wall = time.perf_counter() - t
            results[n] = result["results"]
            out["runs"][f"{n}_workers"] = {"wall_s": wall, "datasets_per_s": n_datasets / wall, "ok": result["ok"],
                                           "failed": result["failed"]}
        first, second = (out["runs"][f"{n}_workers"]["wall_s"] for n in workers[:2])
        out["speedup"] = first / second
        out["identical"] = comparable(results[workers[0]]) == comparable(results[workers[1]])
        out["load_average"]["after"] = list(os.getloadavg())
        return out
    finally:
        close_stores()
        shutil.rmtree(root, ignore_errors=True)
