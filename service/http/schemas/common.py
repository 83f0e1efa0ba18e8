"""Models shared by several resources: the answer that queues a job, and a job."""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

#: For response payloads that may grow: the named fields are documented, others pass through.
OPEN = ConfigDict(extra="allow")

JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class JobQueued(BaseModel):
    """``202``: the job was queued; follow it at GET /api/jobs/{job_id} (or its event stream)."""

    job_id: str
    state: JobState


class Job(BaseModel):
    """A job (DESIGN §5): ``progress`` 0..1; ``result`` is the job's answer (e.g. ``{"dataset_id"}``,
    ``{"model_id", …}``, a trajectory's errors), also on a partial run; ``error`` says why it failed."""

    id: str
    kind: str = Field(description="sweep | trajectory | identify | refine")
    state: JobState
    progress: float = Field(ge=0, le=1)
    message: str | None
    result: dict[str, Any] | None
    error: str | None
    params: dict[str, Any] | None = Field(description="the request as the job runs it")
    created_at: str
    started_at: str | None
    finished_at: str | None


def with_figures(**figures):
    """A decorator that puts ``figures`` into an endpoint's docstring (shown in /docs) before the
    route reads it: ``{name}`` fields; literal braces are doubled."""
    def decorate(endpoint):
        endpoint.__doc__ = endpoint.__doc__.format(**figures)
        return endpoint
    return decorate
