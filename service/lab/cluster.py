"""The Dask client a batch runs on: a running scheduler by address (``dask scheduler`` and ``dask
worker tcp://…`` started by hand, or EVCBENCH_DASK_SCHEDULER), or a LocalCluster of worker
processes (one thread each: a task's least squares use one BLAS thread, service/__init__.py) with no
dashboard. ``distributed`` is imported here only, so nothing else of the service needs it.
"""
from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from typing import Iterator

#: how many worker deaths a task may see before the scheduler gives up on it (KilledWorker): one
#: killed or lost worker costs a retry; a task that itself kills every worker it lands on (out of
#: memory) fails after this many instead of taking the whole cluster down one worker at a time
ALLOWED_FAILURES = 3
#: the environment variable naming a running scheduler (``tcp://host:8786``)
SCHEDULER_ENV = "EVCBENCH_DASK_SCHEDULER"


@contextmanager
def dask_client(scheduler: str | None = None, local_workers: int | None = None) -> Iterator:
    """A distributed.Client: on the scheduler at ``scheduler`` if given, else on a LocalCluster of
    ``local_workers`` processes (1 thread each; closed at exit). ValueError naming ``local_workers``
    when it is below 1."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES}):
        if scheduler:
            with Client(scheduler) as client:
                yield client
            return
        n = int(local_workers or 1)
        if n < 1:
            raise ValueError(f"local_workers: must be 1 or more, not {n}")
        with LocalCluster(n_workers=n, processes=True, threads_per_worker=1, dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield client


def scheduler_from_env() -> str | None:
    """The scheduler address EVCBENCH_DASK_SCHEDULER names, or None (run in process)."""
    return os.environ.get(SCHEDULER_ENV) or None
