"""A bench's identity in a lab: it registers at start-up, beats while it runs, and says ``stopped``
at a clean shut-down (the rows: service.store.benches).

- ``claim`` runs before start-up recovery: a bench id held by another live service (its heartbeat
  is fresh and it is not this host's dead process restarting) is refused with ``BenchIdInUse``, so
  one service never recovers or runs another's jobs.
- ``Heartbeat`` is a daemon thread with its own database engine (so its own connection): every
  ``interval_s`` it writes state (idle | busy), the running bench job and the time. It only reads
  an attribute of the job manager, so it never waits for the bench engine or the emergency stop,
  and a failed write is logged, never raised.
- A bench is ``online`` while its heartbeat is younger than ``OFFLINE_AFTER_HEARTBEATS`` of its own
  intervals (and it has not stopped); an offline bench's datasets and models stay in the store.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import uuid
from collections.abc import Callable
from datetime import UTC, datetime

from service import __version__
from service.runtime.settings import Settings
from service.store import Store, make_engine, utc_now
from service.store.benches import BenchRows

#: A bench whose heartbeat is older than this many of its intervals is shown offline.
OFFLINE_AFTER_HEARTBEATS = 3

log = logging.getLogger("evcbench.heartbeat")


class BenchIdInUse(RuntimeError):
    """Another live service holds this bench id (``field`` bench_id): give this one its own."""

    field = "bench_id"


def new_instance() -> str:
    """This process's name in the bench row: ``host:pid:random``."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def age_s(row: dict, now: datetime | None = None) -> float:
    """Seconds since the row's last heartbeat, to the millisecond the lab view reports (clocks of the
    lab's machines are assumed in step). ``is_online`` decides on this same figure, so a bench shown
    offline never reports an age within the limit (1.5 s against 3 × 0.5 s, rounded from 1.5004 s)."""
    now = now or datetime.now(UTC)
    return round((now - datetime.fromisoformat(row["heartbeat_at"].replace("Z", "+00:00"))).total_seconds(), 3)


def is_online(row: dict, now: datetime | None = None) -> bool:
    """The bench's service is running: not stopped, heartbeat within OFFLINE_AFTER_HEARTBEATS intervals."""
    return row["state"] != "stopped" and age_s(row, now) <= OFFLINE_AFTER_HEARTBEATS * row["heartbeat_s"]


def _holder_is_gone(row: dict) -> bool:
    """The row's owner is a process of this host that has died, or this very process (an app
    started again in one process): a restart, which may take the bench over."""
    host, _, rest = row["instance"].partition(":")
    pid_text = rest.partition(":")[0]
    if host != socket.gethostname() or not pid_text.isdigit():
        return False
    pid = int(pid_text)
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def held_elsewhere(store: Store, settings: Settings, instance: str | None = None) -> str | None:
    """Why another live service holds this bench id (what to do about it, in words), or None."""
    row = store.benches.get(settings.bench_id)
    if row is not None and row["instance"] != instance and is_online(row) and not _holder_is_gone(row):
        return (
            f"bench id {settings.bench_id!r} is held by a running service at {row['url']} (instance "
            f"{row['instance']}, heartbeat {age_s(row):.1f} s ago): give this service its own --bench-id "
            f"(EVCBENCH_BENCH_ID); if that service is gone, its bench shows offline after "
            f"{OFFLINE_AFTER_HEARTBEATS * row['heartbeat_s']:g} s"
        )
    return None


def claim(store: Store, settings: Settings, instance: str) -> None:
    """Register this service's bench (state ``starting``), unless another live service holds the id."""
    reason = held_elsewhere(store, settings, instance)
    if reason is not None:
        raise BenchIdInUse(reason)
    register(store.benches, settings, instance, "starting")


def register(rows: BenchRows, settings: Settings, instance: str, state: str, config: dict | None = None) -> None:
    """Insert or replace this bench's row (``config``: the bench's configuration snapshot)."""
    now = utc_now()
    name = (config or {}).get("parameters", {}).get("name") or settings.bench
    rows.upsert(
        {
            "id": settings.bench_id,
            "name": str(name),
            "bench": settings.bench,
            "url": settings.public_url,
            "config": config,
            "state": state,
            "running_job_id": None,
            "started_at": now,
            "heartbeat_at": now,
            "heartbeat_s": float(settings.heartbeat_s),
            "software_version": __version__,
            "instance": instance,
        }
    )


class Heartbeat:
    """The heartbeat thread. ``status() -> (state, running_job_id)`` is read at every beat; ``stop``
    ends the thread and writes ``stopped``."""

    def __init__(
        self,
        database_url: str,
        bench_id: str,
        instance: str,
        interval_s: float,
        status: Callable[[], tuple[str, str | None]],
    ):
        self.bench_id, self.instance, self.interval_s, self._status = bench_id, instance, float(interval_s), status
        self._engine = make_engine(database_url)  # its own pool: never waits for a request's connection
        self._rows = BenchRows(self._engine)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="evc-heartbeat", daemon=True)
        self.beats = 0  # heartbeats written
        self.failures = 0  # heartbeats that could not be written
        self._taken_over = False

    def start(self) -> Heartbeat:
        self.beat()
        self._thread.start()
        return self

    def beat(self, state: str | None = None, running_job_id: str | None = None) -> bool:
        """Write one heartbeat (``state`` given: that state, no job); False, logged, if it failed."""
        try:
            if state is None:
                state, running_job_id = self._status()
            written = self._rows.beat(
                self.bench_id, self.instance, state=state, running_job_id=running_job_id, heartbeat_at=utc_now()
            )
        except Exception as exc:  # noqa: BLE001 - a heartbeat never raises into anything
            self.failures += 1
            if self.failures == 1 or self.failures % 100 == 0:
                log.warning("heartbeat of bench %s not written (%d so far): %s", self.bench_id, self.failures, exc)
            return False
        if not written and not self._taken_over:
            self._taken_over = True
            log.error(
                "heartbeat: the row of bench %s belongs to another process now; this service no longer writes it",
                self.bench_id,
            )
        self.beats += int(written)
        return written

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.beat()

    def stop(self) -> None:
        """End the thread and mark the bench ``stopped`` (a clean shut-down)."""
        self._stop.set()
        self._thread.join(timeout=self.interval_s + 10.0)
        self.beat("stopped", None)
        self._engine.dispose()


def running_state(jobs) -> tuple[str, str | None]:
    """(``busy``, job id) while a bench job runs on the job manager ``jobs``, else (``idle``, None)."""
    job_id = jobs.running_bench_job
    return ("busy", job_id) if job_id else ("idle", None)
