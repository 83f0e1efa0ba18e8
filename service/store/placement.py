"""Where a dataset row's arrays are, and how they get there (the store's side of service.store.arrays).

A row's ``file`` is one of:

- ``arrays/<id>.npz``: in the data dir of the service that wrote it (no shared location, or rows
  written before one was configured);
- ``outbox/<id>.npz``: measured while the shared location could not be reached. The complete,
  checksummed file waits in the recording service's ``<data_dir>/outbox/``; ``flush`` uploads it
  and points the row at its key as soon as the location answers (after each later upload, at
  start-up and in ``evcbench store repair``). Until then other services get ArrayStoreUnavailable;
- anything else: a key in the shared location.

Writing to a shared location: the npz is written atomically to the outbox, uploaded (complete, one
PUT, checked), and only then is the row inserted; a failed insert deletes the object again. An
upload that fails keeps the file in the outbox when asked to (a sweep's bench time is not thrown
away) or raises ArrayStoreUnavailable with nothing stored (an import: the user still has the file).
No lock is held while talking to the location.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
from sqlalchemy import select, update

from service.store import tables
from service.store.arrays import QUARANTINE_PREFIX, ArrayStoreUnavailable
from service.store.files import IntegrityError, file_sha256, verify_file, write_arrays

OUTBOX_DIR = "outbox"
CACHE_DIR = "cache/arrays"
#: an object of the shared location that no row names is reported only when older than this: a
#: service may have uploaded it a moment ago and be about to insert its row
ORPHAN_GRACE_S = 3600.0
DATA_DIR_PREFIXES = ("arrays/", f"{OUTBOX_DIR}/")

log = logging.getLogger("evcbench.store")


def in_data_dir(file: str) -> bool:
    """True if a row's ``file`` is relative to a data dir (``arrays/…``, ``outbox/…``), not a shared key."""
    return file.startswith(DATA_DIR_PREFIXES)


def pending(file: str) -> bool:
    """True if a row's arrays still wait in an outbox for the shared location."""
    return file.startswith(f"{OUTBOX_DIR}/")


def place(
    store, dataset_id: str, arrays: dict[str, np.ndarray], keep_if_unreachable: bool
) -> tuple[str, str, Callable[[], None]]:
    """Write a new dataset's arrays where the store keeps them; returns (``file`` for the row, SHA-256,
    a function that removes them again if the row cannot be inserted)."""
    location = store.arrays
    if location is None:
        path, digest = write_arrays(store.arrays_dir, dataset_id, arrays)
        return str(path.relative_to(store.data_dir)), digest, lambda: path.unlink(missing_ok=True)
    path, digest = write_arrays(store.data_dir / OUTBOX_DIR, dataset_id, arrays)
    key = f"{dataset_id}.npz"
    try:
        location.put(path, key, digest)
    except ArrayStoreUnavailable as exc:
        if not keep_if_unreachable:
            path.unlink(missing_ok=True)
            raise
        log.warning(
            "%s: dataset %s kept in %s/%s, uploaded when the store answers",
            exc,
            dataset_id,
            store.data_dir,
            path.relative_to(store.data_dir),
        )
        return str(path.relative_to(store.data_dir)), digest, lambda: path.unlink(missing_ok=True)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    location.adopt(path, digest)

    def remove() -> None:
        location.forget(digest)
        try:
            location.delete(key)
        except ArrayStoreUnavailable as exc:  # the object stays, named by no row: store check reports it
            log.error("%s: could not delete %s of a dataset whose row was not stored", exc, location.where(key))

    return key, digest, remove


def local_path(store, row: dict) -> Path:
    """A local file of the row's arrays, verified against its SHA-256 (IntegrityError if missing or
    corrupt; ArrayStoreUnavailable if the shared location cannot be read)."""
    file, sha256 = row["file"], row["sha256"]
    if in_data_dir(file):
        path = store.data_dir / file
        if pending(file) and store.arrays is not None and not path.exists():
            raise ArrayStoreUnavailable(
                store.arrays.url,
                f"dataset {row['id']}'s arrays are still in the outbox "
                "of the service that recorded it, uploaded when it reaches the store",
            )
        verify_file(path, sha256)
        return path
    if store.arrays is None:
        raise IntegrityError(
            f"dataset {row['id']}'s arrays are {file} in a shared array location, and this "
            "service has none: start it with the lab's --array-url (EVCBENCH_ARRAY_URL)"
        )
    return store.arrays.fetch(file, sha256)


def size(store, row: dict) -> int:
    """Bytes of the row's arrays (0 if they are missing); ArrayStoreUnavailable if the location is down."""
    if in_data_dir(row["file"]) or store.arrays is None:
        path = store.data_dir / row["file"]
        return path.stat().st_size if path.is_file() else 0
    return store.arrays.size(row["file"]) or 0


