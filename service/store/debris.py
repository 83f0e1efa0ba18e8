"""What a killed write leaves in a data directory, and how it is cleared (start-up recovery and
``evcbench store repair``; ``evcbench store check`` reports the same things).

- **Temporary files** of the atomic writer (``.<name>.*.tmp``, service.store.files.write_atomic) in
  the data dir, ``arrays/``, ``outbox/`` and ``cache/arrays/``: a write that never reached its
  rename. They are never a stored dataset (a dataset's file has its final name before its row is
  inserted), so they are deleted.
- **Arrays with no dataset row** (``arrays/<id>.npz``, ``outbox/<id>.npz``): normally a dataset
  whose row was never inserted (killed between the rename and the insert). But a store opened with the wrong database
  (another ``--database-url``, an older backup) sees every completed dataset of the right one this
  way. So they are never deleted: they are moved to ``quarantine/arrays/`` and moved back as soon as
  a dataset row names them and their SHA-256 matches that row's (``restore``).
- Chunk directories under ``partial/`` are service.runtime.recovery's (they become partial datasets).
- Objects of a shared array location (service.store.arrays) are not debris of this data dir: other
  services write there. ``evcbench store check`` lists the old ones no row names; repair sets them aside.

Nothing here may run while another process writes to the store: the caller holds the store's
lock (service.store.lock).
"""

from __future__ import annotations

import os
from pathlib import Path

from service.store.files import file_sha256
from service.store.placement import CACHE_DIR, OUTBOX_DIR, in_data_dir

QUARANTINE_DIR = "quarantine"


def is_temp(path: Path) -> bool:
    """Named as the atomic writer names its temporary files (``.<name>.<random>.tmp``)."""
    return path.name.startswith(".") and path.name.endswith(".tmp")


def quarantine_dir(data_dir: Path) -> Path:
    """``<data_dir>/quarantine/arrays``: array files moved aside (no row, or damaged)."""
    return Path(data_dir) / QUARANTINE_DIR / "arrays"


def temp_files(data_dir: Path) -> list[Path]:
    """Leftover temporary files of the atomic writer in the data dir and ``arrays/``."""
    data_dir = Path(data_dir)
    found = []
    for directory in (data_dir, data_dir / "arrays", data_dir / OUTBOX_DIR, data_dir / CACHE_DIR):
        if directory.is_dir():
            found.extend(p for p in sorted(directory.iterdir()) if p.is_file() and is_temp(p))
    return found


def find(data_dir: Path, datasets: list[dict]) -> list[dict]:
    """The clean-up a data dir needs, given every dataset row, as actions (nothing is changed):

    - ``{"action": "delete", "kind": "temp_file", "path", "bytes"}``;
    - ``{"action": "quarantine", "kind": "orphan_array", "path", "to", "bytes"}``;
    - ``{"action": "restore", "kind": "missing_array", "id", "path", "to", "bytes"}``: a row's
      missing file found in quarantine with the row's SHA-256.

    Paths are relative to the data dir; ``bytes`` is the file's size."""
    data_dir = Path(data_dir)
    actions = [
        {"action": "delete", "kind": "temp_file", "path": _rel(p, data_dir), "bytes": _size(p)}
        for p in temp_files(data_dir)
    ]
    local_rows = [row for row in datasets if in_data_dir(row["file"])]
    referenced = {(data_dir / row["file"]).resolve() for row in local_rows}
    aside = quarantine_dir(data_dir)
    for arrays_dir in (data_dir / "arrays", data_dir / OUTBOX_DIR):
        if not arrays_dir.is_dir():
            continue
        for path in sorted(arrays_dir.iterdir()):
            if path.is_file() and not is_temp(path) and path.resolve() not in referenced:
                actions.append(
                    {
                        "action": "quarantine",
                        "kind": "orphan_array",
                        "path": _rel(path, data_dir),
                        "to": _rel(free_name(aside / path.name), data_dir),
                        "bytes": _size(path),
                    }
                )
    for row in local_rows:
        target, copy = data_dir / row["file"], aside / Path(row["file"]).name
        if not target.exists() and copy.is_file() and file_sha256(copy) == row["sha256"]:
            actions.append(
                {
                    "action": "restore",
                    "kind": "missing_array",
                    "id": row["id"],
                    "path": _rel(copy, data_dir),
                    "to": row["file"],
                    "bytes": _size(copy),
                }
            )
    return actions


def apply(data_dir: Path, actions: list[dict]) -> list[dict]:
    """Carry out ``find``'s actions; returns them, each with ``done`` (bool) and, on failure,
    ``error`` in words (a failure does not stop the others)."""
    data_dir = Path(data_dir)
    done = []
    for action in actions:
        source = data_dir / action["path"]
        try:
            if action["action"] == "delete":
                source.unlink(missing_ok=True)
            else:
                target = data_dir / action["to"]
                target.parent.mkdir(parents=True, exist_ok=True)
                if target.exists():
                    raise FileExistsError(f"{action['to']} exists")
                os.replace(source, target)
            done.append({**action, "done": True})
        except OSError as exc:
            done.append({**action, "done": False, "error": str(exc)})
    return done


def describe(action: dict, planned: bool = False) -> str:
    """What was done to an action's file, in words: 'deleted (23.1 MB)', 'moved aside to
    quarantine/arrays/ds_1.npz (1.2 MB)'; ``planned``: 'would be deleted (23.1 MB)'."""
    verb = {"delete": "deleted", "quarantine": "moved aside", "restore": "restored"}[action["action"]]
    if planned:
        verb = f"would be {verb}"
    elif not action.get("done", True):
        verb = f"could not be {verb} ({action.get('error')})"
    where = f" to {action['to']}" if "to" in action else ""
    kept = f"; its samples are in dataset {action['dataset']}" if action.get("dataset") else ""
    return f"{verb}{where} ({format_bytes(action['bytes'])}){kept}"


def format_bytes(n: int) -> str:
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} B"


def free_name(path: Path) -> Path:
    """``path``, or ``<stem>.<n><suffix>`` for the first n that is free."""
    candidate, n = path, 1
    while candidate.exists():
        candidate, n = path.with_name(f"{path.stem}.{n}{path.suffix}"), n + 1
    return candidate


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _rel(path: Path, data_dir: Path) -> str:
    return str(path.relative_to(data_dir))
