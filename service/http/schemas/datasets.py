"""Sweeps (the request and its queued answer) and datasets (summary, record, JSON download)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from service.http.schemas.common import BENCH_ID_FIELD, OPEN, JobState, Label


class ExperimentOf(BaseModel):
    """The diagnosis a sweep is the experiment of: the model it was proposed for and the effects it
    separates (two) or tests (one)."""

    model_config = ConfigDict(extra="forbid")

    model_id: str = Field(min_length=1, max_length=40)
    effects: list[str] = Field(default=[], max_length=2)
    extra_datasets: list[str] = Field(
        default=[], max_length=100, description="the datasets the diagnosis had added to the model's own"
    )


class SweepRequest(BaseModel):
    """A characterisation sweep. Volts at the actuator (default the paper's 0–120 V; the bench's
    limits, its stacks' rating, bound them: 0–150 V on the default bench), hertz, seconds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    axes: list[Literal["y", "z"]] = Field(default=["y"], min_length=1)
    waveform: Literal["sine", "step", "chirp", "multisine"] = "sine"
    frequencies_hz: list[float] = Field(default=[1.0, 10.0, 50.0, 100.0], min_length=1, max_length=100)
    cycles: int = Field(default=5, ge=1, le=100_000)
    v_min: float = 0.0  # checked against the bench's limits (service.science.data.plans), naming the field
    v_max: float = 120.0
    settle_s: float = Field(default=0.2, ge=0.0, le=600.0)
    sample_rate_hz: float = Field(default=20_000.0, gt=0.0, le=2_000_000.0)
    together: bool = Field(default=True, description="drive all axes at once, else one after the other")
    levels_v: list[float] = Field(default=[], description="step: levels to step to (default [v_max])")
    hold_s: float = Field(default=2.0, gt=0.0, le=3600.0, description="step: hold time at each level")
    f_start_hz: float = Field(default=1.0, gt=0.0, description="chirp: start frequency")
    f_stop_hz: float = Field(default=100.0, gt=0.0, description="chirp: stop frequency")
    duration_s: float = Field(default=10.0, gt=0.0, le=3600.0, description="chirp: duration")
    name: Label | None = Field(default=None)
    experiment_of: ExperimentOf | None = Field(
        default=None,
        description="the experiment a model's diagnosis proposed (the Models page's Separate): stored with "
        "the dataset as its experiment_of, so its result is found again; absent for a sweep the user planned",
    )

    @field_validator("frequencies_hz")
    @classmethod
    def _positive(cls, values: list[float]) -> list[float]:
        if any(f <= 0 for f in values):
            raise ValueError("every frequency must be above 0 Hz")
        return values

    @field_validator("v_max")
    @classmethod
    def _above_v_min(cls, v_max: float, info) -> float:
        v_min = info.data.get("v_min")
        if v_min is not None and v_max <= v_min:
            raise ValueError(f"must exceed v_min ({v_min:g} V)")
        return v_max


Block = dict[str, Any]
BLOCKS = Field(
    description="the block table: index, kind, axes, start and stop (samples), frequency_hz, cycles, … per block"
)


class SweepQueued(BaseModel):
    """``202``: the sweep is queued; its job's result will be ``{"dataset_id", "samples", "partial"}``."""

    job_id: str
    state: JobState
    samples: int
    duration_s: float
    blocks: list[Block] = BLOCKS


class DatasetSummary(BaseModel):
    """A dataset as listed. ``partial``: the run stopped early (``partial_reason`` says why)."""

    id: str
    name: str
    source: str = Field(description="sweep | trajectory | import")
    axes: list[str]
    samples: int
    sample_rate_hz: float
    partial: bool
    partial_reason: str | None
    created_at: str
    started_at: str | None = Field(description="acquisition start (None for imports)")
    finished_at: str | None
    job_id: str | None
    duration_s: float
    n_blocks: int
    tags: list[str] = Field(default=[], description="a user's labels (PATCH /api/datasets/{id})")
    notes: str | None = None
    bench_id: str | None = BENCH_ID_FIELD
    import_filename: str | None = Field(default=None, description="an import's file (None for data recorded here)")
    experiment_of: dict[str, Any] | None = Field(
        default=None,
        description="a sweep made as an experiment: the model whose diagnosis proposed it (model_id), the effects "
        "it separates or tests (effects), and for a discover run's, its job (discover_job_id); None for data the "
        "user recorded or imported",
    )


class Dataset(DatasetSummary):
    """A dataset's record: block table, plan, the bench's configuration then, units, checksum."""

    blocks: list[Block] = BLOCKS
    plan: dict[str, Any] | None = Field(description="the sweep plan, trajectory request or import options")
    config: dict[str, Any] | None = Field(description="the bench's configuration at the time (None for imports)")
    units: dict[str, str] = Field(description="column → unit")
    drive_range_v: dict[str, list[float]] | None = Field(description="imports: the drive's (min, max) per axis")
    import_notes: list[str] = Field(
        default=[],
        description="imports: units converted to s, V, µm, °C (from "
        "'Time [ms]', 'x_y_nm', a units row, …) and values implausible for a "
        "piezo stage, with the unit that may be meant",
    )
    software_version: str
    file: str = Field(description="the arrays' file, relative to the data dir")
    sha256: str


class DatasetData(BaseModel):
    """``format=json``: every ``stride``-th sample, columns ``t_s``, ``u_<axis>_v``, ``x_<axis>_um``, … as
    arrays (named in ``units``); ``start``/``stop`` are there when the request cut the samples."""

    model_config = OPEN
    id: str
    sample_rate_hz: float
    units: dict[str, str]
    start: int | None = None
    stop: int | None = None
    samples: int
    stride: int
    decimated: bool
    full_resolution: dict[str, str] = Field(description="routes for every sample: csv, ndjson")
    t_s: list[float]
