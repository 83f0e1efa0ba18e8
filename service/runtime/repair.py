"""``evcbench store repair``: make ``evcbench store check`` pass again without losing a completed
dataset. Each problem (service.store.check kinds) is answered so:

- ``temp_file``: deleted (a write that never finished; never a stored dataset);
- ``orphan_array``: moved to ``quarantine/arrays/`` (it may be a completed dataset of another
  database), and moved back when a row names it with the same SHA-256;
- ``orphan_chunks``, ``unfinished_job``: as at start-up (service.runtime.recovery): the chunks become a
  partial dataset unless the job has one, the job is marked failed "interrupted by restart";
- ``missing_array``: the file is restored from ``quarantine/arrays/`` if a copy there matches the
  row's SHA-256 (for a shared location's object: uploaded again from this service's read cache, if
  a copy there matches); otherwise the row is kept and put in quarantine (service.store.quarantine);
- ``corrupt_array``: the file is moved to ``quarantine/arrays/`` (kept for inspection) and the row
  is put in quarantine; putting a good copy back at the row's path lifts it at the next repair;
- ``impossible_job``: the job row is made consistent (service.store.check.job_problems says how);
- ``dangling_reference``: the row is kept and put in quarantine;
- in a shared array location (service.store.arrays): a corrupt object is moved to the location's
  ``quarantine/`` (the row in quarantine); an old object no row names is moved there too;
  ``pending_upload`` is uploaded if the location answers (at recovery), else left, as is
  ``array_store_unavailable``.

No dataset or model row is ever deleted. Entries whose problem is gone are lifted. Repair needs the
data dir to itself: it takes the lock the running service holds (service.store.lock), so it is
refused while the service runs, except ``dry_run``, which changes nothing and says what it would do.
"""

from __future__ import annotations

import os
from pathlib import Path

from service.runtime.recovery import INTERRUPTED, claim, recover
from service.store import Store, debris, placement, quarantine, utc_now
from service.store.check import check_store, job_problems
from service.store.lock import StoreLock

#: problems that put a row in quarantine (the row is kept)
QUARANTINED = ("missing_array", "corrupt_array", "dangling_reference")


class StoreBusy(RuntimeError):
    """Another live process (the service, or a repair) holds the data dir's lock."""


def repair_store(store: Store, dry_run: bool = False) -> dict:
    """Repair ``store`` (or, with ``dry_run``, only say what would be done). Returns ``{"dry_run",
    "found": [problems before], "actions": [{"kind", "id", "action"}], "freed_bytes", "after": the
    check report after (the one before, for a dry run)}``. StoreBusy if the service runs on it."""
    if not dry_run and not claim(store):
        raise StoreBusy(
            f"a process (pid {StoreLock(store.data_dir).owner()}) holds {store.data_dir}/service.lock: "
            "stop the service first (`evcbench store repair --dry-run` shows what would be done)"
        )
    found = check_store(store, offline=True)
    if dry_run:
        return {
            "dry_run": True,
            "found": found["problems"],
            "actions": _plan(store, found["problems"]),
            "freed_bytes": 0,
            "after": found,
        }
    recovered = recover(store)
    actions = [
        {"kind": "unfinished_job", "id": job_id, "action": f"marked failed ({INTERRUPTED})"}
        for job_id in recovered["failed_jobs"]
    ]
    actions += [
        {"kind": "partial_dataset", "id": dataset_id, "action": "rebuilt from an interrupted acquisition's chunks"}
        for dataset_id in recovered["datasets"]
    ]
    actions += [_file_action(a) for a in recovered["cleaned"]]
    actions += [
        {"kind": "pending_upload", "id": u["id"], "action": f"uploaded from the outbox as {u['key']}"}
        for u in recovered.get("uploaded", [])
    ]
    now, handled, left = utc_now(), set(), check_store(store, offline=True)
    for problem in left["problems"]:
        if (problem["kind"], problem["id"]) not in handled:  # a job's fixes are applied together
            handled.add((problem["kind"], problem["id"]))
            actions.append(_fix(store, problem, now))
    for entry in (q for q in left["quarantined"] if q["resolved"]):  # e.g. the right file was put back
        quarantine.lift(store, entry["id"], (entry["kind"],))
        actions.append(
            {"kind": entry["kind"], "id": entry["id"], "action": "lifted from quarantine (its problem is gone)"}
        )
    return {
        "dry_run": False,
        "found": found["problems"],
        "actions": actions,
        "freed_bytes": recovered["freed_bytes"],
        "after": check_store(store, offline=True),
    }


