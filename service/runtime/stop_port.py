"""The emergency stop's own port, served inside the bench engine's process.

``POST /api/bench/stop`` on the service's port goes through the web process: its event loop, its
interpreter lock and the operating system's turn for a process that downloads, imports and fits
are busy with. Under that load the loop reached the stop 4–17 ms late (docs/architecture.md, "The
safety path"). This port is a second door to the same stop that none of it stands in front of: a
listening socket in the engine process (niceness −10), served by a thread of its own that sleeps
in ``select`` until a connection arrives, then parses one small HTTP request and drives the outputs
to 0 V before it answers. Nothing here imports FastAPI or the store.

The request is the REST route's: ``POST /api/bench/stop`` with ``Authorization: Bearer <token>``
of scope operate or admin; the same token works on both doors. The web process tells the engine
which tokens are valid (``StopTokens.replace``: their SHA-256 digests and scopes, never a
plaintext) when it starts and whenever it sees them change. ``OPTIONS`` answers the browser's CORS
preflight, so the dashboard, served from the service's port, may press the stop here.

One thread serves every connection (``selectors``): a client that opens a connection and sends
nothing, or sends slowly, holds no one else up, and is dropped after ``IDLE_TIMEOUT_S``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import selectors
import socket
import threading
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger("evcbench.engine")

STOP_PATH = "/api/bench/stop"
#: Where a service tells the clients on its machine its stop port, in its data dir
#: (``{"service_port", "stop_port", "bench_id"}``): a local ``evcbench stop`` needs nothing of the web process.
STOP_PORT_FILE = "stop_port.json"
#: The reason every emergency stop gives (the job it cancels carries it), through either door.
EMERGENCY_STOP = "emergency stop"
#: A request head larger than this is refused (431): the stop needs a few hundred bytes.
MAX_HEAD_BYTES = 8192
#: A body larger than this is refused (413); the stop takes none, but a client may send one.
MAX_BODY_BYTES = 65536
#: A connection that has not sent a whole request within this long is closed (s).
IDLE_TIMEOUT_S = 5.0
#: Connections held open at once; the oldest is dropped for a new one beyond it.
MAX_CONNECTIONS = 64
#: How long the browser may reuse a preflight answer (s).
PREFLIGHT_MAX_AGE_S = 600

_REASONS = {
    200: "OK",
    204: "No Content",
    400: "Bad Request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not Found",
    405: "Method Not Allowed",
    409: "Conflict",
    413: "Payload Too Large",
    431: "Request Header Fields Too Large",
    503: "Service Unavailable",
}


class StopTokens:
    """The tokens the stop port accepts: SHA-256 hex digest → (id, name, scope), as the web process
    last sent them; ``auth_off`` accepts any request (a service started with auth off)."""

    def __init__(self):
        self._by_digest: dict[str, tuple[str, str, str]] = {}
        self._auth_off = False
        self._loaded = False

    def replace(self, by_digest: dict[str, tuple[str, str, str]], auth_off: bool) -> int:
        """Take the web process's current list (one dict swap: a check never sees half of it)."""
        self._by_digest, self._auth_off, self._loaded = dict(by_digest), bool(auth_off), True
        return len(self._by_digest)

    def refusal(self, authorization: str | None) -> tuple[int, str, str] | None:
        """None if the ``Authorization`` header may press the stop, else (status, detail, field)
        in the words the REST route uses."""
        if self._auth_off:
            return None
        if not self._loaded:
            return (
                503,
                "the stop port has not received the service's tokens yet: press the stop on the service's port",
                "authorization",
            )
        scheme, _, token = (authorization or "").strip().partition(" ")
        token = token.strip()
        if scheme.lower() != "bearer" or not token:
            return 401, "missing API token: send the header 'Authorization: Bearer <token>'", "authorization"
        found = self._by_digest.get(hashlib.sha256(token.encode()).hexdigest())
        if found is None:
            return 401, "unknown or revoked API token", "authorization"
        token_id, name, scope = found
        if scope not in ("operate", "admin"):
            return 403, f"this request needs the 'operate' scope; token {token_id} ({name}) has '{scope}'", "scope"
        return None


