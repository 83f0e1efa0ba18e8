"""The quarantine: dataset and model rows known to be damaged, kept rather than deleted.

``evcbench store repair`` never deletes a dataset row. A dataset whose array file is missing, or
whose file no longer matches its SHA-256 (the file is then moved to ``quarantine/arrays/``), gets an
entry here; so does a model or dataset that names a record which no longer exists. ``evcbench store
check`` then lists such rows under ``quarantined`` instead of failing on them again and again, and
an entry is lifted as soon as its problem is gone (the right file put back, see
service.store.debris.restore).
"""

from __future__ import annotations

from sqlalchemy import delete, insert, select

from service.store import tables

#: the problems (service.store.check kinds) an entry of each kind stands for: a corrupt array moved
#: aside is a missing one from then on
ANSWERS = {
    "missing_array": ("missing_array",),
    "corrupt_array": ("missing_array", "corrupt_array"),
    "dangling_reference": ("dangling_reference",),
}


def entries(store) -> list[dict]:
    """Every entry (record_id, kind, detail, moved_to, created_at), oldest first."""
    query = select(tables.quarantine).order_by(tables.quarantine.c.created_at, tables.quarantine.c.record_id)
    with store.engine.connect() as conn:
        return [dict(row) for row in conn.execute(query).mappings()]


def add(store, record_id: str, kind: str, detail: str, moved_to: str | None, when: str) -> dict:
    """Put ``record_id`` in quarantine for ``kind`` (replacing an entry of the same kind)."""
    if kind not in ANSWERS:
        raise ValueError(f"quarantine kind must be one of {', '.join(ANSWERS)}, not {kind!r}")
    row = {"record_id": record_id, "kind": kind, "detail": detail, "moved_to": moved_to, "created_at": when}
    q = tables.quarantine
    with store.engine.begin() as conn:
        conn.execute(delete(q).where(q.c.record_id == record_id).where(q.c.kind == kind))
        conn.execute(insert(q).values(**row))
    return row


def lift(store, record_id: str, kinds: tuple[str, ...] | None = None) -> int:
    """Remove ``record_id``'s entries (of ``kinds``, or all); returns how many there were."""
    q = tables.quarantine
    query = delete(q).where(q.c.record_id == record_id)
    if kinds is not None:
        query = query.where(q.c.kind.in_(kinds))
    with store.engine.begin() as conn:
        return conn.execute(query).rowcount


def answered_by(problem: dict, quarantined: list[dict]) -> dict | None:
    """The entry that stands for ``problem`` ({"kind", "id", …} of service.store.check), or None."""
    for entry in quarantined:
        if entry["record_id"] == problem["id"] and problem["kind"] in ANSWERS.get(entry["kind"], ()):
            return entry
    return None
