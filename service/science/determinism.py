"""One BLAS thread: the same records give the same figures, whatever else the machine is doing.

numpy's and scipy's OpenBLAS split a large product or factorisation over threads as they see fit,
and the order of the partial sums then changes the result in its last bits. Identification and
discovery take discrete decisions on their results (an effect claimed at p < 1e-3, a segment kept,
a grid point chosen), so those bits can move a reported figure. Measured before this module: two
``python -m service.reports.tracking_error_spectrum --seed 1`` runs at once gave, in one of them,
FF-only 3.61 % where the same seed alone gives 4.56 %; with one BLAS thread every run gave 4.56 %.
It costs no time here: ``evcbench bench discovery`` diagnosed Y in 2.33–2.43 s and Z in 1.64–1.75 s
with one thread, against 2.69–2.78 s and 2.15–2.61 s with two (two runs each, alternating, 2 cores).

``limit_blas_threads()`` limits the BLAS libraries already loaded in this process (threadpoolctl
finds them, whoever imported numpy first) and sets the environment variables that processes started
from this one (the bench engine, Dask workers) read when they load theirs.
"""
from __future__ import annotations

import os

import numpy  # noqa: F401 - loads numpy's BLAS, so that the limit reaches it
import scipy.linalg  # noqa: F401 - and scipy's own
from threadpoolctl import threadpool_limits

BLAS_THREADS = 1
_ENVIRONMENT = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def limit_blas_threads() -> None:
    """Every loaded BLAS to ``BLAS_THREADS`` threads, and child processes told the same."""
    for name in _ENVIRONMENT:
        os.environ[name] = str(BLAS_THREADS)
    threadpool_limits(limits=BLAS_THREADS, user_api="blas")
