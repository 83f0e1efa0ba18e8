"""Store consistency check (``evcbench store check``): do the rows and the files agree?

Problems reported, each as ``{"kind", "id", "detail"}``:
- ``missing_array``: a dataset row whose array file (or object of the shared location) is missing;
- ``corrupt_array``: a dataset's array file or object whose SHA-256 differs from the row's (unless
  ``quick``; an object is read through, as a file is);
- ``orphan_array``: an array file no dataset row refers to (an object of the shared location only
  when older than service.store.placement.ORPHAN_GRACE_S: another service may be storing it);
- ``pending_upload``: a dataset whose arrays wait in an outbox for the shared location;
- ``array_store_unavailable``: the shared location could not be asked (named by its URL);
- ``temp_file``: a leftover ``.*.tmp`` of an unfinished atomic write (in the data dir or arrays/);
- ``orphan_chunks``: a chunk directory under ``partial/`` whose job is not queued or running
  (recovery at the next start turns such chunks into a partial dataset);
- ``impossible_job``: a job in an unknown state, finished without ``finished_at``, failed without
  an error, succeeded with progress below 1, or naming a dataset that does not exist;
- ``dangling_reference``: a model whose datasets or parent, or a dataset whose job, is missing;
- ``unfinished_job``: a job queued or running while the service is not running (only when
  ``offline``; recovery marks it failed at the next start).

Start-up recovery (service.runtime.recovery) clears the temporary files, orphan arrays and chunks and the
unfinished jobs; ``evcbench store repair`` (service.runtime.repair) clears the rest. A problem of a row in
quarantine (service.store.quarantine: a missing or corrupt array, a dangling reference, set aside by
repair) is listed under ``quarantined`` and no longer makes the store inconsistent.
"""

from __future__ import annotations

from service.store import TERMINAL_STATES, Store, debris, placement, quarantine
from service.store.arrays import ArrayStoreUnavailable
from service.store.chunks import partial_root
from service.store.files import file_sha256

STATES = ("queued", "running", *TERMINAL_STATES)


def check_store(store: Store, quick: bool = False, offline: bool = False) -> dict:
    """Check ``store``; returns ``{"ok", "problems", "quarantined", "counts"}``. ``quick`` skips the checksums;
    ``offline`` says no service is running on the store (so no job may be queued or running)."""
    datasets = store.list_datasets()
    models = store.list_models()
    jobs = {row["id"]: row for row in store.list_jobs(limit=None)}
    dataset_ids = {row["id"] for row in datasets}
    cleanup = debris.find(store.data_dir, datasets)
    problems, reachable = _dataset_problems(store, datasets, jobs, cleanup, quick)
    problems += _debris_problems(cleanup)
    if reachable and store.arrays is not None:
        problems += _orphan_object_problems(store, datasets)
    problems += _chunk_problems(store, jobs, offline)
    for job in jobs.values():
        problems += [
            _problem(kind, job["id"], detail) for kind, detail, _fix in job_problems(job, dataset_ids, offline)
        ]
    problems += _model_problems(models, dataset_ids)
    entries, open_problems, answering = quarantine.entries(store), [], set()
    for p in problems:
        entry = quarantine.answered_by(p, entries)
        if entry is None:
            open_problems.append(p)
        else:
            answering.add((entry["record_id"], entry["kind"]))
    quarantined = [
        {
            "kind": e["kind"],
            "id": e["record_id"],
            "detail": e["detail"],
            "moved_to": e["moved_to"],
            "since": e["created_at"],
            "resolved": (e["record_id"], e["kind"]) not in answering,
        }
        for e in entries
    ]
    counts = _counts(store, datasets, models, jobs, entries)
    return {"ok": not open_problems, "problems": open_problems, "quarantined": quarantined, "counts": counts}


def _problem(kind: str, record_id: str, detail: str) -> dict:
    return {"kind": kind, "id": record_id, "detail": detail}


def _dataset_problems(store: Store, datasets: list, jobs: dict, cleanup: list, quick: bool) -> tuple[list, bool]:
    """(problems of the datasets' arrays and job references, whether the shared array location answered)."""
    problems: list[dict] = []
    restorable = {a["id"]: a["path"] for a in cleanup if a["action"] == "restore"}
    unreachable = None
    for row in datasets:
        path = store.data_dir / row["file"]
        if not placement.in_data_dir(row["file"]) or placement.pending(row["file"]):
            if unreachable is None or placement.pending(row["file"]):
                try:
                    found = placement.check_row(store, row, quick)
                except ArrayStoreUnavailable as exc:
                    unreachable, found = exc, None
                    problems.append(_problem("array_store_unavailable", exc.url, f"{exc}: its arrays were not checked"))
                if found is not None:
                    problems.append(_problem(found[0], row["id"], found[1]))
        elif not path.is_file():
            copy = restorable.get(row["id"])
            problems.append(
                _problem(
                    "missing_array",
                    row["id"],
                    f"array file {row['file']} is missing"
                    + (f" (its copy {copy} matches: start-up recovery or store repair moves it back)" if copy else ""),
                )
            )
        elif not quick and file_sha256(path) != row["sha256"]:
            problems.append(_problem("corrupt_array", row["id"], f"array file {row['file']} does not match its sha256"))
        if row["job_id"] and row["job_id"] not in jobs:
            problems.append(
                _problem("dangling_reference", row["id"], f"dataset names job {row['job_id']}, which does not exist")
            )
    return problems, unreachable is None


