"""The guided path to a tracked ellipse as one job (POST /api/trajectories/prepare): the service, not
the browser tab, runs it, so it goes on when the tab closes and a reloaded page finds it again.

The path is ``tracking_recipe()``: an axis with no feedforward model gets the first sweep and a
composite model on it; then the sweeps over the span this ellipse drives (``span_sweeps``) and the
same composite models on those. Each sweep is a bench job of its own (``sweep_and_wait``), so the
emergency stop and the real-time loop never wait for this job; the fits run in this compute job.
The steps done so far are the job's partial result, and stay its result when a step fails.
"""

from __future__ import annotations

from drivers.bench import Bench
from service.runtime.jobs import JobContext, JobInterrupted, JobManager
from service.science.control.trajectory import Ellipse
from service.science.errors import FieldError
from service.store import TERMINAL_STATES, Store
from service.usecases.acquire import plan_sweep, sweep_and_wait
from service.usecases.identify import identify, require_fit_memory
from service.usecases.provenance import model_origin
from service.usecases.track import build_controller, span_sweeps, tracking_recipe

#: the ModelRequest defaults the dashboard's identify uses (the effects imply the composite)
MODEL, N_OPERATORS = "static_pi", 10


class PrepareRunning(FieldError):
    """A prepare job is queued or running already: one path at a time drives the bench (409)."""

    status_code = 409


def check_prepare(jobs: JobManager, bench: Bench, store: Store, ellipse: Ellipse, controller: dict) -> None:
    """Refuse before anything is queued: PrepareRunning while another prepare job is unfinished;
    FieldError naming ``controller.feedforward_model_<axis>`` for a model that cannot be used or was
    fitted on imported data (its span is another stage's: a walk swept 0–61 V where this bench needs
    8–90 V, and the run was then refused), or the span's refusal when every axis has its model."""
    unfinished = [j for j in jobs.list(20, kind="prepare") if j["state"] not in TERMINAL_STATES]
    if unfinished:
        raise PrepareRunning(
            "job", f"prepare job {unfinished[0]['id']} is {unfinished[0]['state']}: follow it, or cancel it first"
        )
    build_controller(bench, store, {**controller, "pid": None}, ellipse.frequency_hz)
    for axis in bench.axes:
        model_id = controller.get(f"feedforward_model_{axis}")
        origin = model_origin(store, store.get_model(model_id)["datasets"]) if model_id else None
        if origin and origin["fitted_on"] != "this_bench":
            raise FieldError(
                f"controller.feedforward_model_{axis}",
                f"model {model_id} was fitted on imported data (another stage's): the span this bench sweeps "
                "is read from a model of this bench; leave the axis's model empty to start from this bench's "
                "first sweep",
            )
    if all(controller.get(f"feedforward_model_{axis}") for axis in bench.axes):
        span_sweeps(bench, store, ellipse, controller)
    else:
        plan_sweep(bench, {**tracking_recipe()["first_sweep"], "axes": list(bench.axes)})


class _StepContext:
    """The job's context as one step sees it: its progress fills the step's share of the job's, its
    messages are prefixed by the step, and the steps done so far stay the partial result."""

    def __init__(self, ctx: JobContext, label: str, low: float, high: float, partial: dict):
        self._ctx, self._label, self._low, self._high, self._partial = ctx, label, low, high, partial
        self.job_id = ctx.job_id

    @property
    def cancelled(self) -> bool:
        return self._ctx.cancelled

    def progress(self, fraction: float, message: str | None = None, partial: dict | None = None) -> None:
        share = self._low + (self._high - self._low) * min(max(fraction, 0.0), 1.0)
        self._ctx.progress(share, f"{self._label}: {message}" if message else self._label, self._partial)