def zero_after_request_ms(stop: dict) -> float | None:
    """A ``Bench.last_stop``'s time from the stop's request to its 0 V write (ms), None if unknown."""
    if stop["zero_monotonic_s"] is None:
        return None
    return round(max(0.0, stop["zero_monotonic_s"] - stop["requested_monotonic_s"]) * 1e3, 3)


@dataclass
class _Connection:
    sock: socket.socket
    opened_s: float
    data: bytearray = field(default_factory=bytearray)


@dataclass
class _Request:
    method: str
    path: str
    query: dict[str, str]
    headers: dict[str, str]


def _parse_head(head: bytes) -> _Request | None:
    """The request line and headers of ``head`` (up to the blank line), or None if malformed."""
    try:
        lines = head.decode("latin-1").replace("\r\n", "\n").split("\n")
        method, target, version = lines[0].split(" ")
    except ValueError:
        return None
    if not version.startswith("HTTP/1."):
        return None
    headers = {}
    for line in lines[1:]:
        name, sep, value = line.partition(":")
        if not sep or not name or name != name.strip():
            return None
        headers[name.lower()] = value.strip()
    path, _, query = target.partition("?")
    return _Request(method.upper(), path, dict(urllib.parse.parse_qsl(query)), headers)


def _head_end(data: bytearray) -> tuple[int, int]:
    """(where the request head ends, the blank line's length): CRLF CRLF, or LF LF as a hand-typed
    request (``nc``) sends it; (-1, 0) while it has not ended."""
    ends = [(i, len(sep)) for sep in (b"\r\n\r\n", b"\n\n") if (i := data.find(sep)) >= 0]
    return min(ends) if ends else (-1, 0)


def _response(status: int, body: dict | None, origin: str | None, extra: dict[str, str] | None = None) -> bytes:
    payload = b"" if body is None else json.dumps(body).encode()
    headers = {
        "Content-Type": "application/json",
        "Content-Length": str(len(payload)),
        "Connection": "close",
        "Cache-Control": "no-store",
        **(extra or {}),
    }
    if origin:  # a bearer token is never sent by a browser on its own, so any origin may ask
        headers.update({"Access-Control-Allow-Origin": origin, "Vary": "Origin"})
    head = f"HTTP/1.1 {status} {_REASONS[status]}\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers.items())
    return head.encode("latin-1") + b"\r\n" + payload


