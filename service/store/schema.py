"""Schema upgrades of a database created by an earlier version: ``metadata.create_all`` makes the
tables that are missing but never changes one that exists, so every column added to an existing
table since is listed here and added with ``ALTER TABLE … ADD COLUMN`` (SQLite and PostgreSQL
alike; the column type is compiled for the database's dialect). Old rows read NULL in them, which
the store shows as the column's default (service.store.Store)."""

from __future__ import annotations

from sqlalchemy import inspect, text
from sqlalchemy.engine import Engine
from sqlalchemy.exc import DBAPIError

from service.store import tables

#: columns added to existing tables, per table, in the order they were added
ADDED_COLUMNS = {
    "datasets": ("tags", "notes", "bench_id"),  # issue 20: keeping the store tidy; 21: a lab
    "models": ("name", "tags", "notes", "bench_id"),
    "jobs": ("bench_id",),
}


#: the PostgreSQL advisory lock key that serialises schema creation between services starting at once
SCHEMA_LOCK_KEY = 0x45564342  # "EVCB"


def create_schema(engine: Engine) -> list[str]:
    """Create the missing tables and add the missing columns (``upgrade``), safely when several services
    of a lab start at once on one database: on PostgreSQL under a transaction-scoped advisory lock (a
    plain ``create_all`` races: both see no table, one CREATE fails with "already exists"); on SQLite,
    whose writers are serialised anyway, a CREATE that lost the race is retried (each retry's existence
    check sees the tables the others made, so there are at most as many as tables)."""
    if engine.dialect.name == "postgresql":
        with engine.begin() as conn:
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": SCHEMA_LOCK_KEY})
            tables.metadata.create_all(conn)
    else:
        for attempt in range(len(tables.metadata.tables) + 1):
            try:
                tables.metadata.create_all(engine)
                break
            except DBAPIError:
                if attempt == len(tables.metadata.tables):
                    raise
    return upgrade(engine)


def missing_columns(engine: Engine) -> dict[str, list[str]]:
    """The added columns the database does not have yet, per table."""
    inspector = inspect(engine)
    present = {name: {c["name"] for c in inspector.get_columns(name)} for name in ADDED_COLUMNS}
    return {
        name: [c for c in added if c not in present[name]]
        for name, added in ADDED_COLUMNS.items()
        if any(c not in present[name] for c in added)
    }


def upgrade(engine: Engine) -> list[str]:
    """Add the missing columns (nullable, no default); returns ``table.column`` of each one added. Two
    processes upgrading one database at once are harmless: a column the other added is not an error."""
    added = []
    for table_name, names in missing_columns(engine).items():
        for name in names:
            column = tables.metadata.tables[table_name].c[name]
            ddl = f"ALTER TABLE {table_name} ADD COLUMN {name} {column.type.compile(dialect=engine.dialect)}"
            try:
                with engine.begin() as conn:
                    conn.execute(text(ddl))
            except DBAPIError:
                if name in missing_columns(engine).get(table_name, []):
                    raise
                continue
            added.append(f"{table_name}.{name}")
    return added
