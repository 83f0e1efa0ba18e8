"""``evcbench token create|list|revoke``: manage API tokens directly in the store (no server needed).

    evcbench token create --name alice --scope operate     # prints the token once
    evcbench token list
    evcbench token revoke tok_…

``--data-dir`` / ``--database-url`` (or EVCBENCH_DATA_DIR / EVCBENCH_DATABASE_URL) pick the store,
as for ``evcbench serve``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.runtime.settings import Settings
from service.security import auth
from service.store import Store, utc_now


def open_store(data_dir: Path | None = None, database_url: str | None = None, array_url: str | None = None) -> Store:
    """The store ``serve`` would open with the same options (defaults from the environment)."""
    defaults = Settings()
    settings = Settings(
        data_dir=data_dir or defaults.data_dir,
        database_url=database_url or defaults.database_url,
        array_url=array_url or defaults.array_url,
    )
    return Store(settings.resolved_database_url, settings.data_dir, array_url=settings.array_url)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``token`` and its sub-commands on the ``evcbench`` sub-parser."""
    token = sub.add_parser("token", help="create, list or revoke API tokens (acts on the store directly)")
    verbs = token.add_subparsers(dest="token_command", required=True)

    def verb(name: str, help_text: str, func) -> argparse.ArgumentParser:
        p = verbs.add_parser(name, help=help_text)
        p.add_argument("--data-dir", type=Path, help="store directory (default ./var, env EVCBENCH_DATA_DIR)")
        p.add_argument("--database-url", help="SQLAlchemy URL of the metadata database (env EVCBENCH_DATABASE_URL)")
        p.add_argument("--json", action="store_true", help="print JSON")
        p.set_defaults(func=func)
        return p

    p = verb("create", "issue a token and print it once (only its SHA-256 is stored)", _create)
    p.add_argument("--name", required=True, help="who or what uses it, e.g. 'alice' or 'ci'")
    p.add_argument(
        "--scope",
        default="read",
        choices=auth.SCOPES,
        help="read (GET only) ⊂ operate (sweeps, trajectories, stop, jobs, imports) ⊂ admin "
        "(token management); default read",
    )
    p.add_argument("--output", type=Path, help="write the token to this file (mode 0600) instead of stdout")
    p.add_argument(
        "--if-missing",
        action="store_true",
        help="do nothing if an active cli/api token already exists (container start-up)",
    )
    verb("list", "list tokens (no secrets)", _list)
    p = verb(
        "revoke",
        "revoke a token: requests with it get 401 at once (a running service's emergency "
        "stop still takes it for up to 5 s if it saw it lately, its bench engine's stop port for up to 2 s)",
        _revoke,
    )
    p.add_argument("token_id", help="the token's id (tok_…), from `evcbench token list`")


def _create(args: argparse.Namespace) -> int:
    store = open_store(args.data_dir, args.database_url)
    try:
        existing = auth.remote_tokens(store)
        if args.if_missing and existing:
            print(f"a token already exists ({existing[0]['id']}, {existing[0]['name']}): none created", file=sys.stderr)
            return 0
        plaintext, record = auth.issue(store, args.name, args.scope, "cli")
    finally:
        store.close()
    if args.output:
        auth.write_secret(args.output, plaintext)
        print(f"token {record['id']} ({record['name']}, {record['scope']}) written to {args.output}", file=sys.stderr)
    elif args.json:
        print(json.dumps({**record, "token": plaintext}))
    else:
        print(
            f"token {record['id']} ({record['name']}, scope {record['scope']}); shown once, keep it:", file=sys.stderr
        )
        print(plaintext)
    return 0


def _list(args: argparse.Namespace) -> int:
    store = open_store(args.data_dir, args.database_url)
    try:
        rows = [auth.public(t) for t in store.tokens.list()]
    finally:
        store.close()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for t in rows:
        state = f"revoked {t['revoked_at']}" if t["revoked"] else "active"
        print(f"{t['id']}  {t['scope']:<7} {t['origin']:<9} {t['created_at']}  {state:<8} {t['name']}")
    return 0


def _revoke(args: argparse.Namespace) -> int:
    store = open_store(args.data_dir, args.database_url)
    try:
        found = store.tokens.revoke(args.token_id, utc_now())
    finally:
        store.close()
    if not found:
        print(f"error: no token with id {args.token_id!r}", file=sys.stderr)
        return 2
    print(f"token {args.token_id} revoked")
    return 0


def serve_refusal(settings: Settings) -> str | None:
    """Why ``evcbench serve`` must not start with these settings, or None: a non-loopback bind
    without a token (see service.security.binding), or a bench id a live service holds (said here,
    before uvicorn starts, so it is not buried in a start-up traceback; the start-up checks again)."""
    from service.runtime.heartbeat import held_elsewhere
    from service.security.binding import bind_refusal, is_loopback

    port_clash = stop_port_refusal(settings)
    if port_clash:
        return port_clash
    loopback = is_loopback(settings.host)
    store = open_store(settings.data_dir, settings.database_url)
    try:
        held = held_elsewhere(store, settings)
        count = 0 if loopback or settings.auth != "tokens" else len(auth.remote_tokens(store))
    finally:
        store.close()
    if held is not None or loopback:
        return held
    return bind_refusal(settings.host, settings.auth, count)


def stop_port_refusal(settings: Settings) -> str | None:
    """Why the bench engine's stop port (``--stop-port``) cannot listen, in one line, or None: the
    service's own port, or a port another program holds (0: any free port, never refused)."""
    import socket

    if settings.stop_port == 0:
        return None
    if settings.stop_port == settings.port:
        return f"--stop-port {settings.stop_port} is the service's own --port: give the emergency stop another port"
    family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
    try:
        socket.create_server((settings.host, settings.stop_port), family=family).close()
    except OSError as exc:
        return (
            f"the stop port {settings.host}:{settings.stop_port} cannot listen ({exc.strerror or exc}): "
            "pick another with --stop-port, or 0 for any free port"
        )
    return None
