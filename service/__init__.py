"""EVC Bench service: sweeps, hysteresis identification, discovery and control of a piezo bench."""

import os as _os
from importlib import metadata as _metadata

# One BLAS thread unless the user says otherwise, set before numpy is first imported: the service's
# least-squares solves are small, and a threaded BLAS on a 2-core lab PC fights the bench engine and
# itself (evcbench bench discovery: a diagnosis took 11.0 s of CPU with OpenBLAS's default threads
# against 4.3 s with one, measured side by side on this machine under load ~3).
for _name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")

try:
    __version__ = _metadata.version("evc-bench")
except _metadata.PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+source"
