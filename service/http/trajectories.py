"""POST /api/trajectories: check an ellipse and its controller against the bench, then run it as a
bench job (FF + PID + ILC through service.science.control, the path the control benchmark measures)."""
from __future__ import annotations

from typing import Literal

import numpy as np
from fastapi import APIRouter, Depends
from pydantic import BaseModel, ConfigDict, Field, model_validator

from drivers.bench import Bench
from service.usecases.acquire import bench_snapshot
from service.http.deps import get_bench, get_jobs, get_store
from service.science.control.feedforward import as_feedforward
from service.science.control.loop import PIDGains, StopRequested
from service.science.control.safety import ControlRefused
from service.science.control.session import SAMPLE_RATE_HZ, Controller, plan, trace_arrays, track_plan
from service.science.control.trajectory import Ellipse
from service.science.data.datasets import units_for
from service.science.errors import FieldError
from service.runtime.jobs import JobContext, JobInterrupted, JobManager
from service.usecases.identify import load_model
from service.store import NotFoundError, Store, utc_now
from service.store.chunks import ChunkWriter

router = APIRouter(tags=["trajectories"])


class PIDRequest(BaseModel):
    """Per-axis gains: kp V/µm, ki V/(µm·s), kd V·s/µm (paper eq. 19), derivative filter tf_s."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kp_y: float = Field(ge=0, le=1000)
    ki_y: float = Field(default=0.0, ge=0, le=1e5)
    kd_y: float = Field(default=0.0, ge=0, le=10)
    kp_z: float = Field(ge=0, le=1000)
    ki_z: float = Field(default=0.0, ge=0, le=1e5)
    kd_z: float = Field(default=0.0, ge=0, le=10)
    tf_s: float = Field(default=1e-4, gt=0, le=1)


class ControllerRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    feedforward_model_y: str | None = None
    feedforward_model_z: str | None = None
    pid: PIDRequest | None = None
    ilc: bool = False
    ilc_gain: float = Field(default=0.2, gt=0, le=1)
    ilc_harmonics: int = Field(default=20, ge=1, le=50)
    #: run a range beyond the axis's stroke anyway, commands clamped at 0/120 V (the refusal becomes a warning)
    allow_saturation: bool = False


class TrajectoryRequest(BaseModel):
    """An ellipse in YOZ: ranges (min, max) µm per axis, or peak-to-peak amplitudes above min_*_um."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    shape: Literal["ellipse"] = "ellipse"
    y_range_um: tuple[float, float] | None = None
    z_range_um: tuple[float, float] | None = None
    amplitude_y_um: float | None = Field(default=None, gt=0)
    amplitude_z_um: float | None = Field(default=None, gt=0)
    min_y_um: float = Field(default=1.0, ge=0)
    min_z_um: float = Field(default=1.0, ge=0)
    inclination_deg: float = Field(default=0.0, ge=-90, le=90)
    frequency_hz: float = Field(default=100.0, gt=0, le=1000)
    cycles: int = Field(default=50, ge=1, le=10_000)
    mode: Literal["point_by_point", "buffered"] = "point_by_point"
    controller: ControllerRequest = Field(default_factory=ControllerRequest)
    name: str | None = Field(default=None, max_length=200)

    @model_validator(mode="after")
    def _ranges(self):
        for ax in ("y", "z"):
            if getattr(self, f"{ax}_range_um") is None and getattr(self, f"amplitude_{ax}_um") is None:
                raise ValueError(f"give {ax}_range_um [min, max] or amplitude_{ax}_um")
        return self

    def ellipse(self) -> Ellipse:
        yr = self.y_range_um or (self.min_y_um, self.min_y_um + self.amplitude_y_um)
        zr = self.z_range_um or (self.min_z_um, self.min_z_um + self.amplitude_z_um)
        return Ellipse(tuple(map(float, yr)), tuple(map(float, zr)), self.inclination_deg, self.frequency_hz,
                       self.cycles)


