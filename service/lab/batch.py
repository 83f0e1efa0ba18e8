"""Batch discovery: identify, diagnose and (for a bounded number of steps) run the discovery loop
over many stored datasets, one task per dataset and axis, in this process or on a Dask cluster.

A task (``discover_one``) is the REST path a user would take for one dataset and axis: POST
/api/models with ``model: composite, effects: [hysteresis]`` (service.usecases.identify), GET
/api/models/{id}/diagnosis (service.usecases.discover.diagnose_model), and with ``steps`` > 0 POST
/api/models/{id}/discover with ``max_steps = steps + 1`` (service.usecases.discover_run.discover;
no experiments: a batch has no bench). It opens the store from its ``StoreAddress`` in the process
it runs in, stores every model it fits (with the dataset's bench id) tagged ``batch:<id>``, and
returns a plain JSON-safe row. The fit and diagnosis draw no random numbers, so a task gives the
same numbers wherever it runs; the rows differ only in the ids of the models stored
(``comparable`` leaves those out).

On a cluster a worker that dies mid-task loses nothing: the scheduler runs the task again on
another worker (up to ``distributed.scheduler.allowed-failures`` deaths per task). A task run twice
stores its models twice; the result names the run that finished.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Sequence

from service.lab.address import StoreAddress, open_store
from service.science.data.holdout import split_blocks
from service.science.discovery.parameters import physical_parameters
from service.science.discovery.registry import model_for
from service.science.errors import FieldError
from service.store import NotFoundError, Store, clean_json
from service.usecases.discover import diagnose_model
from service.usecases.discover_run import discover
from service.usecases.identify import load_record, require_fit_memory, store_model

AXES = ("y", "z")
#: fields of a result row that name stored rows (differ between two runs of the same batch)
REFERENCES = ("model_id", "final_model_id")

#: how often a batch on a cluster looks at its cancel flag while it waits for results (s)
CANCEL_POLL_S = 0.5
#: ``on_result(row, done, total)``: called as each task's row arrives (in completion order)
ResultCallback = Callable[[dict, int, int], None]


class _BatchContext:
    """What the discover loop needs of a job inside a batch task: no job row, never cancelled,
    progress kept by the batch (per task), not per step."""

    job_id = None
    cancelled = False

    def progress(self, fraction: float, message: str | None = None, partial: dict | None = None) -> None:
        pass


def plan_batch(store: Store, dataset_ids: Sequence[str] | None = None, axes: Sequence[str] = AXES) -> list[dict]:
    """One row per dataset and axis, in dataset order: ``{"dataset_id", "axis", "bench_id",
    "dataset_name"}`` to run, plus ``"status": "skipped"`` and ``"reason"`` where the row already shows
    that a diagnosis cannot run (no such axis, no block that drives it). FieldError names
    ``dataset_ids`` or ``axes`` at fault."""
    bad = [a for a in axes if a not in AXES]
    if bad or not axes:
        raise FieldError("axes", f"{', '.join(map(repr, bad)) or 'an empty list'}: use some of {', '.join(AXES)}")
    if dataset_ids is None:
        rows = store.list_datasets()
    else:
        rows = []
        for dataset_id in dataset_ids:
            try:
                rows.append(store.get_dataset(dataset_id))
            except NotFoundError:
                raise FieldError("dataset_ids", f"no dataset with id {dataset_id!r}") from None
    plan = []
    for row in rows:
        for axis in axes:
            entry = {
                "bench_id": row.get("bench_id"),
                "dataset_id": row["id"],
                "dataset_name": row["name"],
                "axis": axis,
            }
            if axis not in row["axes"]:
                entry.update(status="skipped", reason=f"no {axis} axis (the dataset has {', '.join(row['axes'])})")
            elif not split_blocks(row["blocks"], row["samples"], row["sample_rate_hz"], axis):
                entry.update(status="skipped", reason=f"no block drives axis {axis}")
            plan.append(entry)
    return plan


def discover_one(
    address: StoreAddress,
    dataset_id: str,
    axis: str,
    steps: int = 0,
    n_operators: int = 10,
    batch_id: str | None = None,
    continue_past_ambiguity: bool = False,
) -> dict:
    """One task: identify the hysteresis model of ``axis`` of a stored dataset, diagnose it, and run
    the discovery loop for at most ``steps`` added effects (a batch runs no experiment: the loop stops
    at an ambiguity, ``stopped`` "needs_experiment", unless ``continue_past_ambiguity``). A JSON-safe row (µm; ``status`` "ok", or
    "skipped" with the ``reason`` the data cannot be modelled)."""
    store = open_store(address)
    row = store.get_dataset(dataset_id)
    out = {"bench_id": row.get("bench_id"), "dataset_id": dataset_id, "dataset_name": row["name"], "axis": axis}
    try:
        require_fit_memory(store, [dataset_id])  # this worker's free memory, not the planner's
        record = load_record(store, dataset_id, axis, row=row)
    except FieldError as exc:
        return {**out, "status": "skipped", "reason": exc.message}
    if not record.training_mask(own_axis_only=True).any():
        return {
            **out,
            "status": "skipped",
            "reason": "no training data: every block is too short to hold out its last cycle and keep one for the fit",
        }
    labels = {"tags": [f"batch:{batch_id}"] if batch_id else []}  # the bench: the dataset's (Store.add_model)
    estimator = model_for("composite", ["hysteresis"], n_operators)
    estimator.fit([record])
    base = store_model(store, estimator, [record], axis, [dataset_id], ["hysteresis"], n_operators, None, None, labels)
    d = diagnose_model(store, base["id"], records=[record])
    out.update(
        {
            "status": "ok",
            "model_id": base["id"],
            "parameters_sha256": base["parameters_sha256"],
            "train_rms_um": d["train_rms_um"],
            "held_out_rms_um": d["residual_rms_um"],
            "noise_floor_um": d["noise_floor_um"],
            "at_noise_floor": d["at_noise_floor"],
            "verdict": d["verdict"],
            "claimed_effects": [c["effect"] for c in d["candidates"] if c["claimed"] and c["kind"] == "physical"],
            "ambiguous": d["ambiguity"]["effects"] if d.get("ambiguity") else None,
            "candidates": [
                {k: c[k] for k in ("effect", "kind", "claimed", "p_value", "expected_rms_um")}
                for c in d["candidates"]
                if c["testable"]
            ],
            # the loop's figures; with steps = 0 the loop does not run and the base model is the final one
            "final_model_id": base["id"],
            "effects": ["hysteresis"],
            "effects_found": [],
            "held_out_rms_after_um": d["residual_rms_um"],
            "physical_parameters": physical_parameters(estimator),
            "stopped": None,
        }
    )
    if steps > 0:
        run = discover(
            _BatchContext(),
            store,
            base["id"],
            max_steps=steps + 1,
            labels=labels,
            continue_past_ambiguity=continue_past_ambiguity,
        )
        out.update(
            {
                "final_model_id": run["final_model_id"],
                "effects": run["effects"],
                "effects_found": [e["effect"] for e in run["effects_found"]],
                "held_out_rms_after_um": run["remains"]["validation_rms_um"],
                "physical_parameters": run["final_parameters"],
                "stopped": run["stopped"],
            }
        )
    return clean_json(out)


def batch_discover(
    address: StoreAddress,
    dataset_ids: Sequence[str] | None = None,
    axes: Sequence[str] = AXES,
    steps: int = 0,
    n_operators: int = 10,
    client=None,
    on_result: ResultCallback | None = None,
    cancelled: Callable[[], bool] | None = None,
    continue_past_ambiguity: bool = False,
) -> dict:
    """Run ``discover_one`` for every dataset (all of the store's when ``dataset_ids`` is None) and
    axis: in this process when ``client`` is None, else as one task each on the Dask cluster of
    ``client`` (a distributed.Client). Returns ``{"batch_id", "steps", "n_operators", "ran", "ok",
    "skipped", "failed", "cancelled", "results"}``: one row per dataset and axis in dataset order; a
    task that raised is a row with ``status`` "failed" and its ``error``. When ``cancelled()`` turns
    true (polled between tasks, and every CANCEL_POLL_S on a cluster) the tasks not yet finished are
    cancelled and their rows say so; a task a worker is running finishes there, unread."""
    if steps < 0:
        raise FieldError("steps", f"must be 0 or more, not {steps}")
    plan = plan_batch(open_store(address), dataset_ids, axes)
    batch_id = uuid.uuid4().hex[:12]
    todo = [i for i, entry in enumerate(plan) if "status" not in entry]
    results = list(plan)
    done = []
    stop = cancelled or (lambda: False)

    def arrived(i: int, row: dict) -> None:
        results[i] = row
        done.append(i)
        if on_result is not None:
            on_result(row, len(done), len(todo))

    if client is None:
        for i in todo:
            if stop():
                break
            try:
                row = discover_one(
                    address,
                    plan[i]["dataset_id"],
                    plan[i]["axis"],
                    steps,
                    n_operators,
                    batch_id,
                    continue_past_ambiguity,
                )
            except Exception as exc:  # noqa: BLE001 - one dataset's failure is its row, not the batch's
                row = _failed(plan[i], exc)
            arrived(i, row)
    else:
        _run_on_cluster(
            client,
            address,
            plan,
            todo,
            arrived,
            stop,
            steps=steps,
            n_operators=n_operators,
            batch_id=batch_id,
            continue_past_ambiguity=continue_past_ambiguity,
        )
    for i in todo:
        if i not in done:
            results[i] = {**plan[i], "status": "cancelled"}
    count = {s: sum(1 for r in results if r.get("status") == s) for s in ("ok", "skipped", "failed", "cancelled")}
    return {
        "batch_id": batch_id,
        "steps": steps,
        "n_operators": n_operators,
        "ran": len(todo),
        **count,
        "results": results,
    }


def _run_on_cluster(client, address, plan, todo, arrived, stop, **options) -> None:
    """One task per entry of ``todo`` on ``client``'s cluster (``options``: discover_one's keywords);
    each row to ``arrived`` as it comes; the rest cancelled once ``stop()``."""
    from distributed import wait

    futures = client.map(
        discover_one,
        [address] * len(todo),
        [plan[i]["dataset_id"] for i in todo],
        [plan[i]["axis"] for i in todo],
        pure=False,
        **options,
    )
    index = {f.key: i for f, i in zip(futures, todo)}
    pending = set(futures)
    while pending:
        if stop():
            client.cancel(list(pending))
            return
        try:
            finished, pending = wait(pending, timeout=CANCEL_POLL_S, return_when="FIRST_COMPLETED")
        except TimeoutError:
            continue
        for future in sorted(finished, key=lambda f: index[f.key]):
            i = index[future.key]
            arrived(i, future.result() if future.status == "finished" else _failed(plan[i], future.exception()))
            future.release()


def _failed(entry: dict, exc: BaseException) -> dict:
    return {**entry, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}


def comparable(results: list[dict]) -> list[dict]:
    """The rows without the ids of the models stored, so two runs of one batch compare equal when
    they computed the same numbers."""
    return [{k: v for k, v in row.items() if k not in REFERENCES} for row in results]
