"""Start-up recovery after a crash (``kill -9``, power loss): run once, before any job starts.

1. Every job still ``queued`` or ``running`` in the store belonged to a process that is gone: it
   is marked ``failed`` with the reason ``"interrupted by restart"``.
2. Every chunk directory under ``<data_dir>/partial/`` (service.store.chunks) holds samples an
   acquisition wrote before it died. If its job has no dataset yet, the chunks become a dataset
   marked ``partial`` (``partial_reason`` "interrupted by restart") and the job's result names it;
   it is never shown as complete. Then the directory is removed.

Each step is idempotent, so a crash during recovery is recovered at the next start: the dataset
is stored before the job is updated, and a job that already has a dataset gets no second one.
"""
from __future__ import annotations

import logging
from pathlib import Path

from service.datasets import units_for
from service.store import Store, utc_now
from service.store.chunks import chunk_dir, discard, partial_root, read_chunks, read_meta
from service.sweeps import trim_blocks

INTERRUPTED = "interrupted by restart"

log = logging.getLogger("evcbench.recovery")


def recover(store: Store) -> dict:
    """Fail the interrupted jobs and turn their chunks into partial datasets.

    Returns ``{"failed_jobs": [ids], "datasets": [ids created], "problems": [words]}``.
    """
    report: dict[str, list] = {"failed_jobs": [], "datasets": [], "problems": []}
    for job in store.unfinished_jobs():
        directory = chunk_dir(store.data_dir, job["id"])
        result = _rebuild(store, job["id"], directory, report) if directory.is_dir() else None
        store.update_job(job["id"], state="failed", error=INTERRUPTED, message=INTERRUPTED,
                         finished_at=utc_now(), **({"result": result} if result else {}))
        discard(directory)
        report["failed_jobs"].append(job["id"])
    root = partial_root(store.data_dir)
    if root.is_dir():  # chunks of jobs that ended but died before removing them, or of unknown jobs
        for directory in sorted(p for p in root.iterdir() if p.is_dir()):
            _rebuild(store, directory.name, directory, report)
            discard(directory)
    if report["failed_jobs"] or report["datasets"]:
        log.warning("recovery: %d interrupted job(s) marked failed, %d partial dataset(s) rebuilt",
                    len(report["failed_jobs"]), len(report["datasets"]))
    return report


def _rebuild(store: Store, job_id: str, directory: Path, report: dict) -> dict | None:
    """A partial dataset from the job's chunks (unless the job already has a dataset); its result."""
    existing = store.datasets_of_job(job_id)
    if existing:
        row = existing[-1]
        return {"dataset_id": row["id"], "samples": row["samples"], "partial": row["partial"]}
    meta = read_meta(directory)
    arrays, problems = read_chunks(directory)
    report["problems"].extend(f"job {job_id}: {p}" for p in problems)
    if meta is None:
        if arrays:
            report["problems"].append(f"job {job_id}: chunks without meta.json; not recoverable")
        return None
    if not arrays:
        return None
    samples = len(next(iter(arrays.values())))
    rate_hz = float(meta["sample_rate_hz"])
    row = store.add_dataset(arrays, {
        **meta, "job_id": job_id, "blocks": trim_blocks(meta.get("blocks") or [], samples, rate_hz),
        "units": meta.get("units") or units_for(arrays), "partial": True, "partial_reason": INTERRUPTED,
        "finished_at": None})
    report["datasets"].append(row["id"])
    return {"dataset_id": row["id"], "samples": row["samples"], "partial": True}
