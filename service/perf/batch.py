"""Batch benchmark: the same batch diagnosis on a Dask LocalCluster of 1 and of 2 worker processes
(1 thread each), side by side in one run: both clusters are up at once and the batch runs on one,
then the other, ``rounds`` times.

    evcbench bench batch --json

A temporary store gets ``n_datasets`` short emulated sweeps (10 and 50 Hz, 4 cycles each, axis Y;
the default, creep and dynamics benches in turn, seed = the dataset's number). Each cluster first
runs one diagnosis on every worker (imports and compiled kernels loaded: start-up is not
throughput), then the timed batch: identify + diagnose each dataset's Y axis, one task per dataset,
every model stored. Figures: wall time per cluster and round, datasets per second (best round), the
1→2 worker ``speedup`` (best time with 1 / best time with 2), ``spin_speedup``: the same ratio
for ``spin_tasks`` busy-loops of ``spin_cpu_s`` CPU seconds, measured after each batch (what the
machine gave two processes at the time: 2.0 on two idle cores), and ``identical``: every run gave
the same numbers (every row but the stored models' ids; the models' parameters by their SHA-256). ``workers_cpu_s`` is the
CPU time the workers spent in the batch, and ``cpu_share_per_worker`` that over wall time and
workers: near 1 when each worker had a core to itself. ``load_average`` is the machine's before and
after: on a shared machine other processes take their turns too, and the ratio shows it.
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


def spin(cpu_s: float) -> float:
    """Busy-loop for ``cpu_s`` seconds of this process's CPU time; the wall time it took (s)."""
    t, wall = time.process_time(), time.perf_counter()
    while time.process_time() - t < cpu_s:
        pass
    return time.perf_counter() - wall


def _timed_batch(client, address: StoreAddress, ids: list[str]) -> tuple[dict, float, float]:
    """The batch on ``client``: (its result, wall s, the workers' CPU s in it)."""
    cpu = client.run(time.process_time)
    t = time.perf_counter()
    result = batch_discover(address, ids, axes=("y",), client=client)
    wall = time.perf_counter() - t
    return result, wall, sum(after - cpu[w] for w, after in client.run(time.process_time).items())


def _timed_spin(client, tasks: int, cpu_s: float) -> float:
    """Wall time (s) of ``tasks`` busy-loops of ``cpu_s`` each on ``client``'s workers."""
    t = time.perf_counter()
    client.gather(client.map(spin, [cpu_s] * tasks, pure=False))
    return time.perf_counter() - t


def run_batch_benchmark(n_datasets: int = 64, rounds: int = 2, spin_tasks: int = 8, spin_cpu_s: float = 0.5) -> dict:
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
        out = {
            "datasets": n_datasets,
            "axes": ["y"],
            "sweep": "10, 50 Hz x 4 cycles",
            "rounds": rounds,
            "seed_s": time.perf_counter() - t0,
            "load_average": {"before": list(os.getloadavg())},
        }
        runs = {n: {"wall_s": [], "workers_cpu_s": [], "spin_wall_s": []} for n in (1, 2)}
        results = {}
        with dask_client(local_workers=1) as one, dask_client(local_workers=2) as two:
            clients = {1: one, 2: two}
            for client in clients.values():
                client.run(warm_up, address, ids[0])
            for _ in range(rounds):  # alternate, so that both see the machine's load alike
                for n, client in clients.items():
                    result, wall, cpu_s = _timed_batch(client, address, ids)
                    results.setdefault(n, []).append(result)
                    runs[n]["wall_s"].append(wall)
                    runs[n]["workers_cpu_s"].append(cpu_s)
                    runs[n]["spin_wall_s"].append(_timed_spin(client, spin_tasks, spin_cpu_s))
        for n, run in runs.items():
            best = min(run["wall_s"])
            run.update(
                best_wall_s=best,
                datasets_per_s=n_datasets / best,
                ok=[r["ok"] for r in results[n]],
                failed=[r["failed"] for r in results[n]],
                cpu_share_per_worker=[c / w / n for c, w in zip(run["workers_cpu_s"], run["wall_s"])],
            )
        out["runs"] = {f"{n}_workers": run for n, run in runs.items()}
        out["speedup"] = runs[1]["best_wall_s"] / runs[2]["best_wall_s"]
        out["spin_speedup"] = min(runs[1]["spin_wall_s"]) / min(runs[2]["spin_wall_s"])
        first = comparable(results[1][0]["results"])
        out["identical"] = all(comparable(r["results"]) == first for n in results for r in results[n])
        out["load_average"]["after"] = list(os.getloadavg())
        return out
    finally:
        close_stores()
        shutil.rmtree(root, ignore_errors=True)
