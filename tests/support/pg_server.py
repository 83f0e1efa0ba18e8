"""A throw-away PostgreSQL server for the store tests: initdb in a temp dir, a free port, a
unix socket in the same dir, trust auth for one user, torn down afterwards.

PostgreSQL refuses to run as root, so as root the cluster is owned and run by the
``postgres`` user (created by Debian's package). ``tests/setup/install_postgres.sh`` (run by
``make test``) installs the server when it is missing.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


class PostgresUnavailable(RuntimeError):
    """The server binaries are missing or the cluster would not start; the message says why."""


def find_bin_dir() -> Path:
    """The directory holding initdb and pg_ctl ($EVCBENCH_PG_BIN, Debian's layout, or $PATH)."""
    candidates = [os.environ.get("EVCBENCH_PG_BIN", "")]
    candidates += sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda p: int(p.split("/")[-2]), reverse=True)
    initdb = shutil.which("initdb")
    if initdb:
        candidates.append(str(Path(os.path.realpath(initdb)).parent))
    for directory in candidates:
        if directory and (Path(directory) / "initdb").exists() and (Path(directory) / "pg_ctl").exists():
            return Path(directory)
    raise PostgresUnavailable(
        "initdb/pg_ctl not found: run tests/setup/install_postgres.sh (make test does) or set EVCBENCH_PG_BIN"
    )


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def postgres_server() -> Iterator[str]:
    """Start a private cluster; yield an SQLAlchemy URL of an empty database; stop and delete it."""
    bin_dir = find_bin_dir()
    root = Path(tempfile.mkdtemp(prefix="evc-pg-"))
    as_user: list[str] = []
    if os.geteuid() == 0:
        runuser = shutil.which("runuser")
        if runuser is None:
            raise PostgresUnavailable("running as root and runuser is missing: cannot start PostgreSQL")
        shutil.chown(root, user="postgres", group=None)
        as_user = [runuser, "-u", "postgres", "--"]
    data, log = root / "data", root / "server.log"

    def run(*cmd: str) -> None:
        result = subprocess.run([*as_user, *cmd], capture_output=True, text=True, timeout=120, cwd=root)
        if result.returncode != 0:
            extra = log.read_text() if log.exists() else ""
            raise PostgresUnavailable(
                f"{' '.join(cmd)} failed ({result.returncode}):\n{result.stdout}{result.stderr}{extra}"
            )

    started = False
    try:
        run(str(bin_dir / "initdb"), "-D", str(data), "-U", "evc", "--auth=trust", "-E", "UTF8", "--no-sync")
        for attempt in range(3):
            # A port found free may be taken before the server binds it (another xdist worker's
            # cluster or service): then another one.
            port = free_port()
            options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
            try:
                run(str(bin_dir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(log), "-w", "-t", "60", "start")
                break
            except PostgresUnavailable as exc:
                if attempt == 2 or "already in use" not in str(exc):
                    raise
        started = True
        run(
            str(bin_dir / "createdb") if (bin_dir / "createdb").exists() else "createdb",
            "-h",
            "127.0.0.1",
            "-p",
            str(port),
            "-U",
            "evc",
            "evcbench",
        )
        yield f"postgresql+psycopg://evc@127.0.0.1:{port}/evcbench"
    finally:
        if started:
            subprocess.run(
                [*as_user, str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop"],
                capture_output=True,
                timeout=60,
                cwd=root,
            )
        shutil.rmtree(root, ignore_errors=True)
