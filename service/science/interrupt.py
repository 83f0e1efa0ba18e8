"""Cooperative interruption of long computations: a fit that a user cancels stops at its next solve.

A discover run's step fits a dozen models; a cancel read only between steps waited for all of them
(a walk's took 267 s to land). The caller that owns the computation (a job) installs a question,
"should this stop?", with ``interruptible``; the science code asks it at ``checkpoint`` — every
least-squares solve — and ``Interrupted`` unwinds to the caller, which keeps what it had. Without a
question installed (a script, a test, a report), ``checkpoint`` does nothing.

The question lives in a ``contextvars.ContextVar``: it is the calling thread's own, so a job's
cancel never reaches another job's fit. Pure Python: no jobs, no HTTP.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

_SHOULD_STOP: ContextVar[Callable[[], bool] | None] = ContextVar("evcbench_should_stop", default=None)


class Interrupted(BaseException):
    """A computation stopped at a checkpoint because its owner asked it to. A ``BaseException``, as
    asyncio's CancelledError is since Python 3.8: a fit's own ``except Exception`` (a candidate found
    untestable, a fallback) must not swallow a cancel and carry on."""


@contextmanager
def interruptible(should_stop: Callable[[], bool]) -> Iterator[None]:
    """Within the block, every ``checkpoint`` in this thread raises ``Interrupted`` once
    ``should_stop()`` is true."""
    token = _SHOULD_STOP.set(should_stop)
    try:
        yield
    finally:
        _SHOULD_STOP.reset(token)


def checkpoint() -> None:
    """Raise ``Interrupted`` if this thread's owner asked to stop; nothing otherwise (cheap)."""
    should_stop = _SHOULD_STOP.get()
    if should_stop is not None and should_stop():
        raise Interrupted("stopped at a checkpoint: its owner asked it to stop")
