"""Start-up recovery after a crash (``kill -9``, power loss): run once, before any job starts.

1. Every job of this bench (``store.bench_id``; or without a bench) still ``queued`` or ``running``
   in the store belonged to a process that is gone: it is marked ``failed`` with the reason
   ``"interrupted by restart"``. In a lab another bench's jobs are never touched; a store opened
   without a bench id (``evcbench store repair``) leaves the jobs of every bench online alone.
2. Every chunk directory under ``<data_dir>/partial/`` (service.store.chunks) holds samples an
   acquisition wrote before it died. If its job has no dataset yet, the chunks become a dataset
   marked ``partial`` (``partial_reason`` "interrupted by restart") and the job's result names it;
   it is never shown as complete. Then the directory is removed (with any torn chunk in it).
3. What killed writes left in the data dir (service.store.debris): temporary files of the atomic
   writer are deleted; array files no dataset row names are moved to ``quarantine/arrays/`` (never
   deleted: with the wrong database every completed dataset looks like that), and moved back when
   a row names them with the same SHA-256. A completed dataset's file is never touched.
4. Datasets measured while the shared array location was unreachable (service.store.placement's
   outbox) are uploaded, if it answers now.

Recovery first takes the data dir's lock (service.store.lock) and keeps it while the service runs,
so ``evcbench store repair`` cannot run beside it. If another live process holds it, step 3 is
skipped and the log says so. Every file removed or moved is logged with its path and size, and
listed in the report.

Each step is idempotent, so a crash during recovery is recovered at the next start: the dataset
is stored before the job is updated, and a job that already has a dataset gets no second one.
"""

from __future__ import annotations

import logging
from pathlib import Path

from service.runtime.heartbeat import is_online
from service.science.data.datasets import units_for
from service.science.data.plans import trim_blocks
from service.store import Store, debris, placement, utc_now
from service.store.arrays import ArrayStoreUnavailable
from service.store.chunks import chunk_dir, discard, partial_root, read_chunks, read_meta
from service.store.lock import StoreLock

INTERRUPTED = "interrupted by restart"

log = logging.getLogger("evcbench.recovery")


def recover(store: Store) -> dict:
    """Fail the interrupted jobs, turn their chunks into partial datasets, clear the debris.

    Returns ``{"failed_jobs": [ids], "datasets": [ids created], "problems": [words], "cleaned":
    [actions], "freed_bytes": n}`` and, with a shared array location, ``"uploaded"``: the outbox's
    uploads (service.store.placement.flush). An action is service.store.debris's (``action``, ``kind``,
    ``path``, ``bytes``, ``done``, maybe ``to``), or ``{"action": "delete", "kind": "chunks", …}`` for
    a chunk directory, whose ``dataset`` names the dataset its samples are in (or None).
    """
    report: dict = {"failed_jobs": [], "datasets": [], "problems": [], "cleaned": [], "freed_bytes": 0}
    owned = claim(store)
    for job in _unfinished_here(store):
        directory = chunk_dir(store.data_dir, job["id"])
        result = _rebuild(store, job["id"], directory, report) if directory.is_dir() else None
        store.update_job(
            job["id"],
            state="failed",
            error=INTERRUPTED,
            message=INTERRUPTED,
            finished_at=utc_now(),
            **({"result": result} if result else {}),
        )
        _discard(store, directory, result, report)
        report["failed_jobs"].append(job["id"])
    root = partial_root(store.data_dir)
    if root.is_dir():  # chunks of jobs that ended but died before removing them, or of unknown jobs
        for directory in sorted(p for p in root.iterdir() if p.is_dir()):
            _discard(store, directory, _rebuild(store, directory.name, directory, report), report)
    if owned:
        cleaned = debris.apply(store.data_dir, debris.find(store.data_dir, store.list_datasets()))
        report["cleaned"] += cleaned
        report["freed_bytes"] += sum(a["bytes"] for a in cleaned if a["done"] and a["action"] == "delete")
        report["problems"] += [f"{a['path']}: {debris.describe(a)}" for a in cleaned if not a["done"]]
    if owned and store.arrays is not None:  # measurements waiting for the shared location go up if it answers
        report["uploaded"] = []
        try:
            report["uploaded"] = placement.flush(store)
        except ArrayStoreUnavailable as exc:
            report["problems"].append(f"outbox not uploaded: {exc}")
            log.warning("recovery: outbox not uploaded: %s", exc)
    for action in report["cleaned"]:
        log.warning("recovery: %s: %s", action["path"], debris.describe(action))
    if report["failed_jobs"] or report["datasets"] or report["cleaned"]:
        log.warning(
            "recovery: %d interrupted job(s) marked failed, %d partial dataset(s) rebuilt, %d file(s) "
            "or chunk directories cleared, %s freed",
            len(report["failed_jobs"]),
            len(report["datasets"]),
            len(report["cleaned"]),
            debris.format_bytes(report["freed_bytes"]),
        )
    return report


def _unfinished_here(store: Store) -> list[dict]:
    """The unfinished jobs this process may fail: ``store.unfinished_jobs()`` (this bench's), less
    the jobs of other benches whose services are online."""
    live = {row["id"] for row in store.benches.list() if row["id"] != store.bench_id and is_online(row)}
    jobs = store.unfinished_jobs()
    for job in (j for j in jobs if j.get("bench_id") in live):
        log.info("recovery: job %s is bench %s's, whose service is online: left to it", job["id"], job["bench_id"])
    return [j for j in jobs if j.get("bench_id") not in live]


def claim(store: Store) -> bool:
    """Take the data dir's lock for this process (kept until ``store.close()``); False, with the
    reason in the log, if another live process holds it."""
    if store.owner_lock is not None and store.owner_lock.held:
        return True
    lock = StoreLock(store.data_dir)
    if not lock.acquire():
        log.error(
            "recovery: another process (pid %s) holds %s: is a second service or `evcbench store repair` "
            "running on this data dir? Leftover files are not cleared",
            lock.owner(),
            lock.path,
        )
        return False
    store.owner_lock = lock
    return True


def _discard(store: Store, directory: Path, result: dict | None, report: dict) -> None:
    """Remove a chunk directory and account for it in the report."""
    if not directory.is_dir():
        return
    size = sum(p.stat().st_size for p in directory.rglob("*") if p.is_file())
    discard(directory)
    report["cleaned"].append(
        {
            "action": "delete",
            "kind": "chunks",
            "path": str(directory.relative_to(store.data_dir)),
            "bytes": size,
            "done": not directory.exists(),
            "dataset": (result or {}).get("dataset_id"),
        }
    )
    report["freed_bytes"] += size


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
    row = store.add_dataset(
        arrays,
        {
            **meta,
            "job_id": job_id,
            "blocks": trim_blocks(meta.get("blocks") or [], samples, rate_hz),
            "units": meta.get("units") or units_for(arrays),
            "partial": True,
            "partial_reason": INTERRUPTED,
            "finished_at": None,
        },
        keep_if_unreachable=True,
    )
    report["datasets"].append(row["id"])
    return {"dataset_id": row["id"], "samples": row["samples"], "partial": True}