def build_controller(body: TrajectoryRequest, store: Store) -> Controller:
    c = body.controller
    models = {}
    for ax in ("y", "z"):
        model_id = getattr(c, f"feedforward_model_{ax}")
        if model_id is None:
            continue
        try:
            models[ax] = as_feedforward(load_model(store.get_model(model_id)))
        except NotFoundError:
            raise FieldError(f"controller.feedforward_model_{ax}", f"no model {model_id!r}") from None
        except Exception as exc:  # a model that cannot be rebuilt or inverted
            raise FieldError(f"controller.feedforward_model_{ax}", f"model {model_id} cannot be used: {exc}") from None
        if not callable(getattr(models[ax], "inverse", None)):
            raise FieldError(f"controller.feedforward_model_{ax}", f"model {model_id} has no inverse")
    pid = None
    if c.pid is not None:
        p = c.pid
        pid = {"y": PIDGains(p.kp_y, p.ki_y, p.kd_y, p.tf_s), "z": PIDGains(p.kp_z, p.ki_z, p.kd_z, p.tf_s)}
    return Controller(feedforward=models, pid=pid, ilc=c.ilc, ilc_gain=c.ilc_gain, ilc_harmonics=c.ilc_harmonics,
                      allow_saturation=c.allow_saturation)


def run_trajectory(ctx: JobContext, bench: Bench, store: Store, ellipse: Ellipse, controller: Controller,
                   mode: str, params: dict, name: str | None) -> dict:
    """The job: track, report the error per period as progress, store measured and reference traces
    (written in ~1 s chunks while it runs, so a killed process keeps them: service.runtime.recovery)."""
    total = ellipse.cycles + 6
    meta = {"name": name or f"ellipse {ellipse.frequency_hz:g} Hz {mode}", "source": "trajectory",
            "axes": list(bench.axes), "sample_rate_hz": SAMPLE_RATE_HZ, "blocks": [], "plan": params,
            "config": bench_snapshot(bench), "job_id": ctx.job_id,
            "started_at": utc_now()}
    chunks = ChunkWriter(store.data_dir, ctx.job_id, meta)

    def on_period(p: int, arrays: dict, last_error_um: float | None) -> None:
        chunks.append(arrays)
        msg = f"period {p + 1}/{total}" + (f": error {last_error_um * 1e3:.1f} nm RMS" if last_error_um is not None else "")
        ctx.progress(min(0.97, (p + 1) / total), msg)

    try:
        try:
            result, rec, ref = bench.execute(track_plan, ellipse, controller, mode, on_event=on_period,
                                             should_stop=lambda: ctx.cancelled)
        except StopRequested as exc:
            raise JobInterrupted(f"{exc.reason} while measuring the response for the ILC; nothing stored",
                                 None, cancelled=True) from None
        n = rec.samples
        arrays = trace_arrays(rec, SAMPLE_RATE_HZ, bench.axes, 0, n)
        row = store.add_dataset(arrays, {
            **meta, "units": units_for(arrays), "partial": bool(result["tripped"] or result["stopped"]),
            "partial_reason": result["tripped"] or rec.stop_reason, "finished_at": utc_now()})
    finally:  # stored (or nothing to keep): the chunks are only for a process that dies mid-run
        chunks.discard()
    result["dataset_id"] = row["id"]
    result["warnings"] = result.get("warnings", []) + chunks.warnings()
    kept = f"{n} samples kept as partial dataset {row['id']}"
    if result["tripped"]:
        raise JobInterrupted(f"tripped: {result['tripped']}: {kept}", result)
    if result["stopped"]:
        raise JobInterrupted(f"{rec.stop_reason or 'stopped on request'}: {kept}", result, cancelled=True)
    return result


@router.post("/trajectories", status_code=202)
def start_trajectory(body: TrajectoryRequest, bench: Bench = Depends(get_bench), store: Store = Depends(get_store),
                     jobs: JobManager = Depends(get_jobs)) -> dict:
    """Queue a tracking run; the result has max_error_y_um, max_error_z_um, rms_error_um,
    relative_error_pct, error_per_period_um and dataset_id. Refused with 422 naming the field if the
    mode, the current, the resonance or the voltage forbid it: nothing is queued then."""
    try:
        ellipse = body.ellipse()
        controller = build_controller(body, store)
        plan(bench, ellipse, controller, body.mode)
    except ControlRefused as exc:
        raise FieldError(exc.field, exc.reason) from None
    except ValueError as exc:
        if isinstance(exc, FieldError):
            raise
        field, _, msg = str(exc).partition(": ")
        raise FieldError(field if msg else "body", msg or str(exc)) from None
    params = body.model_dump()
    job = jobs.submit("trajectory", params,
                      lambda ctx: run_trajectory(ctx, bench, store, ellipse, controller, body.mode, params, body.name),
                      needs_bench=True)
    return {"job_id": job["id"], "state": job["state"]}
