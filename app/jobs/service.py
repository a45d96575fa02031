"""Creating, listing and cancelling jobs. The web layer only enqueues and reads rows."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import updated_one, utcnow
from app.core.errors import (
    ConfigurationError,
    ConflictError,
    InvalidInputError,
    NotFoundError,
    PermissionDeniedError,
)
from app.core.models import Job, JobScope, JobStatus, User
from app.core.permissions import Action, may
from app.jobs.queue import JobQueue
from app.jobs.registry import counted, job_spec, lane_of
from app.jobs.runner import reap_lost_jobs


def create_job(
    session: Session,
    queue: JobQueue,
    kind: str,
    params: dict[str, Any],
    user: User | None,
    frame_ids: list[int] | None = None,
) -> Job:
    """Record a queued job and put it on the queue; a job that cannot be queued is failed.
    ``frame_ids``, the frames a person listed, are kept in the job's own scope row
    (``listed_frames`` reads them) and its parameters say only how many."""
    spec = job_spec(kind)
    if spec is None:
        raise InvalidInputError(f"There is no job kind {kind!r}.")
    if frame_ids is not None:
        params = params | {"frames": len(frame_ids), LISTED: True}
    job = Job(
        kind=kind,
        params=params,
        max_attempts=spec.max_attempts,
        created_by_id=user.id if user else None,
        priority=priority_of(params, user),
    )
    session.add(job)
    if frame_ids is not None:
        job.scope = JobScope(frame_ids=list(frame_ids))
    try:
        session.commit()
    except sa.exc.IntegrityError:  # the one-training-job-at-a-time index
        session.rollback()
        # The job in the way may belong to a worker that died: reap, then try once more.
        if not reap_lost_jobs(
            queue.session_factory, queue.settings.job_stale_after_s, queue.enqueue
        ):
            raise ConflictError(
                f"A {kind} job is already queued or running; wait for it."
            ) from None
        return create_job(session, queue, kind, params, user)
    try:
        queue.enqueue(job.id, kind, job.priority)
    except ConfigurationError as exc:
        job.status, job.error, job.finished_at = JobStatus.failed, exc.message, utcnow()
        session.commit()
        raise
    return job


PERSON, AUTOMATIC = 1, 0
LISTED = "listed"
"""The parameter that says a job's frames are listed in its scope row."""


def listed_frames(session: Session, job_id: int, params: dict[str, Any]) -> list[int] | None:
    """The frames a person listed for job ``job_id`` (its scope row; a job queued before the
    scope had its own table lists them in its parameters), or None when it names none."""
    if params.get(LISTED):
        ids = session.scalar(sa.select(JobScope.frame_ids).where(JobScope.job_id == job_id))
        return [int(i) for i in ids or []]
    if "frame_ids" in params:
        return [int(i) for i in params["frame_ids"]]
    return None


def priority_of(params: dict[str, Any], user: User | None) -> int:
    """Within its lane, a job a person asked for goes before automatic work: the embedding a
    video import starts (no user) and auto-retraining (``automatic``)."""
    return AUTOMATIC if user is None or params.get("automatic") else PERSON


def _minutes_left(
    started_at: dt.datetime | None, progress: float, now: dt.datetime
) -> float | None:
    """A running job's time left from its pace so far (None before it has a pace)."""
    if started_at is None or progress < 0.02:
        return None
    elapsed = (now - started_at).total_seconds()
    return elapsed * (1 - progress) / progress / 60


def waiting_for(session: Session, jobs: list[Job]) -> dict[int, str]:
    """For each queued job of ``jobs``: what it waits behind in its lane, in words ("behind
    train_student #4 (about 3 min left) and 2 queued jobs"), from the lane's running jobs and
    the queued jobs that go first (higher priority, else older)."""
    queued = [job for job in jobs if job.status == JobStatus.queued]
    if not queued:
        return {}
    active = session.execute(
        sa.select(Job.id, Job.kind, Job.status, Job.priority, Job.progress, Job.started_at)
        .where(Job.status.in_([JobStatus.queued, JobStatus.running]))
        .order_by(Job.id)
    ).all()
    now, words = utcnow(), {}
    for job in queued:
        lane = lane_of(job.kind)
        same = [row for row in active if lane_of(row.kind) == lane and row.id != job.id]
        running = [row for row in same if row.status == JobStatus.running]
        ahead = [
            row
            for row in same
            if row.status == JobStatus.queued and (row.priority, -row.id) > (job.priority, -job.id)
        ]
        parts = []
        for row in running[:2]:
            left = _minutes_left(row.started_at, row.progress, now)
            when = f" (about {max(1, round(left))} min left)" if left is not None else ""
            parts.append(f"{row.kind} #{row.id}{when}")
        if ahead:
            parts.append(counted(len(ahead), "queued job"))
        words[job.id] = (
            f"queued in the {lane} lane behind " + " and ".join(parts)
            if parts
            else f"queued in the {lane} lane: next"
        )
    return words


def get_job(session: Session, job_id: int) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise NotFoundError(f"There is no job {job_id}.")
    return job


def list_jobs(
    session: Session, kind: str | None, status: JobStatus | None, limit: int, offset: int
) -> tuple[list[Job], int]:
    """Newest first, filtered by kind and status."""
    query = sa.select(Job)
    if kind:
        query = query.where(Job.kind == kind)
    if status:
        query = query.where(Job.status == status)
    total = session.scalar(sa.select(sa.func.count()).select_from(query.subquery())) or 0
    rows = session.scalars(query.order_by(Job.id.desc()).limit(limit).offset(offset)).all()
    return list(rows), total


def cancel_job(session: Session, job_id: int, user: User) -> Job:
    """Cancel a queued job at once; ask a running one to stop at its next progress report.

    Annotators may cancel only the jobs they started; reviewers and admins any job.
    """
    job = get_job(session, job_id)
    if not may(user, Action.cancel_any_job) and job.created_by_id != user.id:
        raise PermissionDeniedError(
            f"Job {job_id} was started by someone else; only they, a reviewer or an admin may "
            "cancel it."
        )
    # Two conditional updates, not a read then a write: the worker may claim a queued job
    # between the two, and then the request to stop must still reach the running job.
    cancelled = updated_one(
        session,
        sa.update(Job)
        .where(Job.id == job_id, Job.status == JobStatus.queued)
        .values(
            status=JobStatus.cancelled,
            cancel_requested=True,
            finished_at=utcnow(),
            message="cancelled before it started",
        ),
    )
    if not cancelled:
        session.execute(
            sa.update(Job)
            .where(Job.id == job_id, Job.status == JobStatus.running)
            .values(cancel_requested=True)
        )
    session.commit()
    session.refresh(job)
    return job
