"""numba's ``njit`` with a cache that several processes can fill at once.

Every compiled kernel of the product (the emulator's, the fits', the control loop's) is compiled
with ``cache=True``, and several processes share one cache: the service and its bench engine, the
benches of a lab, the workers of the test suite. numba 0.68's cache is not safe for that
(numba/numba#4807, #10128). ``IndexDataCacheFile.save`` reads the function's index, takes the
first free data-file number, writes the index, then the data file. Two processes that save two
signatures of one function at the same time both take number 1. The index then names one
signature and file 1 holds the other's machine code, and every later process that loads that
signature runs the wrong code, silently. tests/unit/drivers/test_jit_cache.py shows the lost save; without
the lock it fails.

Here the index's read-modify-write and the data file are written under an exclusive ``flock`` on a
lock file beside the index, and loads hold a shared one, so a reader never sees an index entry
whose data file another writer is still choosing. Where the lock file cannot be made (a read-only
cache), numba's own behaviour is kept.
"""

from __future__ import annotations

import contextlib
import fcntl
import os

from numba import njit  # noqa: F401 - re-exported: kernels import njit from here, so the lock is in place
from numba.core import caching

__all__ = ["njit"]


@contextlib.contextmanager
def index_lock(index_path: str, mode: int):
    """Hold ``fcntl.flock(mode)`` on ``<index_path>.lock`` for the block (no lock if it cannot be opened)."""
    try:
        fd = os.open(f"{index_path}.lock", os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, mode)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def _install() -> None:
    cache_file = caching.IndexDataCacheFile
    if getattr(cache_file, "_evc_locked", False):
        return
    unlocked_save, unlocked_load = cache_file.save, cache_file.load

    def save(self, key, data):
        with index_lock(self._index_path, fcntl.LOCK_EX):
            unlocked_save(self, key, data)

    def load(self, key):
        with index_lock(self._index_path, fcntl.LOCK_SH):
            return unlocked_load(self, key)

    cache_file.save, cache_file.load, cache_file._evc_locked = save, load, True


_install()


def drop_stale_caches(namespace: dict, sources) -> None:
    """numba keys a cached function on its own file alone, so a change to a function it compiles in
    from another file (``sources``: paths) would not reach it. Call at the end of a module with its
    ``globals()``: every cached kernel defined there whose index is older than a source loses that
    index before its first call loads it (numba writes a fresh one on the next compile). The index
    is found through numba's own locator, so ``NUMBA_CACHE_DIR`` is honoured. Best effort: a cache
    that cannot be read or written is left as it is."""
    try:
        newest = max(os.stat(p).st_mtime for p in sources)
    except OSError:
        return
    for obj in list(namespace.values()):
        if getattr(getattr(obj, "py_func", None), "__module__", None) != namespace.get("__name__"):
            continue
        try:
            index = obj._cache._cache_file._index_path
            if os.path.exists(index) and os.stat(index).st_mtime < newest:
                with index_lock(index, fcntl.LOCK_EX):
                    os.unlink(index)
        except (AttributeError, OSError):
            pass
