"""drivers.jit: two processes that save two signatures of one compiled function at the same time
each find their own machine code afterwards (numba's own cache gives both data file 1)."""

from __future__ import annotations

import importlib
import multiprocessing
import sys
import time

import numpy as np
from numba.core.caching import IndexDataCacheFile

import drivers.jit  # noqa: F401 - installs the lock

STAMP = (1.0, 1)  # a source file's (mtime, size), as numba stamps it


def _save_slowly(cache_dir: str, key: str, payload: bytes, start) -> None:
    """Save ``payload`` under ``key`` with the index read held open for 0.3 s: without a lock the other
    process reads the same index within that time and takes the same data-file number."""

    cache = IndexDataCacheFile(cache_dir, "kernel-10.py311", STAMP)
    read_index = cache._load_index

    def slow_read():
        index = read_index()
        time.sleep(0.3)
        return index

    cache._load_index = slow_read
    start.wait()
    cache.save(key, payload)


def test_concurrent_saves_of_two_signatures_keep_each_ones_code(tmp_path):
    ctx = multiprocessing.get_context("fork")
    start = ctx.Event()
    payloads = {"(float64,)": b"code for float64", "(int64,)": b"code for int64"}
    workers = [
        ctx.Process(target=_save_slowly, args=(str(tmp_path), key, data, start)) for key, data in payloads.items()
    ]
    for w in workers:
        w.start()
    start.set()
    for w in workers:
        w.join(30)
        assert w.exitcode == 0
    cache = IndexDataCacheFile(str(tmp_path), "kernel-10.py311", STAMP)
    index = cache._load_index()
    assert sorted(index) == sorted(payloads)  # neither save was lost
    assert len(set(index.values())) == 2  # two data files, one per signature
    for key, data in payloads.items():
        assert cache.load(key) == data, key


def test_a_kernel_compiles_caches_and_loads_through_the_lock(tmp_path, monkeypatch):
    """A cached njit function still compiles, saves and, in a new dispatcher, loads (numba's cache
    under the lock), giving the same numbers."""
    from numba.core.config import reload_config

    (tmp_path / "kernel_mod.py").write_text(
        "from drivers.jit import njit\n\n@njit(cache=True)\ndef twice(x):\n    return 2.0 * x\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    reload_config()
    try:
        first = importlib.import_module("kernel_mod")
        assert first.twice(np.arange(3.0)).tolist() == [0.0, 2.0, 4.0]
        assert sum(first.twice.stats.cache_misses.values()) == 1  # compiled and saved
        sys.modules.pop("kernel_mod")
        again = importlib.import_module("kernel_mod")
        assert again.twice(np.arange(3.0)).tolist() == [0.0, 2.0, 4.0]
        assert sum(again.twice.stats.cache_hits.values()) == 1  # loaded from the cache
        assert list((tmp_path / "cache").rglob("*.nbi.lock")), "the lock file sits beside the index"
    finally:
        sys.modules.pop("kernel_mod", None)
        monkeypatch.undo()
        reload_config()  # later tests in this process compile into their own cache again


def test_a_kernel_recompiles_when_a_kernel_it_compiles_in_from_another_file_changes(tmp_path):
    """drivers.jit.drop_stale_caches: numba stamps a cached kernel with its own file only, so a
    kernel that calls another file's kernel kept running the old callee after an edit (this test
    fails so without the call). With the call at the end of the caller's module, a fresh process
    runs the new callee."""
    import os
    import subprocess

    (tmp_path / "callee.py").write_text(
        "from drivers.jit import njit\n\n@njit(cache=True)\ndef value():\n    return 1\n"
    )
    (tmp_path / "caller.py").write_text(
        "import callee\nfrom drivers.jit import drop_stale_caches, njit\n\n@njit(cache=True)\ndef read():\n"
        "    return callee.value()\n\ndrop_stale_caches(globals(), [callee.__file__])\n"
    )
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
        "PYTHONPATH": os.pathsep.join([str(tmp_path), os.getcwd()]),
    }

    def run() -> str:
        return subprocess.run(
            [sys.executable, "-c", "import caller; print(caller.read())"],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()

    assert run() == "1" and run() == "1"  # compiled, then loaded from the cache
    time.sleep(0.05)
    (tmp_path / "callee.py").write_text(
        "from drivers.jit import njit\n\n@njit(cache=True)\ndef value():\n    return 2\n"
    )
    assert run() == "2"