class _Path:
    """The steps of one prepare job, run in order; ``steps`` and the models chosen are its result."""

    def __init__(self, ctx: JobContext, jobs: JobManager, bench: Bench, store: Store, planned_steps: int):
        self.ctx, self.jobs, self.bench, self.store = ctx, jobs, bench, store
        self.planned_steps = max(planned_steps, 1)
        self.steps: list[dict] = []
        self.models: dict[str, str | None] = {}

    def result(self) -> dict:
        return {
            **{f"feedforward_model_{axis}": self.models.get(axis) for axis in self.bench.axes},
            "steps": list(self.steps),
        }

    def _context(self, label: str) -> _StepContext:
        done = len(self.steps)
        share = 0.98 / self.planned_steps
        return _StepContext(self.ctx, label, done * share, (done + 1) * share, self.result())

    def failed(self, why: str) -> JobInterrupted:
        return JobInterrupted(why, result=self.result(), cancelled=self.ctx.cancelled)

    def sweep(self, body: dict, what: str) -> str:
        """Run ``body`` (a /api/sweeps body) as a bench job and wait for it; its dataset id."""
        self._context(what).progress(0.0, "queued on the bench")
        try:
            values = {key: value for key, value in body.items() if key != "name"}
            job = sweep_and_wait(self.ctx, self.jobs, self.bench, self.store, values, name=body.get("name") or what)
        except JobInterrupted:
            raise
        except Exception as exc:  # a refusal (FieldError), no engine, a full queue: the path stops here
            raise self.failed(f"{what} was not run: {exc}") from None
        dataset_id = (job.get("result") or {}).get("dataset_id")
        if job["state"] != "succeeded" or not dataset_id:
            raise self.failed(
                f"{what} (job {job['id']}) ended {job['state']}: {job.get('error') or job.get('message')}"
            )
        self.steps.append(
            {"step": "sweep", "what": what, "axes": body["axes"], "job_id": job["id"], "dataset_id": dataset_id}
        )
        return dataset_id

    def identify(self, axis: str, dataset_id: str, effects: list[str], on: str) -> str:
        """Fit the recipe's composite model of ``axis`` on ``dataset_id``; its model id."""
        what = f"{axis.upper()}: a model with {' + '.join(effects)} on {on}"
        try:
            # the recipe's effects are valid and the sweep just ran on this bench: only the memory is checked
            # (check_identify_request would read the dataset once more before the fit reads it)
            require_fit_memory(self.store, [dataset_id])
            fitted = identify(self._context(what), self.store, axis, [dataset_id], effects, MODEL, N_OPERATORS)
        except JobInterrupted:
            raise
        except Exception as exc:
            raise self.failed(f"{what} failed: {exc}") from None
        self.models[axis] = fitted["model_id"]
        self.steps.append(
            {
                "step": "model",
                "what": what,
                "axes": [axis],
                "model_id": fitted["model_id"],
                "dataset_id": dataset_id,
                "validation_rms_um": fitted["validation_rms_um"],
            }
        )
        self.ctx.progress(len(self.steps) * 0.98 / self.planned_steps, what, self.result())
        return fitted["model_id"]


def prepare_tracking(
    ctx: JobContext, jobs: JobManager, bench: Bench, store: Store, ellipse: Ellipse, controller: dict
) -> dict:
    """Job body: the recipe's path for ``ellipse``; returns ``{"feedforward_model_<axis>", "steps",
    "controller", "why"}``, the models selected for the run and the controller the recipe recommends.
    ``controller``'s feedforward models, where given, are the start; the span is read from them."""
    recipe = tracking_recipe()
    effects = recipe["effects"]
    given = {axis: controller.get(f"feedforward_model_{axis}") for axis in bench.axes}
    missing = [axis for axis in bench.axes if not given[axis]]
    planned = (1 + len(missing) if missing else 0) + 2 * len(bench.axes)
    path = _Path(ctx, jobs, bench, store, planned)
    path.models.update({axis: model for axis, model in given.items() if model})
    if missing:
        body = {**recipe["first_sweep"], "axes": missing}
        first = path.sweep(body, f"the first sweep of {' and '.join(axis.upper() for axis in missing)}")
        for axis in missing:
            path.identify(axis, first, effects, "the first sweep")
    chosen = {**controller, **{f"feedforward_model_{axis}": path.models[axis] for axis in bench.axes}}
    try:
        bodies = span_sweeps(bench, store, ellipse, chosen)
    except Exception as exc:  # the ellipse is beyond what the models allow: named by span_sweeps
        raise path.failed(f"the span this ellipse drives: {exc}") from None
    for body in bodies:
        axis = body["axes"][0]
        dataset_id = path.sweep(body, body["name"])
        path.identify(axis, dataset_id, effects, "the span this ellipse drives")
    return {**path.result(), "controller": recipe["controller"], "why": recipe["why"]}
