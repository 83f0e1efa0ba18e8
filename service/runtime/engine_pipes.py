"""The bench engine's pipe ends (service.runtime.engine_process): how a message is answered, how
a plan's events leave without blocking its loop, and how an exception crosses the pipe."""

from __future__ import annotations

import pickle
import queue
import threading
import time
from multiprocessing.connection import Connection

from drivers.interfaces import DriverError


def picklable(exc: BaseException) -> BaseException:
    """The exception itself if it survives a pickle round trip, else a DriverError saying what it was."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception may fail to rebuild on the other side
        return DriverError(f"{type(exc).__name__}: {exc}")


def serve_pipe(conn: Connection, handle, lock: threading.Lock | None, on_eof) -> None:
    """Answer each message on ``conn`` with ``("ok", value)`` or ``("error", exception)``."""
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            on_eof()
            return
        try:
            reply = ("ok", handle(message))
        except Exception as exc:  # noqa: BLE001 - the caller gets it; the engine lives on
            reply = ("error", picklable(exc))
        try:
            if lock is None:
                conn.send(reply)
            else:
                with lock:
                    conn.send(reply)
        except (EOFError, OSError):
            on_eof()
            return


class Outbox:
    """The plan pipe's sending side, on a thread of its own: a plan's ``emit`` never blocks its
    loop when the web process is slow to read (its socket buffer full while it collects garbage,
    say); events and the answer leave in the order they were put."""

    def __init__(self, conn: Connection, on_eof):
        self._conn, self._on_eof = conn, on_eof
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._count_lock = threading.Lock()
        self._unsent, self._waiting_since = 0, 0.0
        self._thread = threading.Thread(target=self._send_all, name="evc-engine-outbox", daemon=True)
        self._thread.start()

    def put(self, message: tuple) -> None:
        with self._count_lock:
            if self._unsent == 0:
                self._waiting_since = time.monotonic()  # the clock starts with the first unsent message
            self._unsent += 1
        self._queue.put(message)

    def unsent_for_s(self) -> float:
        """While messages wait: how long since the reader last took one (or since the first of them
        was put, if later), in s; 0 when none waits. A reader that takes nothing makes it grow."""
        with self._count_lock:
            return time.monotonic() - self._waiting_since if self._unsent else 0.0

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what is queued, then stop."""
        self._queue.put(None)
        self._thread.join(timeout_s)

    def _send_all(self) -> None:
        while (message := self._queue.get()) is not None:
            try:
                self._conn.send(message)
            except (EOFError, OSError):
                self._on_eof()
                return
            with self._count_lock:
                self._unsent -= 1
                self._waiting_since = time.monotonic()  # the reader took one just now
