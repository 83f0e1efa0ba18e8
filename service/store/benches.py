"""The lab's bench rows: one per service that has run on this database (several services, one store).

A service registers its bench at start-up (``upsert``), writes a heartbeat every few seconds
(``heartbeat``: state, running job, time) and marks itself ``stopped`` at a clean shut-down. The
table shares the store's metadata, so ``Store`` creates it with the others (an existing database
gains it at the next start, on SQLite and PostgreSQL alike). No bench ever writes another's row.
"""

from __future__ import annotations

from sqlalchemy import JSON, Column, Float, String, Table, Text, func, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.engine import Engine

from service.store.tables import datasets, metadata, models

#: What a bench's service last said it was doing: ``starting`` (registered, bench not open yet),
#: ``idle``, ``busy`` (a bench job runs: ``running_job_id``), ``stopped`` (clean shut-down).
BENCH_STATES = ("starting", "idle", "busy", "stopped")

benches = Table(
    "benches",
    metadata,
    Column("id", String(40), primary_key=True),  # the bench id (Settings.bench_id)
    Column("name", Text, nullable=False),  # the bench config's own name ([name] of its TOML)
    Column("bench", Text, nullable=False),  # the config the service was started with (--bench)
    Column("url", Text, nullable=False),  # where the service answers (Settings.public_url)
    Column("config", JSON, nullable=True),  # the bench's configuration snapshot
    Column("state", String(16), nullable=False),  # BENCH_STATES
    Column("running_job_id", String(40), nullable=True),
    Column("started_at", String(40), nullable=False),
    Column("heartbeat_at", String(40), nullable=False),
    Column("heartbeat_s", Float, nullable=False),  # the interval its heartbeat promises (s)
    Column("software_version", String(40), nullable=False),
    Column("instance", String(40), nullable=False),  # the service process that owns the row now
)


class BenchRows:
    """Register, beat, stop and list bench rows on one engine."""

    def __init__(self, engine: Engine):
        self.engine = engine

    def upsert(self, row: dict) -> None:
        """Insert the bench's row, or replace every field of an existing one (a restart)."""
        dialect = self.engine.dialect.name
        if dialect not in ("postgresql", "sqlite"):
            raise RuntimeError(f"benches: no upsert for the {dialect} dialect")
        statement = (pg_insert if dialect == "postgresql" else sqlite_insert)(benches).values(**row)
        statement = statement.on_conflict_do_update(
            index_elements=["id"], set_={k: v for k, v in row.items() if k != "id"}
        )
        with self.engine.begin() as conn:
            conn.execute(statement)

    def beat(self, bench_id: str, instance: str, **fields) -> bool:
        """Set some of state, running_job_id, heartbeat_at on the bench's row while ``instance`` owns
        it; False if it does not (another process took the bench id over) or the row is gone."""
        with self.engine.begin() as conn:
            result = conn.execute(
                update(benches).where(benches.c.id == bench_id).where(benches.c.instance == instance).values(**fields)
            )
            return bool(result.rowcount)

    def get(self, bench_id: str) -> dict | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(benches).where(benches.c.id == bench_id)).mappings().first()
        return dict(row) if row else None

    def list(self) -> list[dict]:
        """Every registered bench, by id."""
        with self.engine.connect() as conn:
            return [dict(row) for row in conn.execute(select(benches).order_by(benches.c.id)).mappings()]


def latest_models(engine: Engine, axis: str | None = None, parameters: bool = False) -> list[dict]:
    """Per bench and axis (or only ``axis``), its newest model (by ``created_at``) fitted on that bench's
    own data, and apart from it its newest fitted on imported data (any dataset imported: recorded on
    another stage): id, bench_id, axis, kind, effects, datasets, metrics, job_id, created_at,
    ``imported_data`` (and ``parameters`` with their sha256 if asked). A model fitted on an import
    describes the stage that recorded it, never its bench's: the two are kept apart. Models without a
    bench (stored before benches had ids) are left out."""
    imported = select(datasets.c.id).where(datasets.c.source == "import")
    light = select(models.c.id, models.c.bench_id, models.c.axis, models.c.datasets).where(
        models.c.bench_id.is_not(None)
    )
    if axis is not None:
        light = light.where(models.c.axis == axis)
    light = light.order_by(models.c.created_at.desc(), models.c.id.desc())
    with engine.connect() as conn:
        imported_ids = {row[0] for row in conn.execute(imported)}
        newest: dict[tuple, str] = {}
        for row in conn.execute(light):
            is_imported = any(d in imported_ids for d in row.datasets or ())
            newest.setdefault((row.bench_id, row.axis, is_imported), row.id)
        columns = [
            models.c.id,
            models.c.bench_id,
            models.c.axis,
            models.c.kind,
            models.c.effects,
            models.c.datasets,
            models.c.metrics,
            models.c.job_id,
            models.c.created_at,
        ]
        if parameters:
            columns += [models.c.parameters, models.c.parameters_sha256]
        query = select(*columns).where(models.c.id.in_(list(newest.values())))
        rows = {row["id"]: dict(row) for row in conn.execute(query).mappings()}
    return [
        {**rows[model_id], "imported_data": key[2]}
        for key, model_id in sorted(newest.items(), key=lambda kv: kv[0])
        if model_id in rows
    ]


def dataset_counts(engine: Engine) -> dict[str | None, dict[str, int]]:
    """Per bench (None: datasets stored before benches had ids), how many datasets it ``recorded`` and
    how many ``imported`` ones it stores: an import's bench_id is the service that stored it, but
    another stage recorded it, so it is never counted as the bench's recording."""
    imported = func.coalesce(datasets.c.source == "import", False)
    query = select(datasets.c.bench_id, imported, func.count()).group_by(datasets.c.bench_id, imported)
    out: dict[str | None, dict[str, int]] = {}
    with engine.connect() as conn:
        for bench_id, is_import, n in conn.execute(query):
            counts = out.setdefault(bench_id, {"recorded": 0, "imported": 0})
            counts["imported" if is_import else "recorded"] += int(n)
    return out
