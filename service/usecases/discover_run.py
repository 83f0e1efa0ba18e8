"""The discover job: the automatic discovery loop run from a stored model, every step a stored model.

The decisions are the science loop's (service.science.discovery.loop: ``discovery_step``,
``try_step``, ``next_effect``, ``needed_experiment``), so the job reaches what ``python -m
service.reports.discovery`` reaches on the same records. Here only what the report cannot do: each
fitted step is validated and stored with ``parent_id`` = the previous step; progress (with the
steps so far) is reported after each; a cancel stops the fit at work at its next solve
(service.science.interrupt), the steps done kept; and when the loop needs an
experiment it is run on the bench (service.usecases.discover_experiments: when allowed, the bench
free, within ``max_experiments``, cut to the bench's limits) and its dataset joins the fit, or the
job stops and names it (``stopped`` = "needs_experiment"; at an ambiguity ``continue_past_ambiguity``
adds the leading claimed effect instead and goes on; an experiment the bench cannot run is skipped
with its reason and the loop goes on).

Only model steps count against ``max_steps`` (the start and each effect tried, kept or not); the
refit on an experiment's data does not. An added effect that raises the held-out RMS on the same data
is not kept (``not_kept``): the loop stays on the step before and tries the next candidate. When an
experiment adds data, every step is scored again on the enlarged data (``like_for_like_rms_um``,
service.science.discovery.like_for_like), beside its figure on the data the run started from.
Where the loop would stop short of the noise floor, the base's grid is compared once with its
alternatives refitted in its place (``grid_swap``); a step that swaps it reports ``replaced``.
"""

from __future__ import annotations

from dataclasses import replace

from service.runtime.jobs import JobContext, JobInterrupted
from service.science.discovery.composite import as_composite
from service.science.discovery.diagnosis import fitted_without_lines
from service.science.discovery.like_for_like import effects_key, like_for_like
from service.science.discovery.loop import (
    MAX_STEPS,
    discovery_step,
    grid_swap,
    needed_experiment,
    next_effect,
    refitted_choice,
    swappable_grid,
    try_step,
)
from service.science.discovery.rests import LineFree
from service.science.effects import EFFECTS, ordered
from service.science.interrupt import Interrupted, interruptible
from service.store import Store
from service.usecases.discover_experiments import MAX_EXPERIMENTS, ExperimentPolicy, fit_experiments, recorded_already
from service.usecases.discover_result import (
    discover_result,
    fit_label,
    guess_words,
    natural_stop,
    step_summary,
    step_words,
    stop_without_experiment,
)
from service.usecases.identify import load_model, load_record, load_records, store_model


def discover(
    ctx: JobContext,
    store: Store,
    model_id: str,
    max_steps: int = MAX_STEPS,
    allow_experiments: bool = False,
    labels: dict | None = None,
    continue_past_ambiguity: bool = False,
    max_experiments: int = MAX_EXPERIMENTS,
    bench: ExperimentPolicy | None = None,
) -> dict:
    """Job body: the loop from stored model ``model_id`` for at most ``max_steps`` model steps (the
    start model's diagnosis is step 0) and ``max_experiments`` experiments, run through ``bench``
    (its runner, busy list and limits check; None: no bench); each step's model is stored with
    ``labels`` (more fields of its row: bench, tags). Where a diagnosis names an experiment that is
    not run (not allowed, the bench busy, none left), the job stops there (``stopped`` =
    "needs_experiment") and names it, unless ``continue_past_ambiguity`` (then it adds the leading
    claimed effect, as an ambiguity allows, and goes on); one the bench cannot run is skipped and
    the loop goes on. Returns ``{"start_model_id", "final_model_id", "final_parameters", "steps",
    "effects_found", "not_kept", "remains", "stopped", "stop_reason", "needed_experiment",
    "experiments", "suggested_experiments", "original_datasets", "like_for_like_datasets"}`` (units
    in the names)."""
    policy = replace(bench or ExperimentPolicy(), allowed=allow_experiments, max_experiments=max_experiments)
    loop = _Loop.start(store, model_id, labels)
    # what each step proposes to test is what this bench runs (none for another stage's data)
    loop.fit = policy.fit if policy.elsewhere is None else None
    try:
        with interruptible(lambda: ctx.cancelled):  # a cancel lands at the fit's next solve
            return _run(ctx, store, loop, policy, max_steps, continue_past_ambiguity)
    except Interrupted:
        loop.raise_if_cancelled(ctx, during=True)
        raise


