"""Keep the garbage collector's full passes out of real-time work."""

from __future__ import annotations

import gc


def freeze_heap() -> None:
    """Collect, then move every object alive now out of the garbage collector's reach (``gc.freeze``).

    A full collection of a service's heap (numba, scipy, SQLAlchemy: ~200 000 objects) holds the
    GIL for 50–200 ms, which would stall a real-time loop and every request; after a freeze the
    collector only scans what was allocated since, which takes well under a millisecond. Called at
    start-up and before each bench job (whose first run may have compiled kernels), in the web
    process and in the bench engine's."""
    gc.collect()
    gc.freeze()
