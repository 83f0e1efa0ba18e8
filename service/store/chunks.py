"""Crash-safe acquisition: samples of a running job written in ~1 s chunks under
``<data_dir>/partial/<job_id>/``.

While a sweep or trajectory runs, its samples arrive block by block. ``ChunkWriter`` keeps them
in memory and, once ``CHUNK_S`` seconds of samples (at the acquisition's sample rate) have
accumulated, writes them as ``chunk_<n>.npz`` atomically (temporary file, fsync, rename, fsync of
the directory). ``meta.json`` beside them holds what the dataset row needs (name, source, axes,
sample_rate_hz, blocks, plan, config, units, job_id, started_at). So after a ``kill -9`` at most
the last second of samples is lost, and ``service.runtime.recovery`` can rebuild a dataset marked partial
from the chunks. When the job stores its dataset normally, ``discard`` removes the directory.

A chunk file is either absent or whole (the rename is atomic); a leftover ``.*.tmp`` file is an
unfinished write and is ignored. Chunks are numbered from 1 without gaps; reading stops at the
first missing or unreadable one, so what is returned is always a prefix of the acquisition.
"""

from __future__ import annotations

import io
import json
import logging
import queue
import shutil
import threading
from pathlib import Path

import numpy as np

from service.store import clean_json
from service.store.files import write_arrays, write_bytes_atomic

PARTIAL_DIR = "partial"
META_FILE = "meta.json"
CHUNK_S = 1.0  # seconds of samples per chunk (at the acquisition's sample rate)


def partial_root(data_dir: Path) -> Path:
    """``<data_dir>/partial``: one directory per job that was acquiring."""
    return Path(data_dir) / PARTIAL_DIR


def chunk_dir(data_dir: Path, job_id: str) -> Path:
    return partial_root(data_dir) / job_id


class ChunkWriter:
    """Appends a job's samples to fsync'ed chunk files of about ``chunk_s`` seconds each.

    ``meta`` is the dataset metadata known at the start (see ``Store.add_dataset``; it needs
    ``sample_rate_hz``). Arrays passed to ``append`` are the new rows only, one 1-D array per
    column, all the same length, the same columns every time. The files are written by a
    background thread, so the acquisition loop that calls ``append`` never waits for the disk
    (compression and fsync take tens of milliseconds, longer than a control period).
    """

    def __init__(self, data_dir: Path, job_id: str, meta: dict, chunk_s: float = CHUNK_S):
        self.directory = chunk_dir(data_dir, job_id)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.rows_per_chunk = max(1, int(round(chunk_s * float(meta["sample_rate_hz"]))))
        self._pending: dict[str, list[np.ndarray]] = {}
        self._pending_rows = 0
        self._queued = 0  # chunks handed to the writer thread
        self._rows_handed = 0  # rows in those chunks
        self.chunks = 0  # chunk files written
        self.rows_written = 0  # rows in those files
        self.error: BaseException | None = None  # the writer's failure, if any (the run goes on)
        write_bytes_atomic(self.directory / META_FILE, json.dumps(clean_json(meta)).encode())
        self._queue: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._write_loop, name=f"chunks-{job_id}", daemon=True)
        self._thread.start()

    @property
    def rows_seen(self) -> int:
        """Rows handed to ``append`` so far (written, queued or pending)."""
        return self._rows_handed + self._pending_rows

    def append(self, arrays: dict[str, np.ndarray]) -> None:
        """Add new rows (copied); queues a chunk once ``rows_per_chunk`` rows are pending."""
        lengths = {len(v) for v in arrays.values()}
        if len(lengths) != 1:
            raise ValueError(f"chunk columns differ in length: {sorted(lengths)}")
        n = lengths.pop()
        if n == 0:
            return
        for name, values in arrays.items():
            self._pending.setdefault(name, []).append(np.array(values, copy=True))
        self._pending_rows += n
        if self._pending_rows >= self.rows_per_chunk:
            self._hand_over()

    def flush(self) -> None:
        """Queue whatever is pending and wait until every queued chunk is on disk."""
        self._hand_over()
        self._queue.join()

    def discard(self) -> None:
        """Stop the writer and remove the job's chunk directory (its dataset is stored, or nothing
        is to be kept)."""
        self._queue.put(None)
        self._thread.join(timeout=60)
        discard(self.directory)

    def warnings(self) -> list[str]:
        """What a job result should say about the chunks: a write that failed (crash safety was lost)."""
        return (
            []
            if self.error is None
            else [
                f"the running record could not be written to disk ({self.error}): "
                "a crash during the run would have lost it"
            ]
        )

    def _hand_over(self) -> None:
        if not self._pending_rows:
            return
        arrays = {name: np.concatenate(parts) for name, parts in self._pending.items()}
        self._queued += 1
        self._queue.put((self._queued, arrays))
        self._rows_handed += self._pending_rows
        self._pending, self._pending_rows = {}, 0

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                if self.error is None:
                    number, arrays = item
                    try:
                        write_arrays(self.directory, f"chunk_{number:06d}", arrays)
                        self.chunks += 1
                        self.rows_written += len(next(iter(arrays.values())))
                    except BaseException as exc:  # a full disk: keep running, later chunks would leave a gap
                        self.error = exc
                        logging.getLogger(__name__).error(
                            "job %s: writing chunk %d failed (%s); this run is no longer recoverable after a "
                            "crash, its dataset is still stored when it ends",
                            self.directory.name,
                            number,
                            exc,
                        )
            finally:
                self._queue.task_done()


def discard(directory: Path) -> None:
    shutil.rmtree(directory, ignore_errors=True)


def read_meta(directory: Path) -> dict | None:
    """The metadata written at the start, or None if it is missing or unreadable."""
    try:
        return json.loads((directory / META_FILE).read_text())
    except (OSError, ValueError):
        return None


def chunk_files(directory: Path) -> list[Path]:
    """The chunk files present, in order (temporary files of unfinished writes excluded)."""
    return sorted(p for p in directory.glob("chunk_*.npz") if not p.name.startswith("."))


def read_chunks(directory: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """Concatenate the chunks ``chunk_000001.npz``, ``chunk_000002.npz``, … up to the first one
    missing or unreadable. Returns (arrays, problems in words); arrays is empty if none is read."""
    parts: dict[str, list[np.ndarray]] = {}
    problems: list[str] = []
    files = chunk_files(directory)
    for index, path in enumerate(files, start=1):
        if path.name != f"chunk_{index:06d}.npz":
            problems.append(f"{directory.name}: chunk {index} is missing; later chunks ignored")
            break
        try:
            with np.load(io.BytesIO(path.read_bytes()), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
        except (OSError, ValueError, EOFError) as exc:
            problems.append(f"{path.name}: unreadable ({exc}); it and later chunks ignored")
            break
        if parts and set(arrays) != set(parts):
            problems.append(f"{path.name}: columns differ from the first chunk; it and later chunks ignored")
            break
        for name, values in arrays.items():
            parts.setdefault(name, []).append(values)
    return {name: np.concatenate(values) for name, values in parts.items()}, problems
