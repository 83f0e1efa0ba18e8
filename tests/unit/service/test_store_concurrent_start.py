"""A lab's services starting at once on a brand-new database (issue 21): every one opens its store,
none fails with "table … already exists" (service.store.schema.create_schema), on PostgreSQL and SQLite."""

from __future__ import annotations

import threading
import uuid

import pytest
from sqlalchemy import create_engine, inspect, text

from service.store import Store
from service.store.tables import metadata

SERVICES = 6


def _open_at_once(url: str, tmp_path) -> list[BaseException]:
    """SERVICES threads open a Store on ``url`` behind a barrier; the errors they met."""
    barrier, errors = threading.Barrier(SERVICES), []

    def start(i: int) -> None:
        barrier.wait()
        try:
            Store(url, tmp_path / f"bench{i}").close()
        except BaseException as exc:  # noqa: BLE001 — every failure is the finding
            errors.append(exc)

    threads = [threading.Thread(target=start, args=(i,)) for i in range(SERVICES)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    return errors


@pytest.mark.postgres
def test_services_starting_at_once_on_a_new_postgresql_database(postgres_url, tmp_path):
    name = f"lab_{uuid.uuid4().hex[:8]}"
    admin = create_engine(
        postgres_url.replace("postgresql://", "postgresql+psycopg://", 1)
        if postgres_url.startswith("postgresql://")
        else postgres_url,
        isolation_level="AUTOCOMMIT",
    )
    with admin.connect() as conn:
        conn.execute(text(f"CREATE DATABASE {name}"))
    url = postgres_url.rsplit("/", 1)[0] + "/" + name
    try:
        for _ in range(3):  # the race is a matter of timing: three fresh starts, each on an empty schema
            assert _open_at_once(url, tmp_path) == []
            engine = create_engine(
                url.replace("postgresql://", "postgresql+psycopg://", 1) if url.startswith("postgresql://") else url
            )
            assert set(metadata.tables) <= set(inspect(engine).get_table_names())
            metadata.drop_all(engine)
            engine.dispose()
    finally:
        with admin.connect() as conn:
            conn.execute(text(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
        admin.dispose()


def test_services_starting_at_once_on_a_new_sqlite_database(tmp_path):
    for attempt in range(3):
        url = f"sqlite:///{tmp_path / f'lab{attempt}.db'}"
        assert _open_at_once(url, tmp_path) == []
        assert set(metadata.tables) <= set(inspect(create_engine(url)).get_table_names())