def _run(
    ctx: JobContext, store: Store, loop: _Loop, policy: ExperimentPolicy, max_steps: int, continue_past_ambiguity: bool
) -> dict:
    """The loop's decisions, step by step, until a verdict, a stop or ``max_steps``: ``discover``'s result."""
    stopped, reason, needed = "max_steps", f"stopped after max_steps = {max_steps} model steps", None
    d, fresh = loop.step(ctx, store, max_steps), True
    while True:
        add = next_effect(d, loop.excluded)
        # asked again after an effect not kept only when the loop would stop (then it may need a sweep)
        need = needed_experiment(d, stopping=add is None, done=loop.asked) if fresh or add is None else None
        if need is not None:
            why, skipped = _experiment(ctx, store, loop, need, policy, max_steps)
            if why is None:
                d, fresh = loop.step(ctx, store, max_steps), True
                continue
            needed = needed if skipped else need
            stop = stop_without_experiment(d, need, add, why, continue_past_ambiguity or skipped)
            swapped = loop.try_swap(ctx, store, d, max_steps) if stop is not None and add is None else None
            if swapped is not None:
                d, fresh = swapped, True
                continue
            if stop is not None:
                stopped, reason = stop
                break
        if add is None:
            swapped = loop.try_swap(ctx, store, d, max_steps)
            if swapped is not None:
                d, fresh = swapped, True
                continue
            stopped, reason = natural_stop(d), d["answer"]["text"] + loop.not_kept_words() + guess_words(needed)
            break
        if loop.model_steps >= max_steps:
            break
        tried = loop.try_add(ctx, store, add, d, max_steps)
        d, fresh = (tried, True) if tried is not None else (d, False)
    return discover_result(loop.run, needed, stopped, reason, loop.run.get("final_model"))


