"""The Dask client a batch runs on: a running scheduler by address (``dask scheduler`` and ``dask
worker tcp://…`` started by hand, or EVCBENCH_DASK_SCHEDULER), or a LocalCluster of worker
processes (one thread each: a task's least squares use one BLAS thread, service/__init__.py) with no
dashboard. ``distributed`` is imported here only, so nothing else of the service needs it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: how many worker deaths a task may see before the scheduler gives up on it (KilledWorker): one
#: killed or lost worker costs a retry; a task that itself kills every worker it lands on (out of
#: memory) fails after this many instead of taking the whole cluster down one worker at a time
ALLOWED_FAILURES = 3
#: Dask settings of a batch cluster. The nanny's default MALLOC_TRIM_THRESHOLD_ (65536) is left
#: unset: setting it turns off glibc's adaptive mmap threshold, so every large numpy temporary is
#: mmap'ed, page-faulted and unmapped anew, and a diagnosis took twice the CPU time on a worker as in
#: process (4.5–5.2 s against 2.2–2.3 s, /tmp measurement on this machine, 2026-12-02)
WORKER_CONFIG = {
    "distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
}
#: the same as a Dask config file, for a scheduler and workers started by hand (DASK_CONFIG=<this dir>;
#: a DASK_* variable cannot say it: Dask lower-cases the variable's name)
CONFIG_DIR = Path(__file__).resolve().parent / "dask"
#: the environment variable naming a running scheduler (``tcp://host:8786``)
SCHEDULER_ENV = "EVCBENCH_DASK_SCHEDULER"


@contextmanager
def dask_client(scheduler: str | None = None, local_workers: int | None = None) -> Iterator:
    """A distributed.Client: on the scheduler at ``scheduler`` if given, else on a LocalCluster of
    ``local_workers`` processes (1 thread each; closed at exit). ValueError naming ``local_workers``
    when it is below 1."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set(WORKER_CONFIG):
        if scheduler:
            with Client(scheduler) as client:
                yield client
            return
        n = 1 if local_workers is None else int(local_workers)
        if n < 1:
            raise ValueError(f"local_workers: must be 1 or more, not {n}")
        # no dashboard; the scheduler's own HTTP routes (health, metrics) on a free port, not 8787
        with (
            LocalCluster(
                n_workers=n,
                processes=True,
                threads_per_worker=1,
                dashboard_address=None,
                scheduler_kwargs={"dashboard_address": ":0"},
                silence_logs=logging.ERROR,
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client


def scheduler_from_env() -> str | None:
    """The scheduler address EVCBENCH_DASK_SCHEDULER names, or None (run in process)."""
    return os.environ.get(SCHEDULER_ENV) or None
