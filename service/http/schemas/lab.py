"""The lab: the registered benches (state, heartbeat, latest model per axis) and one axis's latest
models compared across benches. Lengths in µm, times in s, timestamps ISO-8601 UTC."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field


class LatestModel(BaseModel):
    """A bench's newest model of one axis."""

    model_config = {"protected_namespaces": ()}
    id: str
    kind: str
    effects: list[str]
    validation_rms_um: float | None = Field(description="held-out RMS (mean over blocks)")
    train_rms_um: float | None
    noise_floor_um: float | None = Field(
        description="from its metrics, or the discovery step that stored it; null if neither knows it"
    )
    created_at: str
    origin: dict[str, Any] = Field(
        default_factory=dict,
        description='where its data came from: {"fitted_on": "this_bench" | "imported" | "mixed", "imported": '
        '[{"dataset_id", "name", "filename"}]}',
    )
    made_by: dict[str, str] | None = Field(
        None,
        description='the job that stored it: {"job_id", "kind", "state"} (a discover stores each step as it goes, '
        "so the newest may be from a run that was cancelled); null if unknown",
    )


class BenchSummary(BaseModel):
    """A bench as its service last registered it. ``state`` is what it last wrote (starting | idle |
    busy | stopped); ``online`` is false once it stopped or its heartbeat is older than
    ``offline_after_heartbeats`` of its ``heartbeat_s``: its data stays readable."""

    id: str
    name: str = Field(description="the bench configuration's own name")
    bench: str = Field(description="the configuration the service was started with (--bench)")
    url: str = Field(description="where its service answers")
    state: Literal["starting", "idle", "busy", "stopped"]
    online: bool
    running_job_id: str | None = Field(description="the bench job running at its last heartbeat")
    started_at: str
    heartbeat_at: str
    heartbeat_age_s: float
    heartbeat_s: float = Field(description="its heartbeat interval")
    software_version: str


class LabBench(BenchSummary):
    datasets: int = Field(
        description="how many datasets it recorded (imports not counted: another stage recorded them)"
    )
    imported_datasets: int = Field(
        default=0, description="how many datasets imported from another stage's file it stores (bench_id is its own)"
    )
    latest_models: dict[Literal["y", "z"], LatestModel | None] = Field(
        description="per axis its newest model fitted on this bench's own data"
    )
    latest_imported_models: dict[Literal["y", "z"], LatestModel | None] = Field(
        default_factory=dict,
        description="per axis its newest model fitted on imported data (another stage's record, see its origin)",
    )


class LabBenches(BaseModel):
    """``GET /api/lab/benches``."""

    benches: list[LabBench]
    offline_after_heartbeats: int
    this_bench_id: str | None = Field(description="the bench of the service that answered")


class ComparedModel(LatestModel):
    parameters: dict[str, dict[str, float | None]] = Field(
        description="per effect its fitted physical parameters, units in the names (resonance_hz, damping_ratio, "
        "creep_pct_per_decade, delay_us, drift_nm_per_s, coupling_ratio, …)"
    )


class ComparedBench(BenchSummary):
    model: ComparedModel | None = Field(description="its newest model of the axis (null: none yet)")


class ImportedComparison(BaseModel):
    bench_id: str = Field(description="the bench that stored it (not the stage it describes: see its origin)")
    model: ComparedModel


class LabComparison(BaseModel):
    """``GET /api/lab/compare?axis=``: per bench, its newest model of the axis fitted on its own data;
    ``imported``: the newest fitted on imported data, apart."""

    axis: Literal["y", "z"]
    benches: list[ComparedBench]
    imported: list[ImportedComparison] = Field(default_factory=list)
    parameter_names: list[str] = Field(description="effect.parameter over every bench's model, for a table's columns")