class _Loop:
    """The discover job's state between steps: the records (``datasets`` of ``axis``, the first
    ``n_original`` the start model's), the effects and transform parameters so far, the last fitted
    model (None: fit afresh), the dataset an experiment just added (``joined``), the effects tried on
    this step and not kept (``excluded``), the experiment bodies asked for and run or skipped
    (``asked``), the model steps fitted, each step's ``(effects, theta)`` and its like-for-like
    figures on the records as they are (``scores``), and ``run``, what the result reports."""

    def __init__(self, model_id: str, row: dict, records: list, labels: dict | None):
        self.model_id, self.axis, self.datasets = model_id, row["axis"], list(row["datasets"])
        self.n_operators = int((row["options"] or {}).get("n_operators", 10))
        self.records, self.labels, self.joined = records, labels, None
        self.n_original = len(records)
        start = as_composite(load_model(row))
        self.effects, self.theta = list(start.effects), dict(start.theta)
        #: the records as every step fits and judges them (without the rests' lines), made again when they grow
        self.line_free = LineFree.of(records)
        # the start model, fitted on the records as recorded, as fitted without their lines; a paper's
        # PI stands for the unfitted composite
        self.model = fitted_without_lines(self.line_free, start) if start.is_fitted else None
        #: step 0's figure is the stand-in composite's, not the stored model's own: both are labelled
        self.stands_in = (
            None
            if start.is_fitted
            else {"kind": row["kind"], "validation_rms_um": (row.get("metrics") or {}).get("validation_rms_um")}
        )
        self.excluded, self.asked, self.model_steps = [], [], 0
        #: whether the base's grid has been compared with its alternatives at the loop's end (once a run)
        self.swapped = False
        #: the bench's check and cut of a sweep, for the experiments a step proposes (None: as named)
        self.fit = None
        self.history, self.fitted, self.scores = [], {}, {}
        self.run = {
            "start_model_id": model_id,
            "axis": self.axis,
            "steps": [],
            "experiments": [],
            "added": {},
            "suggested": [],
            "not_kept": [],
            "original_datasets": list(self.datasets),
        }

    @classmethod
    def start(cls, store: Store, model_id: str, labels: dict | None) -> _Loop:
        """The loop from stored model ``model_id``, on the records of its datasets."""
        row = store.get_model(model_id)
        return cls(model_id, row, load_records(store, list(row["datasets"]), row["axis"]), labels)

    def raise_if_cancelled(self, ctx: JobContext, during: bool = False) -> None:
        """JobInterrupted (cancelled, with the result so far) when the job was cancelled; ``during``: a
        fit of the next step was stopped at a checkpoint (service.science.interrupt), its work dropped."""
        if ctx.cancelled:
            done = len(self.run["steps"])
            kept = {0: "no step kept", 1: "step 0 kept"}.get(done, f"steps 0–{done - 1} kept")
            raise JobInterrupted(
                f"cancelled during step {done}: {kept}" if during else f"cancelled after step {done - 1}",
                result=discover_result(
                    self.run,
                    None,
                    "cancelled",
                    f"cancelled while fitting step {done}; {kept}" if during else "cancelled between steps",
                    self.run.get("final_model"),
                ),
                cancelled=True,
            )

    def _progress(self, ctx: JobContext, max_steps: int, message: str, partial: bool = False) -> None:
        fraction = min(0.99, self.model_steps / max_steps)
        result = discover_result(self.run, None, "running", None, self.model) if partial else None
        ctx.progress(fraction, message, partial=result)

    def step(self, ctx: JobContext, store: Store, max_steps: int) -> dict:
        """Fit (unless fitted) and diagnose hysteresis + the effects so far, store the model (step 0:
        the start model itself), score it like for like, report progress; the diagnosis. Step 0
        counts as a model step; the refit on an experiment's data does not."""
        self.raise_if_cancelled(ctx)
        index = len(self.run["steps"])
        self.model_steps += 0 if self.joined else 1
        what = "refitting with the experiment's data" if self.joined else "fitting and diagnosing"
        self._progress(ctx, max_steps, f"step {index}: {what} hysteresis + {' + '.join(self.effects) or 'nothing'}")
        self.model, step = discovery_step(self.line_free, self.effects, self.n_operators, self.theta, model=self.model)
        return self._keep(ctx, store, step, max_steps)

    def try_add(self, ctx: JobContext, store: Store, effect: str, d: dict, max_steps: int) -> dict | None:
        """Fit the model + ``effect`` (claimed by diagnosis ``d``, the last step's): kept, it is the
        next step (its diagnosis returned); if it raised the held-out RMS, it is stored, reported
        in ``not_kept`` and the loop stays on the last step (None). A model step either way."""
        self.raise_if_cancelled(ctx)
        self.model_steps += 1
        index = len(self.run["steps"])
        grids = [
            c["effect"] for c in d["candidates"] if c.get("claimed") and c["effect"] in EFFECTS[effect].alternative_to
        ]
        choice = f" or {' or '.join(grids)} (the refits choose the grid)" if grids else ""
        self._progress(
            ctx, max_steps, f"step {index}: fitting hysteresis + {' + '.join(self.effects + [effect])}{choice}"
        )
        effect, fitted = refitted_choice(self.line_free, self.effects, effect, self.n_operators, self.theta, d)
        effects = self.effects + [effect]
        model, step, rejected = try_step(
            self.line_free, effects, effect, self.n_operators, self.theta, d["residual_rms_um"], fitted
        )
        if rejected is not None:
            model_id = self._store(store, ctx, model, effects)
            self.excluded.append(effect)
            entry = {**rejected, "model_id": model_id, "after_step": index - 1}
            self.run["not_kept"].append(entry)
            self.run["steps"][-1]["not_kept"].append(entry)
            self._progress(ctx, max_steps, f"step {index}: {rejected['text']} (model {model_id})", partial=True)
            return None
        candidate = next(c for c in d["candidates"] if c["effect"] == effect)
        self.run["added"][effect] = (index, candidate)
        self.effects, self.model, self.excluded = effects, model, []
        return self._keep(ctx, store, step, max_steps)

    def try_swap(self, ctx: JobContext, store: Store, d: dict, max_steps: int) -> dict | None:
        """Where the loop would stop short of the noise floor: the base's grid against its alternatives
        refitted in its place (``grid_swap``, once a run, while model steps are left); the next step's
        diagnosis when another grid wins, else None. A model step where the grids are refitted."""
        if self.swapped or self.model is None or self.model_steps >= max_steps:
            return None
        if swappable_grid(self.effects, d) is None:  # no grid, or at the floor: nothing is fitted
            return None
        self.raise_if_cancelled(ctx)
        self.swapped = True
        self.model_steps += 1
        index = len(self.run["steps"])
        self._progress(ctx, max_steps, f"step {index}: refitting the base's other grids with every effect kept")
        swap = grid_swap(self.line_free, self.effects, self.n_operators, d, self.model)
        if swap is None:
            return None
        effects = [e for e in self.effects if e != swap["replaced"]] + [swap["effect"]]
        self.model, step = discovery_step(self.line_free, effects, self.n_operators, model=swap["model"])
        self.run["added"].pop(swap["replaced"], None)  # the grid replaced is no longer found
        row = {"kind": "capacity", "evidence": swap["evidence"], "p_value": None, "score": None}
        self.run["added"][swap["effect"]] = (index, {**row, "expected_rms_um": swap["held_out_rms_um"]})
        self.effects, self.excluded = effects, []
        return self._keep(ctx, store, step, max_steps)

    def _keep(self, ctx: JobContext, store: Store, step: dict, max_steps: int) -> dict:
        """The step just diagnosed joins the run: stored, scored like for like, reported."""
        self.theta, d = self.model.theta, step["diagnosis"]
        index = len(self.run["steps"])
        step_id = self.model_id if index == 0 else self._store(store, ctx, self.model, self.effects)
        if self.fit is not None:
            fit_experiments(d, self.fit, self.records, ambiguity=False)
        self.run["steps"].append(step_summary(index, step_id, step, self.run, self.joined))
        self.run["steps"][-1]["fit"] = fit_label(index, self.stands_in, step["effects"])
        if self.joined is not None:
            self.run["experiments"][-1]["resolved"] = _resolved(self.run["experiments"][-1]["effects"], d)
            self.fitted, self.scores = {}, {}  # the records grew: every step is scored again on them
            self.excluded = []  # and an effect not kept on less data may be tried again
        self.joined = None
        self.history.append((list(self.effects), dict(self.theta)))
        self.fitted[effects_key(self.effects)] = self.model
        self.run["final_model"] = self.model  # before the scoring, which a cancel may stop
        self._score(ctx)
        self._progress(ctx, max_steps, step_words(self.run["steps"][-1]), partial=True)
        return d

    def _score(self, ctx: JobContext) -> None:
        """Each step's held-out RMS on the records as they are now and on the original ones: one refit
        per step not scored on them yet (every step after an experiment), the job's cancel read between
        them (a walk's cancel took over 2 minutes to land while a run refitted its steps); a step left
        unscored by a cancel reads None, and the next step's start ends the job."""
        todo = {effects_key(e): (e, t) for e, t in self.history if effects_key(e) not in self.scores}
        for key, step in todo.items():
            if ctx.cancelled:
                break
            self.scores[key] = like_for_like(self.line_free, self.n_original, [step], self.n_operators, self.fitted)[0]
        unscored = {"like_for_like_rms_um": None, "original_data_rms_um": None}
        for summary, (effects, _) in zip(self.run["steps"], self.history):
            summary.update(self.scores.get(effects_key(effects), unscored))
        self.run["like_for_like_datasets"] = list(self.datasets)

    def _store(self, store: Store, ctx: JobContext, model, effects: list[str]) -> str:
        """Store a model of this run with the last step's as its parent; its id."""
        return store_model(
            store,
            model,
            self.records,
            self.axis,
            list(self.datasets),
            ["hysteresis"] + ordered(effects),
            self.n_operators,
            self.run["steps"][-1]["model_id"],
            ctx.job_id,
            self.labels,
            line_free=self.line_free,
        )["id"]

    def join(self, store: Store, dataset_id: str) -> None:
        """An experiment's dataset joins the records: the same effects are refitted on every dataset."""
        self.joined = dataset_id
        self.datasets.append(dataset_id)
        self.records.append(load_record(store, dataset_id, self.axis))
        self.line_free = LineFree.of(self.records)
        self.model = None

    def not_kept_words(self) -> str:
        """The effects tried on the last step and not kept, in words ("" if none)."""
        return "".join(f" {r['text'][:1].upper()}{r['text'][1:]}." for r in self.run["steps"][-1]["not_kept"])


