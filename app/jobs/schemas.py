"""Job payloads of the REST API."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from app.core.bounds import InputModel
from app.core.models import JobStatus


class JobOut(BaseModel):
    """A background job as clients see it."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    kind: str
    status: JobStatus
    progress: float = Field(description="0..1")
    message: str = Field(description="What the job is doing now, or why it was retried.")
    params: dict[str, Any]
    result: dict[str, Any] | None
    error: str | None = Field(description="Why the job failed, in one sentence.")
    attempts: int
    cancel_requested: bool
    worker_id: str | None
    created_by: str | None = Field(
        default=None,
        validation_alias="created_by_name",
        description="The user who started the job (none: the system).",
    )
    created_at: dt.datetime
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    lane: str = Field(default="model", description="The lane it runs in: quick or model.")
    waiting: str | None = Field(
        default=None,
        description="A queued job: what it waits behind in its lane, and for about how long.",
    )


class JobPage(BaseModel):
    items: list[JobOut]
    total: int


class JobCreated(BaseModel):
    job_id: int


class DiagnosticJobIn(InputModel):
    """A job that waits and reports progress, to prove that workers run jobs."""

    seconds: float = Field(default=1.0, ge=0, le=3600)
    fail: str | None = Field(default=None, description="When set, the job fails with this text.")