def remove(store, row: dict) -> None:
    """Delete the row's arrays (its row is already gone). A shared location that stopped answering
    leaves the object, named by no row (``evcbench store check`` lists it); the log says so."""
    if in_data_dir(row["file"]) or store.arrays is None:
        (store.data_dir / row["file"]).unlink(missing_ok=True)
        return
    store.arrays.forget(row["sha256"])
    try:
        store.arrays.delete(row["file"])
    except ArrayStoreUnavailable as exc:
        log.error("%s: %s of deleted dataset %s was left behind", exc, store.arrays.where(row["file"]), row["id"])


def flush(store) -> list[dict]:
    """Upload this service's outbox: each pending dataset whose file is here goes to the shared
    location, its row is pointed at the key, the local file is dropped. Returns ``[{"id", "key",
    "bytes"}]`` of those done; stops at the first ArrayStoreUnavailable (raised). Idempotent: a crash
    between the upload and the row leaves the row pending, and the next flush uploads it again."""
    if store.arrays is None or not (store.data_dir / OUTBOX_DIR).is_dir():
        return []
    if not store.flush_lock.acquire(blocking=False):  # another thread of this service is at it
        return []
    try:
        d = tables.datasets
        with store.engine.connect() as conn:
            rows = [
                dict(r)
                for r in conn.execute(
                    select(d.c.id, d.c.file, d.c.sha256).where(d.c.file.like(f"{OUTBOX_DIR}/%"))
                ).mappings()
            ]
        done = []
        for row in rows:
            path = store.data_dir / row["file"]
            if not path.is_file() or file_sha256(path) != row["sha256"]:
                continue  # another service's outbox, or damaged (check says which)
            key = f"{row['id']}.npz"
            store.arrays.put(path, key, row["sha256"])
            with store.engine.begin() as conn:
                moved = conn.execute(
                    update(d).where(d.c.id == row["id"]).where(d.c.file == row["file"]).values(file=key)
                ).rowcount
            if not moved:
                continue  # another store on this data dir flushed it meanwhile
            store.arrays.adopt(path, row["sha256"])
            done.append({"id": row["id"], "key": key, "bytes": store.arrays.size(key) or 0})
            log.warning("outbox: dataset %s uploaded to %s", row["id"], store.arrays.where(key))
        return done
    finally:
        store.flush_lock.release()


def flush_quietly(store) -> list[dict]:
    """``flush``, with any failure logged instead of raised (the caller's own dataset is stored)."""
    try:
        return flush(store)
    except ArrayStoreUnavailable as exc:
        log.warning("outbox not flushed: %s", exc)
    except Exception:
        log.exception("outbox not flushed")
    return []


def check_row(store, row: dict, quick: bool) -> tuple[str, str] | None:
    """(problem kind, detail) of a row's arrays in the shared location or outbox, None if they are fine;
    ArrayStoreUnavailable if the location cannot be asked. Rows in ``arrays/`` are service.store.check's."""
    file, location = row["file"], store.arrays
    if pending(file):
        here = (store.data_dir / file).is_file()
        if here and not quick and file_sha256(store.data_dir / file) != row["sha256"]:
            return "corrupt_array", f"array file {file} (waiting for upload) does not match its sha256"
        where = f"in this service's {file}" if here else "in the outbox of the service that recorded it"
        target = location.url if location is not None else "a shared array location"
        return "pending_upload", f"arrays wait {where} for {target} (uploaded when it answers)"
    if location is None:
        return "missing_array", f"array {file} is in a shared location, and none is configured (--array-url)"
    if quick:
        found = location.size(file) is not None
        return None if found else ("missing_array", f"array {location.where(file)} is missing")
    try:
        digest = location.sha256(file)
    except IntegrityError:
        return "missing_array", f"array {location.where(file)} is missing"
    if digest != row["sha256"]:
        return "corrupt_array", f"array {location.where(file)} does not match its sha256"
    return None


def orphan_objects(store, datasets: list[dict]) -> list[tuple[str, int]]:
    """(key, bytes) of the shared location's arrays that no row names, older than ORPHAN_GRACE_S."""
    if store.arrays is None:
        return []
    named = {row["file"] for row in datasets}
    return [(key, size) for key, size, age in store.arrays.keys() if key not in named and age > ORPHAN_GRACE_S]


def restore_from_cache(store, row: dict) -> str | None:
    """Upload this service's verified cached copy of a row whose object is missing from the shared
    location (an S3 store that lost its data, a bucket re-created empty); where it was put back, or
    None when there is no cached copy whose SHA-256 is the row's."""
    cache_dir = getattr(store.arrays, "cache_dir", None)
    if cache_dir is None or pending(row["file"]) or in_data_dir(row["file"]):
        return None
    cached = Path(cache_dir) / f"{row['sha256']}.npz"
    if not cached.is_file() or file_sha256(cached) != row["sha256"]:
        return None
    store.arrays.put(cached, row["file"], row["sha256"])
    return store.arrays.where(row["file"])


def set_aside(store, key: str) -> str:
    """Move a shared object to the location's quarantine (kept, not deleted); its new location."""
    target = f"{QUARANTINE_PREFIX}{key}"
    n = 1
    while store.arrays.size(target) is not None:
        target, n = f"{QUARANTINE_PREFIX}{Path(key).stem}.{n}.npz", n + 1
    store.arrays.move(key, target)
    return store.arrays.where(target)
