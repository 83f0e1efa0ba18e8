"""Store consistency check (``evcbench store check``): do the rows and the files agree?

Problems reported, each as ``{"kind", "id", "detail"}``:
- ``missing_array``: a dataset row whose array file is missing;
- ``corrupt_array``: a dataset's array file whose SHA-256 differs from the row's (unless ``quick``);
- ``orphan_array``: an array file no dataset row refers to;
- ``temp_file``: a leftover ``.*.tmp`` of an unfinished atomic write;
- ``orphan_chunks``: a chunk directory under ``partial/`` whose job is not queued or running
  (recovery at the next start turns such chunks into a partial dataset);
- ``impossible_job``: a job in an unknown state, finished without ``finished_at``, failed without
  an error, succeeded with progress below 1, or naming a dataset that does not exist;
- ``dangling_reference``: a model whose datasets or parent, or a dataset whose job, is missing;
- ``unfinished_job``: a job queued or running while the service is not running (only when
  ``offline``; recovery marks it failed at the next start).
"""
from __future__ import annotations

import hashlib

from service.store import TERMINAL_STATES, Store
from service.store.chunks import partial_root

STATES = ("queued", "running", *TERMINAL_STATES)


def check_store(store: Store, quick: bool = False, offline: bool = False) -> dict:
    """Check ``store``; returns ``{"ok", "problems", "counts"}``. ``quick`` skips the checksums;
    ``offline`` says no service is running on the store (so no job may be queued or running)."""
    problems: list[dict] = []

    def problem(kind: str, record_id: str, detail: str) -> None:
        problems.append({"kind": kind, "id": record_id, "detail": detail})

    datasets = store.list_datasets()
    models = store.list_models()
    jobs = {row["id"]: row for row in store.list_jobs(limit=None)}
    dataset_ids = {row["id"] for row in datasets}
    referenced = set()
    for row in datasets:
        path = store.data_dir / row["file"]
        referenced.add(path.resolve())
        if not path.is_file():
            problem("missing_array", row["id"], f"array file {row['file']} is missing")
        elif not quick and hashlib.sha256(path.read_bytes()).hexdigest() != row["sha256"]:
            problem("corrupt_array", row["id"], f"array file {row['file']} does not match its sha256")
        if row["job_id"] and row["job_id"] not in jobs:
            problem("dangling_reference", row["id"], f"dataset names job {row['job_id']}, which does not exist")
    if store.arrays_dir.is_dir():
        for path in sorted(store.arrays_dir.iterdir()):
            if path.name.endswith(".tmp"):
                problem("temp_file", path.name, f"leftover temporary file arrays/{path.name}")
            elif path.is_file() and path.resolve() not in referenced:
                problem("orphan_array", path.stem, f"arrays/{path.name} belongs to no dataset")
    root = partial_root(store.data_dir)
    if root.is_dir():
        for directory in sorted(p for p in root.iterdir() if p.is_dir()):
            job = jobs.get(directory.name)
            if job is None or job["state"] in TERMINAL_STATES or offline:
                state = "no such job" if job is None else f"job is {job['state']}"
                problem("orphan_chunks", directory.name, f"partial/{directory.name}: {state}")
    for job in jobs.values():
        for detail in _job_problems(job, dataset_ids, offline):
            problem("unfinished_job" if detail.startswith("still") else "impossible_job", job["id"], detail)
    model_ids = {row["id"] for row in models}
    for row in models:
        missing = [d for d in row["datasets"] if d not in dataset_ids]
        if missing:
            problem("dangling_reference", row["id"], f"model names missing datasets {', '.join(missing)}")
        if row["parent_id"] and row["parent_id"] not in model_ids:
            problem("dangling_reference", row["id"], f"model's parent {row['parent_id']} does not exist")
    counts = {"datasets": len(datasets), "models": len(models), "jobs": len(jobs),
              "partial_datasets": sum(bool(row["partial"]) for row in datasets)}
    return {"ok": not problems, "problems": problems, "counts": counts}


def _job_problems(job: dict, dataset_ids: set[str], offline: bool) -> list[str]:
    state, out = job["state"], []
    if state not in STATES:
        return [f"unknown state {state!r}"]
    if state in TERMINAL_STATES and not job["finished_at"]:
        out.append(f"{state} but has no finished_at")
    if state == "running" and not job["started_at"]:
        out.append("running but has no started_at")
    if state == "failed" and not job["error"]:
        out.append("failed without an error")
    if state == "succeeded" and job["progress"] < 1.0:
        out.append(f"succeeded at progress {job['progress']:.2f}")
    dataset_id = (job["result"] or {}).get("dataset_id") if isinstance(job["result"], dict) else None
    if dataset_id and dataset_id not in dataset_ids:
        out.append(f"result names dataset {dataset_id}, which does not exist")
    if offline and state in ("queued", "running"):
        out.append(f"still {state} though no service runs (recovered at the next start)")
    return out


def format_report(report: dict) -> str:
    """The report in words, one problem a line."""
    c = report["counts"]
    head = (f"store: {c['datasets']} datasets ({c['partial_datasets']} partial), {c['models']} models, "
            f"{c['jobs']} jobs: " + ("consistent" if report["ok"] else f"{len(report['problems'])} problem(s)"))
    return "\n".join([head] + [f"  {p['kind']}: {p['id']}: {p['detail']}" for p in report["problems"]])

