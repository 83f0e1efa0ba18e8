"""Models shared by several resources: the answer that queues a job, and a job."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import Query
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator

from service.render.text import breaks_a_line

#: For response payloads that may grow: the named fields are documented, others pass through.
OPEN = ConfigDict(extra="allow")

JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]
JobKind = Literal["sweep", "trajectory", "identify", "refine", "discover", "prepare"]
#: The ``?bench_id=`` of the list routes: only that bench's rows (a lab sees every bench's by default).
BENCH_FILTER = Query(
    None,
    min_length=1,
    max_length=40,
    pattern=r"^[a-z0-9][a-z0-9._-]*$",
    description="only the rows of this bench (GET /api/lab/benches lists them)",
)


def one_line(text: str) -> str:
    """A name or tag is one line: no line break or control character (a name is printed in lists, in
    script comments and in headers, where a line break would end them)."""
    if any(breaks_a_line(c) for c in text):
        raise ValueError("must be one line: no line break, tab or other control character")
    return text


#: a user's label of a dataset, model, sweep or run: one line, 1–200 characters
Label = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(one_line)]

BENCH_ID_FIELD = Field(
    default=None, description="the bench (GET /api/lab/benches) it belongs to; null: stored before benches had ids"
)


class LabelsUpdate(BaseModel):
    """PATCH a dataset or model: any of ``name``, ``tags`` (replaces the list) and ``notes`` (null
    clears them). The data and parameters never change."""

    model_config = ConfigDict(extra="forbid")

    name: Label | None = None
    tags: list[str] | None = Field(default=None, max_length=50)
    notes: str | None = Field(default=None, max_length=20_000)

    @field_validator("tags")
    @classmethod
    def _tags_are_words(cls, tags: list[str] | None) -> list[str] | None:
        if tags is not None and any(not t.strip() or len(t) > 60 for t in tags):
            raise ValueError("every tag must be 1–60 characters, not blank")
        for tag in tags or []:
            one_line(tag)
        return None if tags is None else list(dict.fromkeys(t.strip() for t in tags))


class DatasetLabelsUpdate(LabelsUpdate):
    """PATCH a dataset: as LabelsUpdate, but a dataset always has a name (it cannot be cleared)."""

    @field_validator("name")
    @classmethod
    def _name_kept(cls, name: str | None) -> str:
        if name is None:
            raise ValueError("a dataset's name cannot be cleared; give a new one")
        return name


class Deleted(BaseModel):
    """What a DELETE removed: the records (a cascade lists every model that went with it) and the
    bytes of array files freed."""

    datasets: list[str]
    models: list[str]
    freed_bytes: int


class JobQueued(BaseModel):
    """``202``: the job was queued; follow it at GET /api/jobs/{job_id} (or its event stream)."""

    job_id: str
    state: JobState


class Job(BaseModel):
    """A job: ``progress`` 0..1; ``result`` is the job's answer (e.g. ``{"dataset_id"}``,
    ``{"model_id", …}``, a trajectory's errors), also on a partial run; ``error`` says why it failed."""

    id: str
    kind: str = Field(description="sweep | trajectory | identify | refine | discover | prepare (JobKind)")
    state: JobState
    progress: float = Field(ge=0, le=1)
    message: str | None
    result: dict[str, Any] | None
    error: str | None
    params: dict[str, Any] | None = Field(description="the request as the job runs it")
    created_at: str
    started_at: str | None
    finished_at: str | None
    bench_id: str | None = BENCH_ID_FIELD


def with_figures(**figures):
    """A decorator that puts ``figures`` into an endpoint's docstring (shown in /docs) before the
    route reads it: ``{name}`` fields; literal braces are doubled."""

    def decorate(endpoint):
        endpoint.__doc__ = endpoint.__doc__.format(**figures)
        return endpoint

    return decorate
