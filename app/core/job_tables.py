"""The jobs' tables: a job's row (the truth about its state), the chunks workers share, a job's
listed frames, and the workers. Imported with every other table from ``app.core.models``."""

from __future__ import annotations

import datetime as dt
import enum
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.core.db import Base, JSONType, UTCDateTime, enum_type, utcnow

if TYPE_CHECKING:
    from app.core.models import User


class JobStatus(enum.StrEnum):
    """The life of a background job."""

    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobStatus.succeeded, JobStatus.failed, JobStatus.cancelled)


ONE_AT_A_TIME = (
    "kind IN ('train_student', 'train_sequential', 'quantize_student') "
    "AND status IN ('queued', 'running')"
)
"""The jobs of which at most one of each kind is queued or running (``uq_jobs_one_training``)."""


class Job(Base):
    """A background job: the row is the truth about its state, the queue only carries its id.

    At most one job of each kind that makes a version's files (a student, a sequential cell, an
    int8 student) is queued or running at a time (a partial unique index).
    """

    __tablename__ = "jobs"
    __table_args__ = (
        sa.Index(
            "uq_jobs_one_training",
            "kind",
            unique=True,
            sqlite_where=sa.text(ONE_AT_A_TIME),
            postgresql_where=sa.text(ONE_AT_A_TIME),
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(sa.String(32), index=True)
    status: Mapped[JobStatus] = mapped_column(
        enum_type(JobStatus, "job_status"), default=JobStatus.queued, index=True
    )
    progress: Mapped[float] = mapped_column(sa.Float, default=0.0)
    message: Mapped[str] = mapped_column(sa.String(500), default="")
    params: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    error: Mapped[str | None] = mapped_column(sa.Text)
    attempts: Mapped[int] = mapped_column(default=0)
    max_attempts: Mapped[int] = mapped_column(default=1)
    cancel_requested: Mapped[bool] = mapped_column(default=False)
    worker_id: Mapped[str | None] = mapped_column(sa.String(200))
    heartbeat_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)
    # Within its lane a job a person asked for (1) goes before automatic work (0): the
    # embedding a video import starts, auto-retraining (``app.jobs.service.priority_of``).
    priority: Mapped[int] = mapped_column(default=0, server_default=sa.text("0"))
    # When the queue last carried its id: a queued row not delivered for a while is sent
    # again (the jobs table is the truth; a Redis restart loses what it held).
    enqueued_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)
    created_by_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL")
    )
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow, index=True)
    started_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)
    finished_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)
    created_by: Mapped[User | None] = relationship(lazy="joined", viewonly=True)
    # The frames a person listed (``app.jobs.service.create_job``): written with the job, never
    # loaded with it.
    scope: Mapped[JobScope | None] = relationship(
        lazy="raise", cascade="all, delete-orphan", passive_deletes=True
    )

    @property
    def created_by_name(self) -> str | None:
        """Who started the job (None: the system, or a deleted user)."""
        return self.created_by.username if self.created_by else None


class JobChunk(Base):
    """A chunk of a job that several workers share (``app.jobs.fanout``): its items (frame
    ids), planned by the job's owner; free, taken by one worker, done with its result, or
    taken over when that worker is gone."""

    __tablename__ = "job_chunks"

    job_id: Mapped[int] = mapped_column(
        sa.ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True
    )
    chunk: Mapped[int] = mapped_column(primary_key=True, autoincrement=False)
    items: Mapped[list[int]] = mapped_column(JSONType, default=list)
    worker_id: Mapped[str | None] = mapped_column(sa.String(200))  # None: free to take
    done: Mapped[bool] = mapped_column(default=False)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSONType)


class JobScope(Base):
    """The frames a job was asked to work on, where a person listed them: kept beside the job,
    never in its parameters (which every Jobs-page poll reads), which say only how many."""

    __tablename__ = "job_scopes"

    job_id: Mapped[int] = mapped_column(
        sa.ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True, autoincrement=False
    )
    frame_ids: Mapped[list[int]] = mapped_column(JSONType, default=list)


class Worker(Base):
    """A worker process that is (or was) consuming the queue; ``last_seen_at`` is its heartbeat."""

    __tablename__ = "workers"

    id: Mapped[str] = mapped_column(sa.String(200), primary_key=True)
    hostname: Mapped[str] = mapped_column(sa.String(200))
    pid: Mapped[int]
    threads: Mapped[int] = mapped_column(default=1)
    started_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    last_seen_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    # The lanes it serves ("quick,model") and the job kinds it cannot run, each with the
    # sentence that says why (no teacher weights, an unusable device), as its start-up found.
    lanes: Mapped[str] = mapped_column(
        sa.String(32), default="quick,model", server_default="quick,model"
    )
    unable: Mapped[dict[str, str] | None] = mapped_column(JSONType, default=dict)
