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
from service.science.data.units import fmt_nm
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
    loop = _Loop.start(store, model_id, labels)
    stopped, reason, needed = "max_steps", f"stopped after max_steps = {max_steps} steps", None
    for index in range(max_steps):
        loop.raise_if_cancelled(ctx, index)
        d = loop.step(ctx, store, index, max_steps)
        add = next_effect(d)
        need = needed_experiment(d, stopping=add is None, done=[e["experiment"] for e in loop.run["experiments"]])
        if need is not None:
            busy = bench_jobs() if bench_jobs else []
            why = _why_not_run(allow_experiments, run_experiment is not None, busy, index == max_steps - 1, max_steps)
            if why is None:
                loop.join(store, _experiment(ctx, store, loop.run, need, run_experiment))
                continue
            needed = need
            loop.run["suggested"].append({**need, "after_step": index, "not_run_because": why})
            stop = _stop_without_experiment(d, need, add, why, continue_past_ambiguity)
            if stop is not None:
                stopped, reason = stop
                break
        if add is None:
            stopped, reason = _natural_stop(d), d["verdict_text"]
            break
        loop.add(add, index, d)
    return _result(loop.run, needed, stopped, reason, loop.run.get("final_model"))


class _Loop:
    """The discover job's state between steps: the records (``datasets`` of ``axis``), the effects
    and transform parameters so far, the last fitted model (None: fit afresh), the dataset an
    experiment just added (``joined``) and ``run``, what the result reports."""

    def __init__(self, model_id: str, row: dict, records: list, labels: dict | None):
        self.model_id, self.axis, self.datasets = model_id, row["axis"], list(row["datasets"])
        self.n_operators = int((row["options"] or {}).get("n_operators", 10))
        self.records, self.labels, self.joined = records, labels, None
        start = as_composite(load_model(row))
        self.effects, self.theta = list(start.effects), dict(start.theta)
        self.model = start if start.is_fitted else None  # a paper's PI stands for the unfitted composite
        #: step 0's figure is the stand-in composite's, not the stored model's own: both are labelled
        self.stands_in = (
            None
            if start.is_fitted
            else {"kind": row["kind"], "validation_rms_um": (row.get("metrics") or {}).get("validation_rms_um")}
        )
        self.run = {
            "start_model_id": model_id,
            "axis": self.axis,
            "steps": [],
            "experiments": [],
            "added": {},
            "suggested": [],
        }

    @classmethod
    def start(cls, store: Store, model_id: str, labels: dict | None) -> _Loop:
        """The loop from stored model ``model_id``, on the records of its datasets."""
        row = store.get_model(model_id)
        return cls(model_id, row, load_records(store, list(row["datasets"]), row["axis"]), labels)

    def raise_if_cancelled(self, ctx: JobContext, index: int) -> None:
        """JobInterrupted (cancelled, with the result so far) when the job was cancelled before step ``index``."""
        if ctx.cancelled:
            raise JobInterrupted(
                f"cancelled after step {index - 1}",
                result=_result(self.run, None, "cancelled", "cancelled between steps", self.run.get("final_model")),
                cancelled=True,
            )

    def step(self, ctx: JobContext, store: Store, index: int, max_steps: int) -> dict:
        """Fit and diagnose hysteresis + the effects so far, store the model (step 0: the start
        model itself), report progress; the diagnosis."""
        ctx.progress(
            index / max_steps,
            f"step {index}: fitting and diagnosing hysteresis + {' + '.join(self.effects) or 'nothing'}",
        )
        self.model, step = discovery_step(self.records, self.effects, self.n_operators, self.theta, model=self.model)
        self.theta, d = self.model.theta, step["diagnosis"]
        step_id = self.model_id if index == 0 else self._store(store, ctx)
        self.run["steps"].append(_step_summary(index, step_id, step, self.run, self.joined))
        self.run["steps"][-1]["fit"] = _fit_label(index, self.stands_in, step["effects"])
        if self.joined is not None:
            self.run["experiments"][-1]["resolved"] = _resolved(self.run["experiments"][-1]["effects"], d)
        self.joined = None
        self.run["final_model"] = self.model
        ctx.progress(
            (index + 1) / max_steps,
            _step_words(self.run["steps"][-1]),
            partial=_result(self.run, None, "running", None, self.model),
        )
        return d

    def _store(self, store: Store, ctx: JobContext) -> str:
        """Store this step's model with the previous step's as its parent; its id."""
        return store_model(
            store,
            self.model,
            self.records,
            self.axis,
            list(self.datasets),
            ["hysteresis"] + ordered(self.effects),
            self.n_operators,
            self.run["steps"][-1]["model_id"],
            ctx.job_id,
            self.labels,
        )["id"]

    def join(self, store: Store, dataset_id: str) -> None:
        """An experiment's dataset joins the records: the same effects are refitted on every dataset."""
        self.joined = dataset_id
        self.datasets.append(dataset_id)
        self.records.append(load_record(store, dataset_id, self.axis))
        self.model = None

    def add(self, effect: str, index: int, d: dict) -> None:
        """Add ``effect`` (claimed by diagnosis ``d`` of step ``index``) for the next step's fit."""
        self.run["added"][effect] = (index, next(c for c in d["candidates"] if c["effect"] == effect))
        self.effects, self.model = self.effects + [effect], None


