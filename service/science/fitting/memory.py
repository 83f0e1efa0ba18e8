"""How much memory a fit or a diagnosis of records needs, and whether this machine has it free.

A composite fit builds every effect's columns over every sample (a filter or a delay needs the
samples between the training rows), and a diagnosis fits a dozen candidates on them: its peak grows
with the samples, not with the training rows. Measured: the diagnosis of a standard 266 000-sample sweep
peaks at 1.44 GB of allocations (tracemalloc), 5.42 kB a sample, since the fine grid of the base has
30 play widths (1.13 GB before, with 20; 0.96 GB before rate dependence drew the switched strain's
relaxation; 0.51 GB before the base's Preisach plane had 20 widths and the library three more
effects), the description of what remains
(service.science.discovery.remainder, its columns built a chunk of rows at a time) included; of a
2 000 000-sample import (Y and
Z, 17 blocks) it raised the process's peak RSS from 0.34 to 3.63 GB, 1.65 kB a sample (the column
memo's 1 GB bound holds there). A record long enough to exhaust the machine would have the
kernel kill the service mid-job, so such a request is refused first, naming what it would need.
"""

from __future__ import annotations

#: the peak a fit or diagnosis adds per sample of its records (bytes): the 5.42 kB measured, with 15 % to spare
FIT_BYTES_PER_SAMPLE = 6200
#: the share of the memory free now that one fit may plan to use (the service, its bench engine
#: and other jobs go on)
USABLE_SHARE = 0.8


def fit_memory_bytes(n_samples: int) -> int:
    """The peak memory (bytes) a fit or diagnosis of records with ``n_samples`` samples in all adds."""
    return int(n_samples) * FIT_BYTES_PER_SAMPLE


def available_memory_bytes(meminfo: str = "/proc/meminfo") -> int | None:
    """The memory the kernel can give without swapping (MemAvailable, bytes); None where unknown."""
    try:
        with open(meminfo) as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def memory_shortfall(n_samples: int, available_bytes: int | None = None) -> str | None:
    """None if a fit of ``n_samples`` samples fits in the memory free now (``available_bytes``, default
    read from the kernel), else why not, in words with the figures."""
    free = available_memory_bytes() if available_bytes is None else available_bytes
    need = fit_memory_bytes(n_samples)
    if free is None or need <= USABLE_SHARE * free:
        return None
    return (
        f"{n_samples:,} samples need about {need / 1e9:.1f} GB to fit and diagnose, more than the "
        f"{USABLE_SHARE * free / 1e9:.1f} GB a fit may use ({100 * USABLE_SHARE:.0f} % of the "
        f"{free / 1e9:.1f} GB free on this machine): fit on fewer or shorter datasets (import a part of the "
        "record), or on a machine with more memory"
    )