def _fix(store: Store, problem: dict, now: str) -> dict:
    """Answer one problem left after recovery; the action in words."""
    kind, record_id = problem["kind"], problem["id"]
    action = {"kind": kind, "id": record_id}
    if kind == "corrupt_array" and not placement.in_data_dir(store.get_dataset(record_id)["file"]):
        moved_to = placement.set_aside(store, store.get_dataset(record_id)["file"])
        quarantine.add(store, record_id, kind, problem["detail"], moved_to, now)
        return {**action, "action": f"object moved to {moved_to}; the dataset row is kept, in quarantine"}
    if kind == "orphan_array" and store.arrays is not None and store.arrays.size(f"{record_id}.npz") is not None:
        # left after recovery: an old object of the shared location
        moved_to = placement.set_aside(store, f"{record_id}.npz")
        return {**action, "action": f"moved aside to {moved_to} (kept: it may be another database's dataset)"}
    if kind == "corrupt_array":
        row = store.get_dataset(record_id)
        source = store.data_dir / row["file"]
        target = debris.free_name(debris.quarantine_dir(store.data_dir) / source.name)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
        moved_to = str(target.relative_to(store.data_dir))
        quarantine.add(store, record_id, kind, problem["detail"], moved_to, now)
        return {**action, "action": f"file moved to {moved_to}; the dataset row is kept, in quarantine"}
    if kind == "missing_array" and store.arrays is not None:
        restored = placement.restore_from_cache(store, store.get_dataset(record_id))
        if restored:
            return {**action, "action": f"object put back at {restored} from this service's verified cache copy"}
    if kind in QUARANTINED:
        quarantine.add(store, record_id, kind, problem["detail"], None, now)
        return {**action, "action": "row kept, in quarantine"}
    if kind == "impossible_job":
        job = store.get_job(record_id)
        dataset_ids = {row["id"] for row in store.list_datasets()}
        fields = {}
        for _kind, _detail, fix in job_problems(job, dataset_ids, offline=True):
            fields.update(fix or {})
        store.update_job(record_id, **fields)
        return {**action, "action": "job row set consistent: " + ", ".join(f"{k}={v!r}" for k, v in fields.items())}
    return {**action, "action": f"left as it is ({problem['detail']})"}


def _plan(store: Store, problems: list[dict]) -> list[dict]:
    """What a repair would do about ``problems``, changing nothing."""
    cleanup = debris.find(store.data_dir, store.list_datasets())
    restored = {a["id"] for a in cleanup if a["action"] == "restore"}
    plan = [_file_action(a, planned=True) for a in cleanup]
    words = {
        "unfinished_job": f"would be marked failed ({INTERRUPTED})",
        "orphan_chunks": "would become a partial dataset (unless its job has one) and be removed",
        "corrupt_array": "file would be moved to quarantine/arrays/; the row kept, in quarantine",
        "missing_array": "row would be kept, in quarantine",
        "dangling_reference": "row would be kept, in quarantine",
        "impossible_job": "job row would be set consistent",
        "pending_upload": "would be uploaded if the shared array location answers",
        "orphan_array": "object would be moved to the shared location's quarantine/",
    }
    restored |= {Path(a["path"]).stem for a in cleanup if a["kind"] == "orphan_array"}  # said above
    for problem in problems:
        if problem["kind"] in words and not (
            problem["kind"] in ("missing_array", "orphan_array") and problem["id"] in restored
        ):
            plan.append({"kind": problem["kind"], "id": problem["id"], "action": words[problem["kind"]]})
    return plan


def _file_action(action: dict, planned: bool = False) -> dict:
    """A debris or chunk action of service.store.debris / service.runtime.recovery as a repair action."""
    return {
        "kind": action["kind"],
        "id": action["path"],
        "path": action["path"],
        "bytes": action["bytes"],
        "action": debris.describe(action, planned),
    }


def format_repair(report: dict) -> str:
    """The repair report in words."""
    head = (
        f"store repair{' (dry run: nothing changed)' if report['dry_run'] else ''}: "
        f"{len(report['found'])} problem(s) found, {len(report['actions'])} action(s)"
    )
    lines = [head] + [f"  {a['kind']}: {a['id']}: {a['action']}" for a in report["actions"]]
    if not report["dry_run"]:
        from service.store.check import format_report

        lines += [f"freed {debris.format_bytes(report['freed_bytes'])}", "after: " + format_report(report["after"])]
    return "\n".join(lines)
