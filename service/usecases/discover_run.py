"""The discover job: the automatic discovery loop run from a stored model, every step a stored model.

The decisions are the science loop's (service.science.discovery.loop: ``discovery_step``,
``next_effect``, ``needed_experiment``), so the job reaches what ``python -m
service.reports.discovery`` reaches on the same records. Here only what the report cannot do: each
fitted step is validated and stored with ``parent_id`` = the previous step; progress (with the
steps so far) is reported after each; a cancel is honoured between steps; and when the loop needs an
experiment it is run on the bench (``run_experiment``, when allowed and the bench is free) and its
dataset joins the fit, or the job stops and names it (``stopped`` = "needs_experiment"; at an
ambiguity ``continue_past_ambiguity`` adds the leading claimed effect instead and goes on).
"""

from __future__ import annotations

from collections.abc import Callable

from service.runtime.jobs import JobContext, JobInterrupted
from service.science.discovery.composite import as_composite
from service.science.discovery.loop import discovery_step, needed_experiment, next_effect
from service.science.discovery.parameters import physical_parameters
from service.science.effects import EFFECTS, ordered
from service.store import Store
from service.usecases.identify import load_model, load_record, load_records, store_model

#: ``run_experiment(ctx, sweep_body) -> the sweep's finished job``; ``bench_jobs() -> [job ids]`` that
#: hold or wait for the bench (service.usecases.acquire.sweep_and_wait, JobManager.bench_jobs)
ExperimentRunner = Callable[[JobContext, dict], dict]


def discover(
    ctx: JobContext,
    store: Store,
    model_id: str,
    max_steps: int = 8,
    allow_experiments: bool = False,
    run_experiment: ExperimentRunner | None = None,
    bench_jobs: Callable[[], list[str]] | None = None,
    labels: dict | None = None,
    continue_past_ambiguity: bool = False,
) -> dict:
    """Job body: the loop from stored model ``model_id`` for at most ``max_steps`` steps (the start
    model's diagnosis is step 0); each step's model is stored with ``labels`` (more fields of its
    row: bench, tags). Where a diagnosis names an experiment that is not run (not allowed, the bench
    busy, no step left), the job stops there (``stopped`` = "needs_experiment") and names it, unless
    ``continue_past_ambiguity`` (then it adds the leading claimed effect, as an ambiguity allows, and
    goes on). Returns ``{"start_model_id", "final_model_id", "final_parameters" (every
    effect of the final model), "steps", "effects_found", "remains", "stopped", "stop_reason",
    "needed_experiment", "experiments"}`` (units in the names)."""
    row = store.get_model(model_id)
    axis, datasets = row["axis"], list(row["datasets"])
    n_operators = int((row["options"] or {}).get("n_operators", 10))
    records = load_records(store, datasets, axis)
    start = as_composite(load_model(row))
    effects, theta = list(start.effects), dict(start.theta)
    model = start if start.is_fitted else None  # a paper's PI stands for the unfitted composite
    run = {"start_model_id": model_id, "axis": axis, "steps": [], "experiments": [], "added": {}, "suggested": []}
    stopped, reason, needed = "max_steps", f"stopped after max_steps = {max_steps} steps", None
    joined = None  # an experiment's dataset, new in this step's fit
    for index in range(max_steps):
        if ctx.cancelled:
            raise JobInterrupted(
                f"cancelled after step {index - 1}",
                result=_result(run, None, "cancelled", "cancelled between steps", run.get("final_model")),
                cancelled=True,
            )
        ctx.progress(
            index / max_steps, f"step {index}: fitting and diagnosing hysteresis + {' + '.join(effects) or 'nothing'}"
        )
        model, step = discovery_step(records, effects, n_operators, theta, model=model)
        theta, d = model.theta, step["diagnosis"]
        step_id = (
            model_id
            if index == 0
            else store_model(
                store,
                model,
                records,
                axis,
                list(datasets),
                ["hysteresis"] + ordered(effects),
                n_operators,
                run["steps"][-1]["model_id"],
                ctx.job_id,
                labels,
            )["id"]
        )
        run["steps"].append(_step_summary(index, step_id, step, run, joined))
        if joined is not None:
            run["experiments"][-1]["resolved"] = _resolved(run["experiments"][-1]["effects"], d)
        joined = None
        run["final_model"] = model
        ctx.progress(
            (index + 1) / max_steps, _step_words(run["steps"][-1]), partial=_result(run, None, "running", None, model)
        )
        add = next_effect(d)
        need = needed_experiment(d, stopping=add is None, done=[e["experiment"] for e in run["experiments"]])
        if need is not None:
            busy = bench_jobs() if bench_jobs else []
            last = index == max_steps - 1  # no step left to use the experiment's data
            if not allow_experiments or run_experiment is None or busy or last:
                needed = need
                why = (
                    "ask again with allow_experiments to run it"
                    if not allow_experiments
                    else f"the bench is busy with {', '.join(busy)}"
                    if busy
                    else f"max_steps = {max_steps} leaves no step to use it"
                )
                run["suggested"].append({**need, "after_step": index, "not_run_because": why})
                if add is None:  # done as far as the data goes; the experiment would test more
                    stopped = _natural_stop(d)
                    reason = f"{d['verdict_text']}; an experiment would test {', '.join(need['effects'])}: {why}"
                    break
                if not continue_past_ambiguity:  # ``need`` is the ambiguity (stops_at_ambiguity's answer)
                    stopped = "needs_experiment"
                    reason = (
                        f"{need['reason']}. Adding either would be a guess the data cannot back, so the loop "
                        f"stops here: {why}, or with continue_past_ambiguity to add {add} (the leading "
                        f"claim) and go on"
                    )
                    break
                # continue_past_ambiguity: the loop goes on with the leading claimed effect, and the
                # step and the result name the sweep that would tell the pair apart
            else:
                joined = _experiment(ctx, store, run, need, run_experiment)
                datasets.append(joined)
                records.append(load_record(store, joined, axis))
                model = None  # the same effects, refitted on every dataset
                continue
        if add is None:
            stopped, reason = _natural_stop(d), d["verdict_text"]
            break
        run["added"][add] = (index, next(c for c in d["candidates"] if c["effect"] == add))
        effects, model = effects + [add], None
    return _result(run, needed, stopped, reason, run.get("final_model"))


