"""The rows the store returns, typed: a dataset, a model and a job (service.store.tables).

Timestamps are ISO-8601 UTC strings; structured fields are JSON (dicts and lists). They are
TypedDicts, so a row is still the plain dict SQLAlchemy hands back.
"""

from __future__ import annotations

from typing import Any

from typing_extensions import TypedDict


class DatasetRow(TypedDict):
    """A stored dataset: its arrays live in ``file`` (relative to the data dir), checked by ``sha256``."""

    id: str
    name: str
    source: str  # sweep | trajectory | import
    axes: list[str]
    samples: int
    sample_rate_hz: float
    blocks: list[dict[str, Any]]  # the block table (service.science.data.segmentation)
    plan: dict[str, Any] | None  # the sweep plan, trajectory request or import options
    config: dict[str, Any] | None  # the bench's configuration at the time (None for imports)
    units: dict[str, str]  # column → unit
    software_version: str
    partial: bool
    partial_reason: str | None
    job_id: str | None
    file: str
    sha256: str
    started_at: str | None  # acquisition start and end (None for imports)
    finished_at: str | None
    created_at: str
    tags: list[str]  # a user's labels (service.store.tidy)
    notes: str | None
    bench_id: str | None  # the bench it was recorded on or imported at (None: before benches had ids)


class ModelRow(TypedDict):
    """A stored model: ``parameters`` is ``model.to_dict()``, checked by ``parameters_sha256``."""

    id: str
    axis: str
    kind: str  # static_pi | dynamic_pi | grpi | composite
    effects: list[str]
    parent_id: str | None
    datasets: list[str]
    options: dict[str, Any] | None  # n_operators, …
    parameters: dict[str, Any]
    parameters_sha256: str
    metrics: dict[str, Any]  # train_rms_um, validation_rms_um, per_dataset, …
    software_version: str
    job_id: str | None
    created_at: str
    name: str | None  # a user's labels (service.store.tidy)
    tags: list[str]
    notes: str | None
    bench_id: str | None  # the bench its datasets came from (None: before benches had ids)


class JobRow(TypedDict):
    """A job: ``state`` queued | running | succeeded | failed | cancelled, ``progress`` 0..1."""

    id: str
    kind: str  # sweep | trajectory | identify | refine
    needs_bench: bool
    state: str
    progress: float
    message: str | None
    params: dict[str, Any] | None
    result: dict[str, Any] | None
    error: str | None
    created_at: str
    started_at: str | None
    finished_at: str | None
    bench_id: str | None  # the bench whose service runs it; no other service touches it
