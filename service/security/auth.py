"""API tokens: issue, check and revoke; the bootstrap admin token.

A token is ``evc_<43 url-safe characters>`` (32 random bytes). Only its SHA-256 is stored, with a
name, one scope, an origin (bootstrap | cli | api), a creation time and a revoked flag. Scopes
nest: read ⊂ operate ⊂ admin, so an admin token can do everything an operate token can.

No web framework here: the FastAPI dependency is service/http/auth.py.
"""

from __future__ import annotations

import hashlib
import os
import secrets
import threading
import time
from pathlib import Path

from service.science.errors import FieldError
from service.store import Store, new_id, utc_now
from service.store.files import write_bytes_atomic

TOKEN_PREFIX = "evc_"
SCOPES = ("read", "operate", "admin")
ORIGINS = ("bootstrap", "cli", "api")
BOOTSTRAP_FILE = "admin.token"


class AuthError(Exception):
    """A request without the right token: 401 (none, unknown or revoked) or 403 (scope too low).
    ``field`` names where the token was looked for (authorization, token) or ``scope``."""

    def __init__(self, status_code: int, detail: str, field: str = "authorization"):
        super().__init__(detail)
        self.status_code, self.detail, self.field = status_code, detail, field


def hash_token(token: str) -> str:
    """SHA-256 hex digest of a token's plaintext (what the store keeps)."""
    return hashlib.sha256(token.encode()).hexdigest()


def scope_allows(granted: str, needed: str) -> bool:
    """True if a token of scope ``granted`` may do what needs ``needed`` (read < operate < admin)."""
    return SCOPES.index(granted) >= SCOPES.index(needed)


def required_scope(method: str, path: str) -> str:
    """The scope a request needs: admin under /api/admin, read for GET/HEAD/OPTIONS, else operate."""
    if path == "/api/admin" or path.startswith("/api/admin/"):
        return "admin"
    return "read" if method.upper() in ("GET", "HEAD", "OPTIONS") else "operate"


def issue(store: Store, name: str, scope: str, origin: str) -> tuple[str, dict]:
    """Create a token; returns (plaintext, record). The plaintext is shown once and never stored."""
    if scope not in SCOPES:
        raise FieldError("scope", f"must be one of {', '.join(SCOPES)}, not {scope!r}")
    if origin not in ORIGINS:
        raise ValueError(f"origin must be one of {', '.join(ORIGINS)}, not {origin!r}")
    name = (name or "").strip()
    if not name:
        raise FieldError("name", "a token needs a name (who or what uses it)")
    plaintext = TOKEN_PREFIX + secrets.token_urlsafe(32)
    row = {
        "id": new_id("tok"),
        "name": name,
        "scope": scope,
        "sha256": hash_token(plaintext),
        "origin": origin,
        "revoked": False,
        "created_at": utc_now(),
        "revoked_at": None,
    }
    store.tokens.add(row)
    return plaintext, public(row)


class RecentTokens:
    """Tokens this process has verified against the store, and when (``time.monotonic`` s): the
    emergency stop checks its caller here, without a store read. A read costs the stop's thread
    dozens of interpreter-lock hand-offs, and under download and import load each one waits its
    turn (20 ms at p99 on a 2-core machine); a dictionary look-up waits for none. A token revoked
    through this process, or found revoked by any request, is forgotten at once; one revoked
    elsewhere (the CLI, another service on the same store) may still press the stop for
    ``trust_s`` — the stop only drives the outputs to 0 V and cancels the bench's job, so that is
    the direction to err in."""

    def __init__(self, trust_s: float = 5.0):
        self.trust_s = float(trust_s)
        self._verified: dict[str, tuple[dict, float]] = {}
        self._lock = threading.Lock()

    def remember(self, token: str, record: dict) -> None:
        with self._lock:
            self._verified[hash_token(token)] = (record, time.monotonic())

    def recent(self, token: str | None) -> dict | None:
        """The record of ``token`` if it was verified within ``trust_s``, else None."""
        if not token:
            return None
        found = self._verified.get(hash_token(token))
        if found is None or time.monotonic() - found[1] > self.trust_s:
            return None
        return found[0]

    def forget_token(self, token: str) -> None:
        """Drop ``token`` (the store refused it)."""
        with self._lock:
            self._verified.pop(hash_token(token), None)

    def forget(self, token_id: str) -> None:
        """Drop every entry of the token ``token_id`` (it was revoked)."""
        with self._lock:
            for digest in [d for d, (record, _) in self._verified.items() if record.get("id") == token_id]:
                del self._verified[digest]


