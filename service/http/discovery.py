"""Discovery routes under /models: diagnosis, refine and discover (jobs) and history. No science here."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from drivers.bench import Bench
from service.http.deps import get_bench, get_jobs, get_store
from service.http.schemas.common import JobQueued
from service.http.schemas.models import Diagnosis, DiscoverRequest, History, RefineRequest
from service.runtime.jobs import JobManager
from service.science.errors import FieldError
from service.store import Store
from service.usecases.acquire import BenchExperiments, sweep_and_wait
from service.usecases.discover import diagnose_model, history, refine_params
from service.usecases.discover_experiments import ExperimentPolicy
from service.usecases.discover_run import discover
from service.usecases.identify import identify, require_fit_memory
from service.usecases.provenance import imported_datasets, recorded_elsewhere

router = APIRouter(prefix="/models", tags=["discovery"])


@router.get("/{model_id}/diagnosis", response_model=Diagnosis, response_model_exclude_unset=True)
def get_diagnosis(
    model_id: str,
    extra_datasets: list[str] = Query(default=[]),
    store: Store = Depends(get_store),
    bench: Bench = Depends(get_bench),
) -> dict:
    """Residual RMS, noise floor, verdict, ranked candidates with evidence, failures, ambiguity. Each
    experiment it proposes for this bench's data is one the bench runs (cut to its limits, said in
    ``cut_to_limits``), or none, with ``not_runnable_here`` saying why."""
    return diagnose_model(store, model_id, extra_datasets, bench_fit=BenchExperiments(bench))


@router.post("/{model_id}/refine", status_code=202, response_model=JobQueued)
def refine(
    model_id: str, body: RefineRequest, store: Store = Depends(get_store), jobs: JobManager = Depends(get_jobs)
) -> dict:
    """Queue a refit with another effect set on the same data; the new model's parent is ``model_id``."""
    params = refine_params(store, model_id, body.add, body.remove, body.effects, body.datasets)
    job = jobs.submit("refine", params, lambda ctx: identify(ctx, store, **params), needs_bench=False)
    return {"job_id": job["id"], "state": job["state"]}


@router.post("/{model_id}/discover", status_code=202, response_model=JobQueued)
def start_discovery(
    model_id: str,
    body: DiscoverRequest,
    store: Store = Depends(get_store),
    jobs: JobManager = Depends(get_jobs),
    bench: Bench = Depends(get_bench),
) -> dict:
    """Queue the discovery loop from ``model_id`` (a compute job: it never holds the bench). Each step
    is stored as a model whose parent is the previous step and reported as progress (the steps so far
    are the job's ``result`` while it runs). The result: ``steps`` (model_id, effects, added,
    validation_rms_um, noise_floor_um, …), ``final_model_id``, ``effects_found`` (fitted physical
    parameters, units in the names, and the evidence), ``remains`` (held-out RMS against the noise
    floor, per block), ``stopped`` and ``needed_experiment`` (a /api/sweeps body) when it stopped for one;
    each step's ``like_for_like_rms_um`` (on every dataset the run ended with) beside
    ``original_data_rms_um`` and ``not_kept`` (effects tried that raised the held-out RMS).
    In a lab, ``allow_experiments`` is refused (422) for a model of another bench: its experiments
    would run on this service's hardware."""
    row = store.get_model(model_id)  # 404 before anything is queued
    imported = imported_datasets(store, row["datasets"])
    if imported and body.allow_experiments:
        raise FieldError(
            "allow_experiments",
            f"model {model_id} was fitted on imported data ({', '.join(imported)}), "
            "recorded on another stage: this bench's experiments would measure a different stack. Run "
            "the experiment it names on that stage and import it, or ask without allow_experiments",
        )
    owner = row.get("bench_id")
    if body.allow_experiments and owner not in (None, store.bench_id):  # a lab: experiments on its own bench
        bench = store.benches.get(owner)
        raise FieldError(
            "allow_experiments",
            f"model {model_id} describes bench {owner!r}: its experiments must run "
            f"on that bench, so start the discovery at its service ({bench['url'] if bench else 'its URL'}),"
            f" or here without allow_experiments",
        )
    require_fit_memory(store, list(row["datasets"]), field="model_id")  # 422 before a job is queued
    params = {"model_id": model_id, **body.model_dump()}

    def run_experiment(ctx, sweep_body: dict) -> dict:
        made_for = {"experiment_of": {"model_id": model_id, "effects": [], "discover_job_id": ctx.job_id}}
        body = {**sweep_body, **made_for}
        return sweep_and_wait(ctx, jobs, bench, store, body, name=f"experiment of discovery from {model_id}")

    elsewhere = recorded_elsewhere(imported, "run it on the stage that recorded the data and import the record")
    policy = ExperimentPolicy(
        run=run_experiment,
        busy=jobs.bench_jobs,
        fit=BenchExperiments(bench),
        elsewhere=elsewhere,
    )
    job = jobs.submit("discover", params, lambda ctx: discover(ctx, store, bench=policy, **params), needs_bench=False)
    return {"job_id": job["id"], "state": job["state"]}


@router.get("/{model_id}/history", response_model=History)
def get_history(model_id: str, store: Store = Depends(get_store)) -> dict:
    """The lineage from the first model to this one, with train and validation RMS at each step."""
    return {"model_id": model_id, "steps": history(store, model_id)}
