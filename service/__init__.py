"""EVC Bench service: sweeps, hysteresis identification, discovery and control of a piezo bench."""
from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("evc-bench")
except _metadata.PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+source"
