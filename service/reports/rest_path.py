"""The tracking report's path is a REST user's (issue 19 §5): sweeps, models and trajectories are asked
for with the bodies a user posts, and answered by the same use cases the routers call.

``identify_for(post, case_body)`` and ``run_rows(post, case_body, ff)`` take ``post(path, body)``: the
API's answer to a POST (a job's final record for job endpoints, the JSON for
``/api/trajectories/span-sweeps``), raising ``Refused`` on a 422. ``UseCases.post`` answers it in
process (service.usecases.*); tests pass a TestClient-backed ``post`` and must get the same figures.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from service.http.app import open_configured_bench
from service.http.schemas.datasets import SweepRequest
from service.http.schemas.models import ModelRequest
from service.http.schemas.trajectories import TrajectoryRequest
from service.runtime.jobs import JobManager
from service.runtime.settings import Settings
from service.science.errors import FieldError
from service.store import Store
from service.usecases import track
from service.usecases.acquire import plan_sweep, run_sweep
from service.usecases.identify import check_identify_request, identify
from service.usecases.track import check_trajectory, run_trajectory, span_sweeps

#: the recommended path (service.usecases.track): the first sweep and the composite model's effects per axis
FIRST_SWEEP, EFFECTS = track.FIRST_SWEEP, track.FEEDFORWARD_EFFECTS
#: the report's rows: controller bodies on top of the feedforward models
ROWS = {
    "b FF only": {},
    "c FF + PID (auto)": {"pid": "auto"},
    "d FF + PID (auto) + ILC": {"pid": "auto", "ilc": True},
    "d' FF + ILC": {"ilc": True},
    "e FF + PID (paper gains)": {"pid": "paper"},
    "f FF + PID (issue 6's scanned gains) + ILC": {
        "pid": {"kp_y": 1, "ki_y": 300, "kd_y": 0.01, "kp_z": 1, "ki_z": 300, "kd_z": 0.01, "tf_s": 2e-4},
        "ilc": True,
    },
}
ENDED = ("succeeded", "failed", "cancelled")

Post = Callable[[str, dict], object]


class Refused(Exception):
    """A 422: the field at fault and the reason."""

    def __init__(self, field: str, detail: str):
        super().__init__(f"{field}: {detail}")
        self.field, self.detail = field, detail


class UseCases:
    """The service of ``settings`` without HTTP: its store, its bench (``open_configured_bench``), a
    job manager; ``post`` answers as the routers do."""

    def __init__(self, settings: Settings):
        Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
        self.store = Store(settings.resolved_database_url, settings.data_dir, array_url=settings.array_url)
        self.bench = open_configured_bench(settings)
        self.jobs = JobManager(self.store, on_cancel_bench=self.bench.cancel_plan)

    def close(self) -> None:
        self.jobs.shutdown()
        self.bench.close()
        self.store.close()

    def _wait(self, job: dict, poll_s: float = 0.05) -> dict:
        while (job := self.jobs.get(job["id"]))["state"] not in ENDED:
            time.sleep(poll_s)
        return job

    def post(self, path: str, body: dict):
        """The answer to POST ``path`` with ``body`` (see the module doc)."""
        try:
            if path == "/api/sweeps":
                values = SweepRequest(**body).model_dump()
                name = values.pop("name")
                planned, plan = plan_sweep(self.bench, values)
                return self._wait(
                    self.jobs.submit(
                        "sweep", plan, lambda ctx: run_sweep(ctx, self.bench, self.store, planned, plan, name), True
                    )
                )
            if path == "/api/models":
                req = ModelRequest(**body)
                check_identify_request(self.store, req.axis, req.datasets, req.effects, req.model)
                params = req.model_dump()
                return self._wait(
                    self.jobs.submit("identify", params, lambda ctx: identify(ctx, self.store, **params), False)
                )
            req = TrajectoryRequest(**body)
            if path == "/api/trajectories/span-sweeps":
                return span_sweeps(self.bench, self.store, req.ellipse(), req.controller.model_dump())
            if path == "/api/trajectories":
                ellipse = req.ellipse()
                controller = check_trajectory(self.bench, self.store, ellipse, req.controller.model_dump(), req.mode)
                params = req.model_dump()
                return self._wait(
                    self.jobs.submit(
                        "trajectory",
                        params,
                        lambda ctx: run_trajectory(
                            ctx, self.bench, self.store, ellipse, controller, req.mode, params, req.name
                        ),
                        True,
                    )
                )
        except FieldError as exc:
            raise Refused(exc.field, exc.message) from None
        raise ValueError(f"no such endpoint: POST {path}")


def _result(job: dict) -> dict:
    if job["state"] != "succeeded":
        raise RuntimeError(f"job {job['id']} {job['state']}: {job.get('error')}")
    return job["result"]


def first_models(post: Post, effects: list[str] = EFFECTS) -> dict[str, str]:
    """axis → composite model id (hysteresis + ``effects``) identified on ``FIRST_SWEEP`` (the default
    0–120 V sweep)."""
    dataset_id = _result(post("/api/sweeps", FIRST_SWEEP))["dataset_id"]
    return {
        ax: _result(post("/api/models", {"axis": ax, "datasets": [dataset_id], "effects": effects}))["model_id"]
        for ax in ("y", "z")
    }


def ff_body(model_ids: dict[str, str]) -> dict:
    return {f"feedforward_model_{ax}": mid for ax, mid in model_ids.items()}


def identify_for(post: Post, case_body: dict, first: dict[str, str], effects: list[str] = EFFECTS) -> dict[str, str]:
    """axis → composite model id (hysteresis + ``effects``) fitted on the sweeps
    ``/api/trajectories/span-sweeps`` offers for ``case_body`` (the voltages the ellipse needs by the
    ``first`` models, ± 5 V)."""
    bodies = post("/api/trajectories/span-sweeps", {**case_body, "controller": ff_body(first)})
    out = {}
    for body in bodies:
        (axis,) = body["axes"]
        dataset_id = _result(post("/api/sweeps", body))["dataset_id"]
        out[axis] = _result(post("/api/models", {"axis": axis, "datasets": [dataset_id], "effects": effects}))[
            "model_id"
        ]
    return out


def run_row(post: Post, case_body: dict, ff: dict[str, str], controller: dict) -> dict:
    """One row: the job's result (``tripped`` set on a failed run), or ``{"refused": {field, detail}}``."""
    try:
        job = post("/api/trajectories", {**case_body, "controller": {**ff_body(ff), **controller}})
    except Refused as exc:
        return {"refused": {"field": exc.field, "detail": exc.detail}}
    if job["state"] == "succeeded":
        return job["result"]
    return {"tripped": job.get("error") or job["state"], "failed_job": job["id"]}


def measure(post: Post, cases: dict[str, dict], rows: dict[str, dict] = ROWS, effects: list[str] = EFFECTS) -> dict:
    """case → {"models": axis → model id, "rows": row name → ``run_row``'s answer}: first models
    (hysteresis + ``effects``) on the default sweep, then per case models on its span sweeps and every
    row of ``rows``."""
    first = first_models(post, effects)
    out = {}
    for case, body in cases.items():
        ff = identify_for(post, body, first, effects)
        out[case] = {"models": ff, "rows": {name: run_row(post, body, ff, ctl) for name, ctl in rows.items()}}
    return out