def public(row: dict) -> dict:
    """A token record as shown to users: no hash, and the scopes the token grants."""
    record = {k: v for k, v in row.items() if k != "sha256"}
    record["scopes"] = list(SCOPES[: SCOPES.index(row["scope"]) + 1])
    return record


def authenticate(store: Store, token: str | None) -> dict:
    """The record of a valid token; AuthError(401) says why otherwise (missing, malformed,
    unknown, revoked). The stored and presented hashes are compared in constant time."""
    if not token:
        raise AuthError(
            401,
            "missing API token: send the header 'Authorization: Bearer <token>' "
            "(create one with `evcbench token create`)",
        )
    if not token.startswith(TOKEN_PREFIX):
        raise AuthError(401, f"malformed API token: tokens start with {TOKEN_PREFIX!r}")
    row = store.tokens.by_hash(hash_token(token))  # by the sha256 itself: only a secret's hash is compared
    reason = refusal(row)
    if reason is not None:
        raise AuthError(401, reason)
    return public(row)


def refusal(row: dict | None) -> str | None:
    """Why a stored token row may not be used (unknown, revoked), in words, or None if it may."""
    if row is None:
        return "unknown API token"
    if row["revoked"]:
        return f"API token {row['id']} ({row['name']}) has been revoked"
    return None


def still_valid(store: Store, record: dict) -> str | None:
    """Re-check a token that was valid when a long request (an event stream) began: why it no
    longer is, or None. One indexed row read; ``record`` is what ``authenticate`` returned (an
    ``id`` of None, as with auth off, is always valid)."""
    if record.get("id") is None:
        return None
    row = store.tokens.get(record["id"])
    return f"API token {record['id']} no longer exists" if row is None else refusal(row)


def authorize(record: dict, needed: str) -> None:
    """AuthError(403) naming the needed scope if ``record``'s scope is lower."""
    if not scope_allows(record["scope"], needed):
        raise AuthError(
            403,
            f"this request needs the '{needed}' scope; token {record['id']} ({record['name']}) has '{record['scope']}'",
            field="scope",
        )


def read_bootstrap_token(data_dir: str | Path) -> str | None:
    """The service's bootstrap admin token from <data_dir>/admin.token, or None if unreadable."""
    try:
        return (Path(data_dir) / BOOTSTRAP_FILE).read_text().strip() or None
    except OSError:
        return None


def ensure_bootstrap_token(store: Store, data_dir: Path, bench_id: str | None = None) -> Path:
    """Make sure <data_dir>/admin.token (mode 0600) holds a valid bootstrap admin token, so the
    local CLI and dashboard work; a missing, unknown or revoked one is replaced. Returns the path.

    In a lab (several services, each with its own data dir, on one database) every service keeps
    its own file and its own token, named after ``bench_id``; the token table is shared, so any
    service's token is valid on every service of the lab, and one service replacing its token never
    touches another's."""
    path = Path(data_dir) / BOOTSTRAP_FILE
    try:
        authenticate(store, read_bootstrap_token(data_dir) or "")
        os.chmod(path, 0o600)
        return path
    except (OSError, AuthError):
        pass
    name = f"bootstrap admin (bench {bench_id})" if bench_id else "bootstrap admin"
    plaintext, _ = issue(store, name, "admin", "bootstrap")
    write_secret(path, plaintext)
    return path


def write_secret(path: Path, text: str) -> None:
    """Write ``text`` + newline to ``path`` with mode 0600, atomically (the store's own atomic write:
    its temporary file is created 0600 by mkstemp and renamed over any old file)."""
    write_bytes_atomic(Path(path), (text + "\n").encode())


def remote_tokens(store: Store) -> list[dict]:
    """Active tokens made on purpose (cli or api), i.e. not the local bootstrap token."""
    return [t for t in store.tokens.list() if not t["revoked"] and t["origin"] != "bootstrap"]
