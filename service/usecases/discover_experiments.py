"""The discover job's experiments: whether the sweep the loop needs is run, cut to what the bench
allows, and run; never the job's failure (issue 37 §3).

An experiment is run when ``allow_experiments`` is set, the bench is free and fewer than
``max_experiments`` have run. The body the diagnosis names is first checked as POST /api/sweeps
checks it (service.usecases.acquire.runnable_sweep: voltage range, current, slew, 0.5 × the first
resonance); where the bench refuses it, it is cut to the bench's limits, and run if it still does
what it was asked for (service.science.discovery.loop.still_separates). A sweep the bench refuses
even so, or that ends without a dataset, is a step skipped with its reason: the loop goes on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from service.runtime.jobs import JobContext
from service.science.discovery.loop import still_separates
from service.science.errors import FieldError

#: ``run_experiment(ctx, sweep_body) -> the sweep's finished job`` (service.usecases.acquire.sweep_and_wait)
ExperimentRunner = Callable[[JobContext, dict], dict]
#: ``fit_to_bench(sweep_body) -> (the body the bench runs, the cuts made in words)``; FieldError when
#: even cut it is refused (service.usecases.acquire.runnable_sweep)
BenchFit = Callable[[dict], tuple[dict, list[str]]]

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

    def runnable(self, need: dict, records) -> tuple[dict | None, list[str], str | None]:
        """``(body, cuts, None)``: the sweep the bench runs for ``need`` (its experiment cut to the
        bench's limits, ``cuts`` in words); or ``(None, cuts, why)`` when the bench cannot run a sweep
        that still does what it was asked for."""
        if self.fit is None:
            return need["experiment"], [], None
        try:
            body, cuts = self.fit(need["experiment"])
        except FieldError as exc:
            return None, [], f"the bench refuses it even cut to its limits ({exc.field}: {exc.message})"
        why = still_separates(need["experiment"], body, records) if cuts else None
        if why is not None:
            return None, cuts, f"cut to the bench's limits ({'; '.join(cuts)}), it no longer separates: {why}"
        return body, cuts, None

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
        body, cuts, why = policy.runnable(item, records)
        if why is not None:
            item["experiment_asked"], item["experiment"], item["not_runnable_here"] = item["experiment"], None, why
        elif cuts:
            item["experiment"], item["cut_to_limits"] = body, cuts
