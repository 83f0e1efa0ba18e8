"""Columns computed from a drive, kept for the fits that follow.

A diagnosis fits a dozen composite models on the same records with the same thresholds and
scales; each fit (and each prediction after it) would otherwise rebuild the same columns over
every sample: the play operators' outputs and every effect's regressor blocks (266 000 samples ×
up to 60 columns for a standard sweep). ``ColumnMemo`` keeps them, keyed by the *identity* of the
arrays they were computed from (a reference is held, so an id stays its own while the entry
lives) and by the numbers that parametrise them. What it returns is read-only: fits share it.

- ``PLAY_OUTPUTS``: the play operators' outputs of the last few drives, for the whole process.
- ``shared_effect_columns()``: a scope (a discovery step, a diagnosis) within which every effect's
  blocks are kept; outside one they are computed each time, so a long-running service holds
  nothing once the scope ends.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np

from service.science.models.kernels import play_operators

#: what a scope may hold (bytes): the effect blocks of a few record contexts of a standard sweep
SCOPE_BUDGET_BYTES = 1 << 30


def _arrays_of(value) -> list[np.ndarray]:
    """The arrays inside ``value``: an array, or a list of lsq Blocks (their parts)."""
    if isinstance(value, np.ndarray):
        return [value]
    return [part for block in value for part in block.parts]


class ColumnMemo:
    """An LRU of computed columns, bounded to ``max_entries`` and (if given) ``max_bytes``;
    thread-safe (jobs run in threads)."""

    def __init__(self, max_entries: int, max_bytes: int | None = None):
        self.max_entries, self.max_bytes = max_entries, max_bytes
        self._entries: OrderedDict = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, sources: tuple, params: tuple, compute: Callable[[], object]):
        """``compute()``'s value for the arrays ``sources`` (None allowed) and the hashable ``params``,
        computed once while the entry lives; its arrays are made read-only."""
        key = (tuple(id(s) for s in sources), params)
        with self._lock:
            hit = self._entries.get(key)
            if hit is not None and all(a is b for a, b in zip(hit[0], sources)):
                self._entries.move_to_end(key)
                return hit[1]
        value = compute()
        size = 0
        for array in _arrays_of(value):
            array.flags.writeable = False  # shared between fits: nobody may change it in place
            size += array.nbytes
        with self._lock:
            old = self._entries.pop(key, None)
            if old is not None:
                self._bytes -= old[2]
            self._entries[key] = (sources, value, size)
            self._bytes += size
            while self._entries and (
                len(self._entries) > self.max_entries or (self.max_bytes is not None and self._bytes > self.max_bytes)
            ):
                self._bytes -= self._entries.popitem(last=False)[1][2]
        return value


#: the play operators' outputs of the last six drives (each n × p floats), for the whole process
PLAY_OUTPUTS = ColumnMemo(max_entries=6)


def play_outputs(u_v: np.ndarray, origin_v: float, thresholds_v: np.ndarray) -> np.ndarray:
    """The play operators' outputs (V) of ``u_v − origin_v`` at ``thresholds_v`` (read-only, memoised)."""
    thresholds_v = np.asarray(thresholds_v, dtype=float)
    return PLAY_OUTPUTS.get(
        (u_v,),
        (u_v.shape, float(origin_v), thresholds_v.tobytes()),
        lambda: play_operators(u_v - origin_v, thresholds_v),
    )


_SCOPE: ContextVar[ColumnMemo | None] = ContextVar("effect_columns_scope", default=None)


@contextmanager
def shared_effect_columns(max_bytes: int = SCOPE_BUDGET_BYTES) -> Iterator[None]:
    """Within this block, effect blocks computed for one record context are reused (a nested scope
    shares its enclosing one); what was kept is released when the outermost block ends."""
    if _SCOPE.get() is not None:
        yield
        return
    token = _SCOPE.set(ColumnMemo(max_entries=1 << 16, max_bytes=max_bytes))
    try:
        yield
    finally:
        _SCOPE.reset(token)


def effect_blocks(sources: tuple, params: tuple, compute: Callable[[], list]) -> list:
    """``compute()`` (an effect's blocks for a record context made of ``sources`` arrays and
    ``params``), kept within a ``shared_effect_columns`` scope, else computed afresh."""
    memo = _SCOPE.get()
    return compute() if memo is None else memo.get(sources, params, compute)
