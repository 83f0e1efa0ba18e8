"""A lab for the tests: several ``evcbench serve`` processes (tests/support/live_server.py) on one PostgreSQL
database, each on its own bench config, bench id and data dir, with a short heartbeat.

    with lab_services(tmp_path, fresh_database(postgres_url), ("default", "creep")) as lab:
        lab["creep"].url, lab["creep"].headers
"""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from sqlalchemy import create_engine, text

from tests.support.live_server import Server

#: The lab of issue 21: the default bench and two hidden-effect variants (fixtures/benches/).
LAB_BENCHES = ("default", "creep", "dynamics")
#: The services' heartbeat interval in the tests (s): a silent bench shows offline after 3 of them.
HEARTBEAT_S = 0.5


def fresh_database(postgres_url: str) -> str:
    """A new empty database on the session's PostgreSQL cluster (the store tests share the default one)."""
    name = f"lab_{uuid.uuid4().hex[:12]}"
    admin = create_engine(postgres_url, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
    finally:
        admin.dispose()
    return postgres_url.rsplit("/", 1)[0] + f"/{name}"


def lab_env(database_url: str, bench_id: str, heartbeat_s: float = HEARTBEAT_S) -> dict[str, str]:
    """The settings of one service of the lab (environment variables of ``evcbench serve``)."""
    return {
        "EVCBENCH_DATABASE_URL": database_url,
        "EVCBENCH_BENCH_ID": bench_id,
        "EVCBENCH_HEARTBEAT_S": str(heartbeat_s),
    }


def start_service(root: Path, database_url: str, bench: str, bench_id: str | None = None) -> Server:
    """One service of the lab on ``bench`` (bench id: the bench's name unless given)."""
    bench_id = bench_id or bench
    root.mkdir(parents=True, exist_ok=True)
    return Server(
        root / bench_id / "var", root / f"{bench_id}.log", bench=bench, seed=1, env=lab_env(database_url, bench_id)
    )


@contextlib.contextmanager
def lab_services(root: Path, database_url: str, benches=LAB_BENCHES) -> Iterator[dict[str, Server]]:
    """Start one service per bench at once; yield ``{bench: Server}``; stop those still running."""
    with ThreadPoolExecutor(max_workers=len(benches)) as pool:
        futures = {bench: pool.submit(start_service, root, database_url, bench) for bench in benches}
    started = {bench: f.result() for bench, f in futures.items() if f.exception() is None}
    try:
        for bench, future in futures.items():
            if future.exception() is not None:
                raise RuntimeError(f"the {bench} service did not start") from future.exception()
        yield started
    finally:
        for server in started.values():
            if server.proc.poll() is None:
                server.stop()