def _experiment(
    ctx: JobContext, store: Store, loop: _Loop, need: dict, policy: ExperimentPolicy, max_steps: int
) -> tuple[str | None, bool]:
    """Run the experiment ``need`` names, cut to the bench's limits; its dataset joins the loop:
    ``(None, False)``. Else ``(why not, skipped)``: ``skipped`` when the bench cannot run it (refused,
    no longer separating once cut, the sweep failed) — the loop goes on without it, and never asks
    for it again — rather than not allowed or not now."""
    after = len(loop.run["steps"]) - 1
    asked = need["experiment"]
    # the body the bench would run, whether or not it runs now: every sweep the result offers is one the
    # bench accepts (another stage's data: its experiment as named, for that stage)
    # one effect: a not-testable effect's experiment, judged by its own rule; two: an ambiguity's
    tested = need["effects"][0] if len(need["effects"]) == 1 else None
    body, cuts, refused = (
        policy.runnable(need, loop.records, effect=tested) if policy.elsewhere is None else (asked, [], None)
    )
    need.update({"experiment": body, "asked": asked, "cut_to_bench": cuts})
    if refused is not None:
        need["not_runnable_here"] = refused
    stored = (
        None
        if policy.elsewhere
        else recorded_already(store, loop.model_id, [b for b in (body, asked) if b], loop.datasets)
    )
    if stored is not None:  # run already, from the Models page or a discover before: its dataset joins
        loop.asked.append(asked)
        loop.run["experiments"].append(
            {**need, "sweep_job_id": None, "dataset_id": stored, "after_step": after, "recorded_before": True}
        )
        loop.join(store, stored)
        return None, False
    why = policy.why_not(len(loop.run["experiments"]))
    skipped = False
    if why is None:
        if body is not None:
            ctx.progress(
                min(0.99, loop.model_steps / max_steps),
                f"running the experiment for {', '.join(need['effects'])}: {body}",
            )
            dataset_id, sweep_id, why = policy.sweep(ctx, body)
            if why is None:
                loop.asked.append(asked)
                loop.run["experiments"].append(
                    {**need, "sweep_job_id": sweep_id, "dataset_id": dataset_id, "after_step": after}
                )
                loop.join(store, dataset_id)
                return None, False
        why = why or refused
        skipped = True
        loop.asked.append(asked)
    loop.run["suggested"].append({**need, "after_step": after, "not_run_because": why, "skipped": skipped})
    return why, skipped


def _resolved(effects: list[str], d: dict) -> bool:
    """Whether the diagnosis with an experiment's data no longer has what the experiment was for:
    the ambiguity between ``effects``, or ``effects`` not testable."""
    still = set(d["ambiguity"]["effects"]) if d.get("ambiguity") else set()
    still |= {c["effect"] for c in d.get("not_testable", [])}
    return not set(effects) <= still