def _why_not_run(allowed: bool, can_run: bool, busy: list[str], last: bool, max_steps: int) -> str | None:
    """Why a needed experiment is not run (not allowed, the bench busy, no step left to use its
    data), or None when it is run."""
    if allowed and can_run and not busy and not last:
        return None
    if not allowed:
        return "ask again with allow_experiments to run it"
    if busy:
        return f"the bench is busy with {', '.join(busy)}"
    return f"max_steps = {max_steps} leaves no step to use it"


def _stop_without_experiment(
    d: dict, need: dict, add: str | None, why: str, continue_past_ambiguity: bool
) -> tuple[str, str] | None:
    """(stopped, reason) when the loop stops for an experiment it does not run, or None when it goes
    on (``continue_past_ambiguity``: with the leading claimed effect, the step and the result naming
    the sweep that would tell the pair apart)."""
    if add is None:  # done as far as the data goes; the experiment would test more
        return _natural_stop(d), f"{d['verdict_text']}; an experiment would test {', '.join(need['effects'])}: {why}"
    if continue_past_ambiguity:
        return None
    # ``need`` is the ambiguity (stops_at_ambiguity's answer)
    return "needs_experiment", (
        f"{need['reason']}. Adding either would be a guess the data cannot back, so the loop "
        f"stops here: {why}, or with continue_past_ambiguity to add {add} (the leading "
        f"claim) and go on"
    )


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


def _fit_label(index: int, stands_in: dict | None, effects: list[str]) -> str:
    """Which fit a step's figures are of. Step 0 of a paper's model (static/dynamic PI, GRPI) is the
    composite fitted on the same data standing for it, whose held-out RMS differs from the one the
    model's own page shows (the stored model's): both are named."""
    if index == 0 and stands_in is not None:
        return (
            f"the composite {' + '.join(effects)} fitted on the same data, standing for this {stands_in['kind']} "
            f"(the {stands_in['kind']}'s own held-out RMS, on its page: {fmt_nm(stands_in['validation_rms_um'], 4)})"
        )
    return "the start model as stored" if index == 0 else "this step's stored model"


def _step_words(step: dict) -> str:
    change = f"+{step['added']}" if step["added"] else ("refit with the experiment" if step["step"] else "start")
    return (
        f"step {step['step']} ({change}): model {step['model_id']}, held-out RMS "
        f"{fmt_nm(step['validation_rms_um'])}, noise floor {fmt_nm(step['noise_floor_um'])}"
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
