"""API token rows: only each token's SHA-256 is stored, never its plaintext.

The table shares the store's metadata, so ``Store`` creates it with the others (a new table on an
existing database is added at the next start, on SQLite and PostgreSQL alike).
"""

from __future__ import annotations

from sqlalchemy import Boolean, Column, String, Table, Text, insert, select, update
from sqlalchemy.engine import Engine

from service.store.tables import metadata

tokens = Table(
    "api_tokens",
    metadata,
    Column("id", String(40), primary_key=True),
    Column("name", Text, nullable=False),
    Column("scope", String(16), nullable=False),  # read | operate | admin
    Column("sha256", String(64), nullable=False, unique=True),  # hex digest of the plaintext
    Column("origin", String(16), nullable=False),  # bootstrap | cli | api
    Column("revoked", Boolean, nullable=False, default=False),
    Column("created_at", String(40), nullable=False),
    Column("revoked_at", String(40), nullable=True),
)

#: What listings show: everything but the hash.
PUBLIC_COLUMNS = [c for c in tokens.c if c.name != "sha256"]


class TokenRows:
    """Insert, find, list and revoke token rows on one engine."""

    def __init__(self, engine: Engine):
        self.engine = engine

    def add(self, row: dict) -> None:
        with self.engine.begin() as conn:
            conn.execute(insert(tokens).values(**row))

    def by_hash(self, sha256: str) -> dict | None:
        """The row whose hash is ``sha256`` (hex), or None."""
        with self.engine.connect() as conn:
            row = conn.execute(select(tokens).where(tokens.c.sha256 == sha256)).mappings().first()
        return dict(row) if row else None

    def get(self, token_id: str) -> dict | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(*PUBLIC_COLUMNS).where(tokens.c.id == token_id)).mappings().first()
        return dict(row) if row else None

    def list(self) -> list[dict]:
        """Every token (revoked ones too), oldest first, without hashes."""
        with self.engine.connect() as conn:
            query = select(*PUBLIC_COLUMNS).order_by(tokens.c.created_at, tokens.c.id)
            return [dict(row) for row in conn.execute(query).mappings()]

    def valid_digests(self) -> dict[str, tuple[str, str, str]]:
        """Every token not revoked: its SHA-256 hex digest → (id, name, scope), for the engine's stop port."""
        with self.engine.connect() as conn:
            query = select(tokens.c.sha256, tokens.c.id, tokens.c.name, tokens.c.scope).where(
                tokens.c.revoked.is_(False)
            )
            return {row.sha256: (row.id, row.name, row.scope) for row in conn.execute(query)}

    def revoke(self, token_id: str, when: str) -> bool:
        """Mark a token revoked; False if there is no such token."""
        with self.engine.begin() as conn:
            result = conn.execute(update(tokens).where(tokens.c.id == token_id).values(revoked=True, revoked_at=when))
            return bool(result.rowcount)
