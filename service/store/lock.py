"""Who owns a data directory: an exclusive advisory lock on ``<data_dir>/service.lock``.

The running service takes it at start-up (``service.runtime.recovery``) and keeps it until the store is
closed; ``evcbench store repair`` takes it too, so the two never touch the same files at once.
The kernel drops the lock when its process dies, even by ``kill -9``: a lock that cannot be taken
always means a live owner. The file holds the owner's pid, for messages only.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_FILE = "service.lock"


class StoreLock:
    """``acquire()`` (non-blocking: True if taken), ``owner()`` (the pid written by the holder, or
    None), ``release()``. Re-acquiring a lock this object holds is a no-op that returns True."""

    def __init__(self, data_dir: Path):
        self.path = Path(data_dir) / LOCK_FILE
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> bool:
        if self._fd is not None:
            return True
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return True

    def owner(self) -> int | None:
        """The pid the holder wrote (the holder may have died since: then ``acquire`` succeeds)."""
        try:
            return int(self.path.read_text().strip())
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)
