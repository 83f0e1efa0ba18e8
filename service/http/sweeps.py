"""POST /api/sweeps: check a characterisation plan against the bench, then queue it as a bench job."""
from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends
from pydantic import BaseModel, ConfigDict, Field, field_validator

from drivers.bench import Bench
from service.http.deps import get_bench, get_jobs, get_store
from service.runtime.jobs import JobManager
from service.store import Store
from service.usecases.acquire import plan_sweep, run_sweep

router = APIRouter(tags=["sweeps"])

Volts = Field(ge=0.0, le=120.0)


class SweepRequest(BaseModel):
    """A characterisation sweep. Volts at the actuator (0–120 V), hertz, seconds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    axes: list[Literal["y", "z"]] = Field(default=["y"], min_length=1)
    waveform: Literal["sine", "step", "chirp", "multisine"] = "sine"
    frequencies_hz: list[float] = Field(default=[1.0, 10.0, 50.0, 100.0], min_length=1, max_length=100)
    cycles: int = Field(default=5, ge=1, le=100_000)
    v_min: float = Field(default=0.0, ge=0.0, le=120.0)
    v_max: float = Field(default=120.0, ge=0.0, le=120.0)
    settle_s: float = Field(default=0.2, ge=0.0, le=600.0)
    sample_rate_hz: float = Field(default=20_000.0, gt=0.0, le=2_000_000.0)
    together: bool = Field(default=True, description="drive all axes at once, else one after the other")
    levels_v: list[float] = Field(default=[], description="step: levels to step to (default [v_max])")
    hold_s: float = Field(default=2.0, gt=0.0, le=3600.0, description="step: hold time at each level")
    f_start_hz: float = Field(default=1.0, gt=0.0, description="chirp: start frequency")
    f_stop_hz: float = Field(default=100.0, gt=0.0, description="chirp: stop frequency")
    duration_s: float = Field(default=10.0, gt=0.0, le=3600.0, description="chirp: duration")
    name: str | None = Field(default=None, max_length=200)

    @field_validator("frequencies_hz")
    @classmethod
    def _positive(cls, values: list[float]) -> list[float]:
        if any(f <= 0 for f in values):
            raise ValueError("every frequency must be above 0 Hz")
        return values

    @field_validator("levels_v")
    @classmethod
    def _levels_in_range(cls, values: list[float]) -> list[float]:
        if any(not 0.0 <= v <= 120.0 for v in values):
            raise ValueError("every level must lie in 0–120 V")
        return values

    @field_validator("v_max")
    @classmethod
    def _above_v_min(cls, v_max: float, info) -> float:
        v_min = info.data.get("v_min")
        if v_min is not None and v_max <= v_min:
            raise ValueError(f"must exceed v_min ({v_min:g} V)")
        return v_max


@router.post("/sweeps", status_code=202)
def start_sweep(body: SweepRequest, bench: Bench = Depends(get_bench), store: Store = Depends(get_store),
                jobs: JobManager = Depends(get_jobs)) -> dict:
    """Queue a sweep; the job's result is ``{"dataset_id"}``. Refused with 422 (naming the field)
    if the plan leaves the bench's voltage, current or slew limits: nothing is queued then."""
    values = body.model_dump()
    name = values.pop("name")
    planned, plan = plan_sweep(bench, values)
    job = jobs.submit("sweep", plan, lambda ctx: run_sweep(ctx, bench, store, planned, plan, name), needs_bench=True)
    return {"job_id": job["id"], "state": job["state"], "samples": planned.samples,
            "duration_s": planned.duration_s, "blocks": planned.blocks}