def _debris_problems(cleanup: list) -> list[dict]:
    """Leftover temporary files and array files no dataset names, in the data dir."""
    problems = []
    for action in cleanup:
        name, size = action["path"].rsplit("/", 1)[-1], debris.format_bytes(action["bytes"])
        if action["kind"] == "temp_file":
            problems.append(_problem("temp_file", name, f"leftover temporary file {action['path']} ({size})"))
        elif action["kind"] == "orphan_array":
            problems.append(
                _problem("orphan_array", name.rsplit(".", 1)[0], f"{action['path']} belongs to no dataset ({size})")
            )
    return problems


def _orphan_object_problems(store: Store, datasets: list) -> list[dict]:
    """Objects no dataset names in the shared array location (or that it did not answer)."""
    try:
        return [
            _problem(
                "orphan_array",
                key.rsplit(".", 1)[0],
                f"{store.arrays.where(key)} belongs to no dataset ({debris.format_bytes(size)})",
            )
            for key, size in placement.orphan_objects(store, datasets)
        ]
    except ArrayStoreUnavailable as exc:
        return [_problem("array_store_unavailable", exc.url, f"{exc}: its objects were not listed")]


def _chunk_problems(store: Store, jobs: dict, offline: bool) -> list[dict]:
    """Chunk directories of jobs that are gone, finished, or (``offline``) cannot be running."""
    root = partial_root(store.data_dir)
    if not root.is_dir():
        return []
    problems = []
    for directory in sorted(p for p in root.iterdir() if p.is_dir()):
        job = jobs.get(directory.name)
        if job is None or job["state"] in TERMINAL_STATES or offline:
            state = "no such job" if job is None else f"job is {job['state']}"
            problems.append(_problem("orphan_chunks", directory.name, f"partial/{directory.name}: {state}"))
    return problems


def _model_problems(models: list, dataset_ids: set[str]) -> list[dict]:
    """Models that name missing datasets or a missing parent."""
    problems = []
    model_ids = {row["id"] for row in models}
    for row in models:
        missing = [d for d in row["datasets"] if d not in dataset_ids]
        if missing:
            problems.append(
                _problem("dangling_reference", row["id"], f"model names missing datasets {', '.join(missing)}")
            )
        if row["parent_id"] and row["parent_id"] not in model_ids:
            problems.append(
                _problem("dangling_reference", row["id"], f"model's parent {row['parent_id']} does not exist")
            )
    return problems


def _counts(store: Store, datasets: list, models: list, jobs: dict, entries: list) -> dict:
    """How many rows of each kind, and what quarantine holds (rows, files, bytes)."""
    aside = [p for p in debris.quarantine_dir(store.data_dir).glob("*") if p.is_file()]
    return {
        "datasets": len(datasets),
        "models": len(models),
        "jobs": len(jobs),
        "partial_datasets": sum(bool(row["partial"]) for row in datasets),
        "quarantined": len(entries),
        "quarantine_files": len(aside),
        "quarantine_bytes": sum(p.stat().st_size for p in aside),
    }


def job_problems(job: dict, dataset_ids: set[str], offline: bool) -> list[tuple[str, str, dict | None]]:
    """(kind, detail in words, fix) for each inconsistency of a job row. ``fix`` is the update of the
    row that resolves it (``evcbench store repair``), None for an unfinished job (recovery fails it)."""
    state, out = job["state"], []
    last_known_at = job["finished_at"] or job["started_at"] or job["created_at"]  # the job's last known time
    if state not in STATES:
        fix = {
            "state": "failed",
            "finished_at": last_known_at,
            "error": f"unknown state {state!r} (set failed by store repair)",
        }
        return [("impossible_job", f"unknown state {state!r}", fix)]
    if state in TERMINAL_STATES and not job["finished_at"]:
        out.append(("impossible_job", f"{state} but has no finished_at", {"finished_at": last_known_at}))
    if state == "running" and not job["started_at"]:
        out.append(("impossible_job", "running but has no started_at", {"started_at": job["created_at"]}))
    if state == "failed" and not job["error"]:
        out.append(
            ("impossible_job", "failed without an error", {"error": "no error was recorded (set by store repair)"})
        )
    if state == "succeeded" and job["progress"] < 1.0:
        out.append(("impossible_job", f"succeeded at progress {job['progress']:.2f}", {"progress": 1.0}))
    result = job["result"] if isinstance(job["result"], dict) else {}
    dataset_id = result.get("dataset_id")
    if dataset_id and dataset_id not in dataset_ids:
        out.append(
            (
                "impossible_job",
                f"result names dataset {dataset_id}, which does not exist",
                {"result": {**result, "dataset_id": None, "missing_dataset_id": dataset_id}},
            )
        )
    if offline and state in ("queued", "running"):
        out.append(("unfinished_job", f"still {state} though no service runs (recovered at the next start)", None))
    return out


def format_report(report: dict) -> str:
    """The report in words, one problem a line."""
    c = report["counts"]
    head = (
        f"store: {c['datasets']} datasets ({c['partial_datasets']} partial), {c['models']} models, "
        f"{c['jobs']} jobs: " + ("consistent" if report["ok"] else f"{len(report['problems'])} problem(s)")
    )
    lines = [head] + [f"  {p['kind']}: {p['id']}: {p['detail']}" for p in report["problems"]]
    if report["quarantined"]:
        lines.append(
            f"{len(report['quarantined'])} record(s) in quarantine (kept as they are, see `evcbench store repair`):"
        )
        lines += [
            f"  {q['kind']}: {q['id']}: {q['detail']} (since {q['since']})"
            + (": resolved, lifted at the next repair" if q["resolved"] else "")
            for q in report["quarantined"]
        ]
    if c["quarantine_files"]:
        lines.append(
            f"{c['quarantine_files']} file(s) moved aside in {debris.QUARANTINE_DIR}/arrays/ "
            f"({debris.format_bytes(c['quarantine_bytes'])}): "
            "delete them once you are sure no database names them"
        )
    return "\n".join(lines)
