"""Where a store lives, as a small picklable value: a Dask task gets the address and opens the
store itself (a Store holds an engine and connections, which never travel to another process).

Each process keeps one open Store per address (``open_store``), so the tasks a worker runs share
its connections instead of creating the tables' metadata again for every dataset.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

from service.runtime.settings import Settings
from service.store import Store


@dataclass(frozen=True)
class StoreAddress:
    """A store's metadata database URL (SQLAlchemy), its data directory, and the shared array
    location (a filesystem path or ``s3://bucket/prefix``; None: the arrays under ``data_dir``)."""

    database_url: str
    data_dir: str
    array_url: str | None = None

    @classmethod
    def of(cls, database_url: str | None, data_dir: str | Path, array_url: str | None = None) -> StoreAddress:
        """The address of a store; ``database_url`` None means the embedded SQLite file in
        ``data_dir``, as ``evcbench serve`` opens it (Settings.resolved_database_url)."""
        settings = Settings(data_dir=Path(data_dir).resolve(), database_url=database_url)
        return cls(settings.resolved_database_url, str(settings.data_dir), array_url)


_OPEN: dict[StoreAddress, Store] = {}
_LOCK = threading.Lock()


def open_store(address: StoreAddress) -> Store:
    """The Store at ``address``, opened once per process."""
    with _LOCK:
        store = _OPEN.get(address)
        if store is None:
            store = _OPEN[address] = Store(address.database_url, Path(address.data_dir), array_url=address.array_url)
        return store


def close_stores() -> None:
    """Close every store this process opened (``open_store``)."""
    with _LOCK:
        for store in _OPEN.values():
            store.close()
        _OPEN.clear()
