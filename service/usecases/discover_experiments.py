"""The discover job's experiments: whether the sweep the loop needs is run, cut to what the bench
allows, and run; never the job's failure (issue 37 §3).

An experiment is run when ``allow_experiments`` is set, the bench is free and fewer than
``max_experiments`` have run. The body the diagnosis names is first checked as POST /api/sweeps
checks it (service.usecases.acquire.runnable_sweep: voltage range, current, slew, 0.5 × the first
resonance); where the bench refuses it, it is cut to the bench's limits, and run if it still does
what it was asked for: an ambiguity's sweep still separates (service.science.discovery.loop.
still_separates); a not-testable effect's sweep passes that effect's own rule (``untestable``) on
the drive it would make, if need be over the whole voltage range. A sweep the bench refuses even
so, or that ends without a dataset, is a step skipped with its reason: the loop goes on."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from service.render.reproduce import PLAN_NOT_IN_BODY
from service.runtime.jobs import JobContext
from service.science.discovery.loop import still_separates
from service.science.effects import EFFECTS
from service.science.errors import FieldError
from service.usecases.acquire import BenchExperiments

#: ``run_experiment(ctx, sweep_body) -> the sweep's finished job`` (service.usecases.acquire.sweep_and_wait)
ExperimentRunner = Callable[[JobContext, dict], dict]
#: the bench's check and cut of a proposed sweep (service.usecases.acquire.BenchExperiments)
BenchFit = BenchExperiments

#: experiments a discover job runs at most, unless asked otherwise (``max_experiments``)
MAX_EXPERIMENTS = 3


@dataclass
class ExperimentPolicy:
    """What the job may do about an experiment: ``allowed`` (allow_experiments), ``run`` (the
    runner; None: no bench), ``busy`` (the bench's jobs now), ``max_experiments``, ``fit`` (the
    bench's check and cut; None: run as named), ``elsewhere`` (why the data's experiments belong to
    another stage, for a model of imported data; None: this bench's)."""

    allowed: bool = False
    run: ExperimentRunner | None = None
    busy: Callable[[], list[str]] | None = None
    max_experiments: int = MAX_EXPERIMENTS
    fit: BenchFit | None = None
    elsewhere: str | None = None

    def why_not(self, ran: int) -> str | None:
        """Why an experiment is not asked of the bench (``ran``: experiments run so far), or None."""
        if self.elsewhere:
            return self.elsewhere
        if not self.allowed:
            return "ask again with allow_experiments to run it"
        if self.run is None:
            return "this service has no bench to run it on"
        busy = self.busy() if self.busy else []
        if busy:
            return f"the bench is busy with {', '.join(busy)}"
        if ran >= self.max_experiments:
            return f"max_experiments = {self.max_experiments} have run"
        return None

    def runnable(self, need: dict, records, effect: str | None = None) -> tuple[dict | None, list[str], str | None]:
        """``(body, cuts, None)``: the sweep the bench runs for ``need`` (its experiment cut to the
        bench's limits, ``cuts`` in words); or ``(None, cuts, why)`` when the bench cannot run a sweep
        that still does what it was asked for. ``effect``: the not-testable effect the experiment is
        for, judged by its own rule (``untestable``) on the drive the cut sweep would make; where the
        cut falls short, the same sweep over the axes' whole voltage range is tried (its rate grows
        with its swing: a slew test cut to 145 Hz at 0–120 V stayed under the rate its rule needs)."""
        asked = need["experiment"]
        if asked is None:  # already found not runnable here (fit_experiments)
            return None, [], need.get("not_runnable_here") or "this bench cannot run it"
        if self.fit is None:
            return asked, [], None
        try:
            body, cuts = self.fit.cut(asked)
        except FieldError as exc:
            return None, [], f"the bench refuses it even cut to its limits ({exc.field}: {exc.message})"
        if not cuts:
            return body, cuts, None
        why = self._short_of(effect, asked, body, records)
        wider = self.fit.widest(asked) if why is not None and effect else None
        if wider is not None:
            try:
                wide_body, wide_cuts = self.fit.cut(wider)
            except FieldError:
                wide_body = None
            if wide_body is not None and self._short_of(effect, asked, wide_body, records) is None:
                span = (
                    f"voltage range → {wide_body['v_min']:g}–{wide_body['v_max']:g} V "
                    f"(the axes' whole range: testing {effect} needs the rate)"
                )
                return wide_body, [span, *wide_cuts], None
        if why is not None:
            job = "separates" if effect is None else f"tests {effect}"
            return None, cuts, f"cut to the bench's limits ({'; '.join(cuts)}), it no longer {job}: {why}"
        return body, cuts, None

    def _short_of(self, effect: str | None, asked: dict, body: dict, records) -> str | None:
        """Why the cut sweep ``body`` no longer does what ``asked`` was for, or None: for a not-testable
        ``effect``, its own rule on the records so far and the drive ``body`` would make; else
        ``still_separates``."""
        if effect is None:
            return still_separates(asked, body, records)
        axis = next((r.axis for r in records if r.axis), "y")
        return EFFECTS[effect].untestable(list(records) + self.fit.records(body, axis))

    def sweep(self, ctx: JobContext, body: dict) -> tuple[str | None, str | None, str | None]:
        """Run ``body``: ``(dataset_id, sweep_job_id, None)``, or ``(None, sweep_job_id, why)``
        when the sweep was refused or ended without a dataset (a cancel of the job propagates)."""
        try:
            sweep = self.run(ctx, body)
        except FieldError as exc:
            return None, None, f"the bench refused the sweep ({exc.field}: {exc.message})"
        dataset_id = (sweep.get("result") or {}).get("dataset_id")
        if sweep["state"] != "succeeded" or not dataset_id:
            return None, sweep["id"], f"its sweep {sweep['id']} ended {sweep['state']}: {sweep.get('error')}"
        return dataset_id, sweep["id"], None


def recorded_already(store, model_id: str, bodies: list[dict], exclude: list[str]) -> str | None:
    """The id of a complete dataset this bench recorded as an experiment of ``model_id`` with one of the
    sweeps ``bodies`` (every field of the body as the plan stored it), newest first, not in ``exclude``;
    None when there is none. A walk ran a diagnosis's separating sweep from the Models page, then a
    discover with experiments ran the identical sweep again."""
    for row in reversed(store.list_datasets(bench_id=store.bench_id)):
        plan = row.get("plan") or {}
        if row["id"] in exclude or row.get("source") != "sweep" or row.get("partial"):
            continue
        if (plan.get("experiment_of") or {}).get("model_id") != model_id:
            continue
        if any(all(_same(plan.get(k), v) for k, v in body.items() if k not in PLAN_NOT_IN_BODY) for body in bodies):
            return row["id"]
    return None


def _same(stored, asked) -> bool:
    """Whether a plan's stored value is the asked one (numbers to 1e-9, lists element by element)."""
    if isinstance(asked, (list, tuple)):
        return isinstance(stored, (list, tuple)) and len(stored) == len(asked) and all(map(_same, stored, asked))
    if isinstance(asked, (int, float)) and not isinstance(asked, bool):
        return isinstance(stored, (int, float)) and abs(float(stored) - float(asked)) <= 1e-9 * max(1.0, abs(asked))
    return stored == asked


def fit_experiments(out: dict, fit: BenchFit, records, ambiguity: bool = True) -> None:
    """Each experiment diagnosis ``out`` proposes (what tests a not-testable effect, what separates an
    ambiguity) as the bench runs it: cut to its limits where it asks more (``cut_to_limits`` says
    how), or, where the bench cannot run one that still does its job, no experiment and
    ``not_runnable_here`` saying why (a walk's button posted 150 Hz on a Z axis limited to 145 Hz).
    ``ambiguity`` False: the not-testable effects' experiments only (a discover job fits the
    ambiguity's itself when it asks for it)."""
    policy = ExperimentPolicy(fit=fit)
    proposals = list(out.get("not_testable") or [])
    proposals += [out["ambiguity"]] if ambiguity and out.get("ambiguity") else []
    for item in proposals:
        if not item.get("experiment"):
            continue
        body, cuts, why = policy.runnable(item, records, effect=item.get("effect"))
        if why is not None:
            item["experiment_asked"], item["experiment"], item["not_runnable_here"] = item["experiment"], None, why
        elif cuts:
            item["experiment"], item["cut_to_limits"] = body, cuts
