"""The store: metadata in SQL (SQLite in WAL mode by default, PostgreSQL by URL), arrays in files
(in the data dir, or in a location the lab's services share: service.store.arrays and .placement).

Nothing is updated in place except a job's state and the labels (name, tags, notes) of a dataset
or model: their data and parameters are written once, and may be deleted (service.store.tidy). A
dataset's arrays are written (atomically) before its row; if the row cannot be inserted the
file is removed again, so a failed request leaves the store as it was.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import create_engine, event, insert, or_, select, update
from sqlalchemy.engine import Engine

from service import __version__
from service.store import placement, schema, tables, tidy
from service.store.arrays import ArrayStoreUnavailable, open_location
from service.store.benches import BenchRows
from service.store.files import IntegrityError, StoredArrays, load_npz
from service.store.rows import DatasetRow, JobRow, ModelRow
from service.store.tokens import TokenRows

__all__ = [
    "Store",
    "NotFoundError",
    "IntegrityError",
    "ArrayStoreUnavailable",
    "StoredArrays",
    "DatasetRow",
    "ModelRow",
    "JobRow",
    "utc_now",
    "clean_json",
    "json_sha256",
]

TERMINAL_STATES = ("succeeded", "failed", "cancelled")


class NotFoundError(KeyError):
    """No record with that id. ``field`` names what was looked up (dataset, model, job)."""

    def __init__(self, field: str, record_id: str):
        super().__init__(f"no {field} with id {record_id!r}")
        self.field, self.record_id = field, record_id

    def __str__(self) -> str:
        return self.args[0]


def utc_now() -> str:
    """Now as an ISO-8601 UTC string with microseconds (sorts as text)."""
    return datetime.now(UTC).isoformat(timespec="microseconds").replace("+00:00", "Z")


def clean_json(value: Any) -> Any:
    """A JSON-safe copy: numpy scalars/arrays to Python, NaN and ±inf to None, tuples to lists."""
    if isinstance(value, dict):
        return {str(k): clean_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return clean_json(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def json_sha256(value: Any) -> str:
    """SHA-256 of the canonical JSON text of ``value`` (sorted keys, no spaces)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def new_id(prefix: str) -> str:
    return f"{prefix}_{uuid.uuid4().hex[:16]}"