class StopPort:
    """Listen on ``(host, port)`` (port 0: the system picks one; ``self.port`` says which) and
    answer ``POST /api/bench/stop``: ``press()`` drives the outputs to 0 V and returns the answer's
    body. ``bench_id`` names the bench: a request whose ``?bench_id=`` names another is refused (409)
    before anything moves, so a client that reached the wrong service's port (a port forwarded to
    another bench) learns it and presses the stop on its own service instead. ``serve_forever`` runs
    in the caller's thread until ``close``."""

    def __init__(
        self, host: str, port: int, press: Callable[[], dict], tokens: StopTokens, bench_id: str | None = None
    ):
        self.press, self.tokens, self.bench_id = press, tokens, bench_id
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.create_server((host, port), family=family, backlog=64)
        self._listener.setblocking(False)
        self.host, self.port = host, self._listener.getsockname()[1]
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, None)
        self._wake_r, self._wake_w = socket.socketpair()
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._open: dict[socket.socket, _Connection] = {}
        self._closing = threading.Event()
        self.presses = 0

    def start(self) -> StopPort:
        threading.Thread(target=self.serve_forever, name="evc-engine-stop-port", daemon=True).start()
        return self

    def close(self) -> None:
        self._closing.set()
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass

    def serve_forever(self) -> None:
        try:
            while not self._closing.is_set():
                for key, _ in self._selector.select(timeout=1.0):
                    if key.data == "wake":
                        continue
                    if key.fileobj is self._listener:
                        self._accept()
                    else:
                        self._read(self._open.get(key.fileobj))
                self._drop_idle()
        finally:
            for conn in list(self._open.values()):
                self._forget(conn)
            self._selector.close()
            self._listener.close()

    # ------------------------------------------------------------------ connections
    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # out of descriptors, say: the next select tries again
                log.warning("stop port: accept failed: %s", exc)
                return
            if len(self._open) >= MAX_CONNECTIONS:
                self._forget(min(self._open.values(), key=lambda c: c.opened_s))
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._open[sock] = _Connection(sock, time.monotonic())
            self._selector.register(sock, selectors.EVENT_READ, None)

    def _forget(self, conn: _Connection) -> None:
        self._open.pop(conn.sock, None)
        try:
            self._selector.unregister(conn.sock)
        except (KeyError, ValueError):
            pass
        conn.sock.close()

    def _drop_idle(self) -> None:
        now = time.monotonic()
        for conn in [c for c in self._open.values() if now - c.opened_s > IDLE_TIMEOUT_S]:
            self._forget(conn)

    def _read(self, conn: _Connection | None) -> None:
        if conn is None:
            return
        try:
            chunk = conn.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:
            self._forget(conn)
            return
        conn.data += chunk
        reply = self._reply_if_complete(conn.data)
        if reply is not None:
            self._send(conn, reply)

    def _send(self, conn: _Connection, reply: bytes) -> None:
        try:
            conn.sock.setblocking(True)
            conn.sock.settimeout(1.0)
            conn.sock.sendall(reply)
        except OSError:
            pass
        self._forget(conn)

    # ------------------------------------------------------------------ HTTP
    def _reply_if_complete(self, data: bytearray) -> bytes | None:
        """The answer once ``data`` holds a whole request (head and body), else None."""
        end, gap = _head_end(data)
        if end < 0:
            return (
                _response(431, {"detail": f"request head over {MAX_HEAD_BYTES} bytes", "field": None}, None)
                if len(data) > MAX_HEAD_BYTES
                else None
            )
        request = _parse_head(bytes(data[:end]))
        if request is None:
            return _response(400, {"detail": "malformed HTTP request", "field": None}, None)
        origin = request.headers.get("origin")
        try:
            length = int(request.headers.get("content-length", "0"))
        except ValueError:
            return _response(400, {"detail": "Content-Length is not a number", "field": "content-length"}, origin)
        if length < 0 or length > MAX_BODY_BYTES:
            return _response(
                413,
                {"detail": f"the stop takes no body (at most {MAX_BODY_BYTES} bytes)", "field": "content-length"},
                origin,
            )
        if len(data) < end + gap + length:
            return None  # the body is still on its way: answering now would reset it
        return self._handle(request, origin)

    def _handle(self, request: _Request, origin: str | None) -> bytes:
        if request.path != STOP_PATH:
            return _response(404, {"detail": f"this port serves only {STOP_PATH}", "field": None}, origin)
        if request.method == "OPTIONS":
            return _response(
                204,
                None,
                origin,
                {
                    "Access-Control-Allow-Methods": "POST, OPTIONS",
                    "Access-Control-Allow-Headers": "Authorization, Content-Type",
                    "Access-Control-Max-Age": str(PREFLIGHT_MAX_AGE_S),
                },
            )
        if request.method != "POST":
            return _response(
                405, {"detail": f"{STOP_PATH} takes POST", "field": None}, origin, {"Allow": "POST, OPTIONS"}
            )
        refusal = self.tokens.refusal(request.headers.get("authorization"))
        if refusal is not None:
            status, detail, field_name = refusal
            extra = {"WWW-Authenticate": "Bearer"} if status == 401 else None
            return _response(status, {"detail": detail, "field": field_name}, origin, extra)
        asked = request.query.get("bench_id")
        if asked is not None and self.bench_id is not None and asked != self.bench_id:
            return _response(
                409,
                {
                    "detail": f"this port stops bench {self.bench_id!r}, not {asked!r}: nothing was "
                    "stopped; press the stop on that bench's own service",
                    "field": "bench_id",
                },
                origin,
            )
        self.presses += 1
        try:
            return _response(200, {**self.press(), "bench_id": self.bench_id}, origin)
        except Exception as exc:  # noqa: BLE001 - the port lives on; the caller learns what failed
            log.exception("stop port: the stop failed")
            return _response(503, {"detail": f"the stop failed: {type(exc).__name__}: {exc}", "field": None}, origin)