def _experiment(ctx: JobContext, store: Store, run: dict, need: dict, run_experiment: ExperimentRunner) -> str:
    """Run the experiment the loop needs; its dataset id (JobInterrupted if the sweep did not succeed)."""
    ctx.progress(
        _experiment_fraction(run), f"running the experiment for {', '.join(need['effects'])}: {need['experiment']}"
    )
    sweep = run_experiment(ctx, need["experiment"])
    dataset_id = (sweep.get("result") or {}).get("dataset_id")
    if sweep["state"] != "succeeded" or not dataset_id:
        raise JobInterrupted(
            f"the experiment's sweep {sweep['id']} ended {sweep['state']}: {sweep.get('error')}",
            result=_result(run, need, "experiment_failed", sweep.get("error"), run.get("final_model")),
        )
    run["experiments"].append(
        {**need, "sweep_job_id": sweep["id"], "dataset_id": dataset_id, "after_step": len(run["steps"]) - 1}
    )
    return dataset_id


def _natural_stop(d: dict) -> str:
    """Why the loop stops when there is nothing left to add: at the noise floor, or complete."""
    return "at_noise_floor" if d["at_noise_floor"] else "complete"


def _resolved(effects: list[str], d: dict) -> bool:
    """Whether the diagnosis with an experiment's data no longer has what the experiment was for:
    the ambiguity between ``effects``, or ``effects`` not testable."""
    still = set(d["ambiguity"]["effects"]) if d.get("ambiguity") else set()
    still |= {c["effect"] for c in d.get("not_testable", [])}
    return not set(effects) <= still


def _experiment_fraction(run: dict) -> float:
    """Progress while an experiment runs: more the more steps are done, never the end (0..0.95)."""
    return min(0.95, len(run["steps"]) / (len(run["steps"]) + 2))


def _step_summary(index: int, model_id: str, step: dict, run: dict, joined: str | None) -> dict:
    """One step as the result shows it (µm); ``joined``: the experiment's dataset new in its fit."""
    d = step["diagnosis"]
    previous = run["steps"][-1] if run["steps"] else None
    added = [e for e in step["effects"] if previous and e not in previous["effects"]]
    return {
        "step": index,
        "model_id": model_id,
        "parent_id": previous["model_id"] if previous else None,
        "effects": step["effects"],
        "added": added[0] if added else None,
        "experiment_dataset_id": joined,
        "validation_rms_um": d["residual_rms_um"],
        "train_rms_um": d["train_rms_um"],
        "noise_floor_um": d["noise_floor_um"],
        "ratio_to_noise_floor": _ratio(d["residual_rms_um"], d["noise_floor_um"]),
        "at_noise_floor": d["at_noise_floor"],
        "verdict": d["verdict"],
        "verdict_text": d["verdict_text"],
        "ambiguous": d["ambiguity"]["effects"] if d.get("ambiguity") else None,
        "per_block": [
            {**b, "ratio_to_noise_floor": _ratio(b["validation_rms_um"], b["noise_floor_um"])}
            for b in step["per_block"]
        ],
        "not_testable": [
            {"effect": c["effect"], "reason": c["reason"], "experiment": c["experiment"]} for c in d["not_testable"]
        ],
    }


def _step_words(step: dict) -> str:
    change = f"+{step['added']}" if step["added"] else ("refit with the experiment" if step["step"] else "start")
    return (
        f"step {step['step']} ({change}): model {step['model_id']}, held-out RMS "
        f"{step['validation_rms_um'] * 1e3:.3g} nm, noise floor {step['noise_floor_um'] * 1e3:.3g} nm"
    )


def _ratio(value_um: float | None, floor_um: float | None) -> float | None:
    return value_um / floor_um if value_um is not None and floor_um else None


def _result(run: dict, needed: dict | None, stopped: str, reason: str | None, final_model) -> dict:
    """The job's answer (also its partial result while it runs)."""
    steps = run["steps"]
    last = steps[-1] if steps else None
    parameters = physical_parameters(final_model) if final_model is not None else {}
    found = [
        {
            "effect": name,
            "kind": EFFECTS[name].kind,
            "added_at_step": index + 1,
            "parameters": parameters.get(name, {}),
            "evidence": c["evidence"],
            "p_value": c["p_value"],
            "score": c["score"],
            "expected_rms_um": c["expected_rms_um"],
        }
        for name, (index, c) in run["added"].items()
        if index + 1 < len(steps)
    ]
    remains = (
        None
        if last is None
        else {
            k: last[k]
            for k in (
                "validation_rms_um",
                "noise_floor_um",
                "ratio_to_noise_floor",
                "at_noise_floor",
                "verdict",
                "verdict_text",
                "per_block",
                "not_testable",
            )
        }
    )
    return {
        "start_model_id": run["start_model_id"],
        "axis": run["axis"],
        "final_model_id": last["model_id"] if last else None,
        "effects": last["effects"] if last else None,
        "final_parameters": parameters,
        "steps": list(steps),
        "effects_found": found,
        "remains": remains,
        "stopped": stopped,
        "stop_reason": reason,
        "needed_experiment": needed,
        "experiments": list(run["experiments"]),
        "suggested_experiments": list(run["suggested"]),
    }
