"""Service settings, read from the environment (EVCBENCH_*) with safe defaults."""

from __future__ import annotations

import os
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path

#: Jobs waiting for the bench (sweeps, trajectories) beyond the running one; one more is refused
#: with 429 (service.runtime.jobs.QueueFull), so a runaway script cannot queue hours of bench time.
MAX_QUEUED_BENCH_JOBS = 16
#: Jobs waiting for a compute worker (identification, refinement, …), counted apart from the bench's.
MAX_QUEUED_COMPUTE_JOBS = 32
#: The Retry-After (s) a refused submission carries.
QUEUE_RETRY_AFTER_S = 5
#: How often a service writes its heartbeat into the lab's ``benches`` table (s; EVCBENCH_HEARTBEAT_S).
HEARTBEAT_INTERVAL_S = 5.0
#: A bench id: what the store, the API and a URL carry (lower-case letters, digits, ``-``, ``_``, ``.``).
BENCH_ID_PATTERN = re.compile(r"^[a-z0-9][a-z0-9._-]{0,39}$")


@dataclass(frozen=True)
class Settings:
    """Where the service keeps its data and which bench it drives.

    ``bench`` names a file in fixtures/benches/ (or a path to one); ``seed`` makes the
    emulated bench reproducible. ``host`` defaults to loopback. ``database_url`` is an
    SQLAlchemy URL (``postgresql+psycopg://…``); empty means SQLite in ``data_dir``.
    ``auth`` is ``tokens`` (every /api route but health needs a token) or ``off`` (loopback only).

    A lab (several services on one database): ``bench_id`` names this service's bench in every row it
    writes (default: derived from ``bench``, so a single bench needs nothing); ``public_url`` is where
    the other services and the lab page reach it (default ``http://host:port``, the machine's name
    for a wildcard host such as 0.0.0.0); ``heartbeat_s`` how often it says it is alive
    (service.runtime.heartbeat).
    """

    data_dir: Path = field(default_factory=lambda: Path(os.environ.get("EVCBENCH_DATA_DIR", "var")))
    bench: str = field(default_factory=lambda: os.environ.get("EVCBENCH_BENCH", "default"))
    seed: int | None = field(default_factory=lambda: _int_or_none(os.environ.get("EVCBENCH_SEED")))
    host: str = field(default_factory=lambda: os.environ.get("EVCBENCH_HOST", "127.0.0.1"))
    port: int = field(default_factory=lambda: int(os.environ.get("EVCBENCH_PORT", "8000")))
    database_url: str | None = field(default_factory=lambda: os.environ.get("EVCBENCH_DATABASE_URL") or None)
    auth: str = field(default_factory=lambda: os.environ.get("EVCBENCH_AUTH", "tokens"))
    #: ``process``: the bench engine runs in its own process (service.runtime.engine), so no request
    #: can delay the real-time loop or the stop; ``inline``: in this process (tests of internals)
    engine: str = field(default_factory=lambda: os.environ.get("EVCBENCH_ENGINE", "process"))
    #: the engine's stop port (service.runtime.stop_port) on ``host``: 0 lets the system pick a free
    #: one (GET /api/bench says which); set one to open it through a firewall
    stop_port: int = field(default_factory=lambda: _port_from_env("EVCBENCH_STOP_PORT"))
    #: the lab's shared array location (service.store.arrays): a path or file:// URL (an NFS mount),
    #: or s3://bucket/prefix (endpoint EVCBENCH_S3_ENDPOINT_URL, AWS_* credentials); empty: <data_dir>/arrays
    array_url: str | None = field(default_factory=lambda: os.environ.get("EVCBENCH_ARRAY_URL") or None)
    #: plug-in effects' directory (--effects-dir; EVCBENCH_EFFECTS_DIR, several joined by the path separator)
    effects_dir: str | None = field(default_factory=lambda: os.environ.get("EVCBENCH_EFFECTS_DIR") or None)
    bench_id: str = field(default_factory=lambda: os.environ.get("EVCBENCH_BENCH_ID", ""))
    public_url: str = field(default_factory=lambda: os.environ.get("EVCBENCH_PUBLIC_URL", ""))
    heartbeat_s: float = field(
        default_factory=lambda: float(os.environ.get("EVCBENCH_HEARTBEAT_S") or HEARTBEAT_INTERVAL_S)
    )

    def __post_init__(self) -> None:
        if self.auth not in ("tokens", "off"):
            raise ValueError(f"auth must be 'tokens' or 'off', not {self.auth!r}")
        if self.engine not in ("process", "inline"):
            raise ValueError(f"engine must be 'process' or 'inline', not {self.engine!r}")
        if not 0 <= self.stop_port <= 65535:
            raise ValueError(
                f"the stop port (--stop-port, EVCBENCH_STOP_PORT) must lie in 0-65535 (0: any free "
                f"port), not {self.stop_port!r}"
            )
        if not self.bench_id:
            object.__setattr__(self, "bench_id", bench_id_for(self.bench))
        if not BENCH_ID_PATTERN.match(self.bench_id):
            raise ValueError(
                f"bench_id must be 1-40 lower-case letters, digits, '.', '-' or '_' (starting with a "
                f"letter or digit), not {self.bench_id!r}"
            )
        if not self.public_url:  # a wildcard bind is reached by this machine's name
            host = socket.gethostname() if self.host in ("0.0.0.0", "::", "") else self.host
            object.__setattr__(self, "public_url", f"http://{host}:{self.port}")
        object.__setattr__(self, "public_url", self.public_url.rstrip("/"))
        if not 0.05 <= self.heartbeat_s <= 3600:
            raise ValueError(f"heartbeat_s must lie in 0.05-3600 s, not {self.heartbeat_s!r}")

    @property
    def resolved_database_url(self) -> str:
        """The metadata database: ``database_url`` if set, else SQLite at <data_dir>/evcbench.db."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{Path(self.data_dir).resolve() / 'evcbench.db'}"


def bench_id_for(bench: str) -> str:
    """The default bench id of a bench config name or path: its file stem, lower-cased, other
    characters than ``[a-z0-9._-]`` as ``-`` (``fixtures/benches/Creep 2.toml`` → ``creep-2``)."""
    stem = Path(bench).stem if bench.endswith(".toml") or "/" in bench else bench
    text = re.sub(r"[^a-z0-9._-]+", "-", stem.lower()).strip("-._")[:40]
    return text or "bench"


def _port_from_env(name: str) -> int:
    """A TCP port from the environment variable ``name`` (unset or empty: 0, any free port)."""
    text = os.environ.get(name) or "0"
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{name} must be a TCP port number (0-65535), not {text!r}") from None


def _int_or_none(text: str | None) -> int | None:
    return int(text) if text not in (None, "") else None