def make_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite gets WAL mode and foreign keys on every connection."""
    if url.startswith("postgresql://") or url.startswith("postgres://"):
        url = "postgresql+psycopg://" + url.split("://", 1)[1]  # psycopg 3 is the installed driver
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_connection, _record):
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.close()

        return engine
    return create_engine(url, pool_pre_ping=True)


class Store:
    """Datasets, models and jobs of one service instance (in a lab, of every bench on the database).

    ``bench_id`` is the bench of the service that opened it (set by the app): every dataset and job
    it adds carries it, and ``unfinished_jobs`` returns only that bench's. None (tools such as
    ``evcbench store repair``, tests) adds rows without a bench and sees every job.

    ``array_url`` is the lab's shared array location (service.store.arrays.open_location: a path,
    ``file://`` or ``s3://bucket/prefix`` URL); None keeps the arrays in ``<data_dir>/arrays``."""

    bench_id: str | None = None

    def __init__(self, database_url: str, data_dir: Path, *, array_url: str | None = None):
        self.data_dir = Path(data_dir)
        self.arrays_dir = self.data_dir / "arrays"
        self.data_dir.mkdir(parents=True, exist_ok=True)
        #: the shared array location (None: the data dir's arrays/); its URL names it in messages
        self.arrays = open_location(array_url, self.data_dir / placement.CACHE_DIR)
        self.array_url = array_url or None
        self.flush_lock = threading.Lock()  # one outbox upload at a time (service.store.placement.flush)
        self.engine = make_engine(database_url)
        schema.create_schema(self.engine)  # tables, and columns added since the database was created
        #: the API token rows (hashes only; see service.security.auth)
        self.tokens = TokenRows(self.engine)
        #: the lab's registered benches (service.store.benches; service.runtime.heartbeat writes them)
        self.benches = BenchRows(self.engine)
        #: the data dir's lock (service.store.lock) while this store's process owns it: the running
        #: service (taken by service.runtime.recovery) or ``evcbench store repair``; released by ``close``
        self.owner_lock = None

    @property
    def backend(self) -> str:
        return self.engine.dialect.name

    def close(self) -> None:
        if self.owner_lock is not None:
            self.owner_lock.release()
        self.engine.dispose()

    # ------------------------------------------------------------------ datasets
    def add_dataset(self, arrays: dict[str, np.ndarray], meta: dict, keep_if_unreachable: bool = False) -> DatasetRow:
        """Store a dataset: arrays to a checksummed file (uploaded to the shared location, if any),
        then its row. Returns the record. If the shared location cannot be reached the arrays wait in
        the outbox when ``keep_if_unreachable`` (a measurement), else ArrayStoreUnavailable and nothing
        is stored (service.store.placement).

        ``meta`` holds name, source, axes, sample_rate_hz, blocks and optionally plan, config,
        units, partial, partial_reason, job_id, started_at and finished_at (of an acquisition).
        """
        dataset_id = new_id("ds")
        samples = len(next(iter(arrays.values()))) if arrays else 0
        row = {
            "id": dataset_id,
            "name": meta.get("name") or dataset_id,
            "source": meta["source"],
            "axes": list(meta["axes"]),
            "samples": samples,
            "sample_rate_hz": float(meta["sample_rate_hz"]),
            "blocks": clean_json(meta.get("blocks", [])),
            "plan": clean_json(meta.get("plan")),
            "config": clean_json(meta.get("config")),
            "units": clean_json(meta.get("units", {})),
            "software_version": __version__,
            "partial": bool(meta.get("partial", False)),
            "partial_reason": meta.get("partial_reason"),
            "job_id": meta.get("job_id"),
            "started_at": meta.get("started_at"),
            "finished_at": meta.get("finished_at"),
            "created_at": utc_now(),
            "tags": list(meta.get("tags") or []),
            "notes": meta.get("notes"),
            "bench_id": self.bench_id,
        }
        file, digest, remove = placement.place(self, dataset_id, arrays, keep_if_unreachable)
        row.update(file=file, sha256=digest)
        try:
            with self.engine.begin() as conn:
                conn.execute(insert(tables.datasets).values(**row))
        except BaseException:
            remove()
            raise
        if self.arrays is not None and not placement.pending(file):
            placement.flush_quietly(self)  # the location answers: earlier measurements waiting go up too
        return row

    def get_dataset(self, dataset_id: str) -> DatasetRow:
        return tidy.with_labels(self._get(tables.datasets, dataset_id, "dataset"))

    def list_datasets(self, bench_id: str | None = None) -> list[DatasetRow]:
        """Every dataset (of every bench), oldest first; ``bench_id``: only that bench's."""
        return [tidy.with_labels(row) for row in self._list(tables.datasets, bench_id=bench_id)]

    def label_dataset(self, dataset_id: str, **labels: Any) -> DatasetRow:
        """Set some of a dataset's ``name``, ``tags`` and ``notes``; the updated record."""
        tidy.set_labels(self, tables.datasets, dataset_id, labels)
        return self.get_dataset(dataset_id)

    def delete_dataset(self, dataset_id: str, cascade: bool = False) -> dict:
        """Delete a dataset and its arrays (service.store.tidy.delete_dataset: InUseError naming the
        models fitted on it unless ``cascade``, which deletes them and their descendants too)."""
        return tidy.delete_dataset(self, dataset_id, cascade)

    def load_arrays(self, dataset_id: str) -> dict[str, np.ndarray]:
        """The dataset's arrays, verified against the stored checksum."""
        return load_npz(placement.local_path(self, self.get_dataset(dataset_id)))

    def open_arrays(self, dataset_id: str) -> StoredArrays:
        """The dataset's arrays opened lazily (memory-mapped or read a range at a time), after the
        file was verified against the stored checksum (read in blocks). Close it when done."""
        return StoredArrays(placement.local_path(self, self.get_dataset(dataset_id)))

    # ------------------------------------------------------------------ models
    def add_model(self, record: dict) -> ModelRow:
        """Store an identified model (axis, kind, effects, datasets, parameters, metrics, …)."""
        parameters = clean_json(record["parameters"])
        row = {
            "id": new_id("md"),
            "axis": record["axis"],
            "kind": record["kind"],
            "effects": list(record.get("effects", [])),
            "parent_id": record.get("parent_id"),
            "datasets": list(record["datasets"]),
            "options": clean_json(record.get("options")),
            "parameters": parameters,
            "parameters_sha256": json_sha256(parameters),
            "metrics": clean_json(record.get("metrics", {})),
            "software_version": __version__,
            "job_id": record.get("job_id"),
            "created_at": utc_now(),
            "name": record.get("name"),
            "tags": list(record.get("tags") or []),
            "notes": record.get("notes"),
        }
        with self.engine.begin() as conn:
            row["bench_id"] = self._bench_of_datasets(conn, row["datasets"])
            conn.execute(insert(tables.models).values(**row))
        return row

    def _bench_of_datasets(self, conn, dataset_ids: list[str]) -> str | None:
        """A model's bench: the one its datasets were all recorded on, else (mixed, or datasets
        without a bench) this store's."""
        query = select(tables.datasets.c.bench_id).where(tables.datasets.c.id.in_(dataset_ids)).distinct()
        found = {value for (value,) in conn.execute(query)}
        return found.pop() if len(found) == 1 and None not in found else self.bench_id

    def get_model(self, model_id: str) -> ModelRow:
        """The model's record; IntegrityError if its parameters no longer match their checksum."""
        row = tidy.with_labels(self._get(tables.models, model_id, "model"))
        if json_sha256(row["parameters"]) != row["parameters_sha256"]:
            raise IntegrityError(f"model {model_id}: parameters do not match their sha256")
        return row

    def list_models(self, bench_id: str | None = None) -> list[ModelRow]:
        """Every model (of every bench), oldest first; ``bench_id``: only that bench's."""
        return [tidy.with_labels(row) for row in self._list(tables.models, bench_id=bench_id)]

    def label_model(self, model_id: str, **labels: Any) -> ModelRow:
        """Set some of a model's ``name``, ``tags`` and ``notes``; the updated record."""
        tidy.set_labels(self, tables.models, model_id, labels)
        return self.get_model(model_id)

    def delete_model(self, model_id: str, cascade: bool = False) -> dict:
        """Delete a model (service.store.tidy.delete_model: InUseError naming its children unless
        ``cascade``, which deletes its descendants too)."""
        return tidy.delete_model(self, model_id, cascade)

    # ------------------------------------------------------------------ jobs
    def add_job(self, kind: str, params: dict | None, needs_bench: bool) -> JobRow:
        row = {
            "id": new_id("job"),
            "kind": kind,
            "needs_bench": needs_bench,
            "state": "queued",
            "progress": 0.0,
            "message": "queued",
            "params": clean_json(params),
            "result": None,
            "error": None,
            "created_at": utc_now(),
            "started_at": None,
            "finished_at": None,
            "bench_id": self.bench_id,
        }
        with self.engine.begin() as conn:
            conn.execute(insert(tables.jobs).values(**row))
        return row

    def update_job(self, job_id: str, **fields: Any) -> None:
        """Set some of state, progress, message, result, error, started_at, finished_at."""
        if "result" in fields:
            fields["result"] = clean_json(fields["result"])
        with self.engine.begin() as conn:
            conn.execute(update(tables.jobs).where(tables.jobs.c.id == job_id).values(**fields))

    def update_progress(self, job_id: str, progress: float, message: str | None) -> None:
        """Progress (0..1) and message of a job still queued or running; a late write after the job
        ended changes nothing."""
        with self.engine.begin() as conn:
            conn.execute(
                update(tables.jobs)
                .where(tables.jobs.c.id == job_id)
                .where(tables.jobs.c.state.not_in(TERMINAL_STATES))
                .values(progress=progress, message=message)
            )

    def get_job(self, job_id: str) -> JobRow:
        return self._get(tables.jobs, job_id, "job")

    def list_jobs(
        self,
        limit: int | None = 100,
        bench_id: str | None = None,
        kind: str | None = None,
        model_id: str | None = None,
        state: str | None = None,
    ) -> list[JobRow]:
        """The newest ``limit`` jobs (of every bench), newest first; ``bench_id``: only that bench's;
        ``kind``: only that kind; ``state``: only those in that state; ``model_id``: only those started
        from that model (``params.model_id``) or that ended at it (``result.final_model_id``, a discover
        run's last model)."""
        job, where = tables.jobs.c, []
        if kind is not None:
            where.append(job.kind == kind)
        if state is not None:
            where.append(job.state == state)
        if model_id is not None:
            started = job.params["model_id"].as_string() == model_id
            where.append(or_(started, job.result["final_model_id"].as_string() == model_id))
        return self._list(tables.jobs, limit=limit, newest_first=True, bench_id=bench_id, where=where)

    def unfinished_jobs(self) -> list[JobRow]:
        """This bench's jobs neither succeeded, failed nor cancelled (queued or running), oldest first:
        those with this store's ``bench_id`` or none (written before benches had ids); every bench's
        when ``bench_id`` is None. Another bench's jobs are its own service's to run or recover."""
        query = (
            select(tables.jobs)
            .where(tables.jobs.c.state.not_in(TERMINAL_STATES))
            .order_by(tables.jobs.c.created_at, tables.jobs.c.id)
        )
        if self.bench_id is not None:
            query = query.where(or_(tables.jobs.c.bench_id == self.bench_id, tables.jobs.c.bench_id.is_(None)))
        with self.engine.connect() as conn:
            return [dict(row) for row in conn.execute(query).mappings()]

    def datasets_of_job(self, job_id: str) -> list[DatasetRow]:
        """The datasets a job stored (normally none or one)."""
        query = select(tables.datasets).where(tables.datasets.c.job_id == job_id).order_by(tables.datasets.c.created_at)
        with self.engine.connect() as conn:
            return [dict(row) for row in conn.execute(query).mappings()]

    # ------------------------------------------------------------------ helpers
    def _get(self, table, record_id: str, field: str) -> dict:
        with self.engine.connect() as conn:
            row = conn.execute(select(table).where(table.c.id == record_id)).mappings().first()
        if row is None:
            raise NotFoundError(field, record_id)
        return dict(row)

    def _list(
        self, table, limit: int | None = None, newest_first: bool = False, bench_id: str | None = None, where=()
    ) -> list[dict]:
        order = table.c.created_at.desc() if newest_first else table.c.created_at
        query = select(table).order_by(order, table.c.id).where(*where)
        if bench_id is not None:
            query = query.where(table.c.bench_id == bench_id)
        if limit is not None:
            query = query.limit(limit)
        with self.engine.connect() as conn:
            return [dict(row) for row in conn.execute(query).mappings()]
