"""At-least-once delivery: the jobs table is the truth, the queue only carries ids.

A queued row whose id the queue no longer carries (Redis restarted, or the web process died
between its commit and the send) is sent again once it has gone ``job_stale_after_s`` without
delivery; every worker and the web process run this pass with their heartbeat. An id that
arrives twice runs once: a worker claims only a row that is still queued (``runner._claim``).
Why not a queue in the database (``FOR UPDATE SKIP LOCKED``): SQLite has none, and Huey's lanes
and priorities on Redis or a SQLite file already serve the embedded default; the pass makes
Redis a carrier that may forget, with the table deciding what runs.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.core.db import db_now, updated_one, utcnow
from app.core.models import Job, JobStatus
from app.jobs.registry import lane_of

log = structlog.get_logger(__name__)


def mark_enqueued(session_factory: sessionmaker[Session], job_id: int) -> None:
    """Record that the queue carries job ``job_id`` from now on."""
    with session_factory() as session:
        now = db_now(session.get_bind().dialect.name)
        session.execute(sa.update(Job).where(Job.id == job_id).values(enqueued_at=now))
        session.commit()


def deliver_again(queue: Any, older_than_s: float) -> list[int]:
    """Send again each queued job not delivered for ``older_than_s`` that its lane's queue no
    longer holds; a job still waiting in its lane is only marked as carried. Returns the ids
    sent again. Safe in many processes at once: a conditional update takes each row once."""
    with queue.session_factory() as session:
        cutoff = db_now(session.get_bind().dialect.name) - dt.timedelta(seconds=older_than_s)
        overdue = sa.func.coalesce(Job.enqueued_at, Job.created_at) < cutoff
        rows = session.execute(
            sa.select(Job.id, Job.kind, Job.priority)
            .where(Job.status == JobStatus.queued, overdue)
            .order_by(Job.id)
        ).all()
        if not rows:
            return []
        carried: dict[str, set[int]] = {}
        sent: list[int] = []
        for job_id, kind, priority in rows:
            lane = lane_of(kind)
            if lane not in carried:
                carried[lane] = queue.carried(lane)
            taken = updated_one(  # this pass's, not a concurrent one's
                session,
                sa.update(Job)
                .where(Job.id == job_id, Job.status == JobStatus.queued, overdue)
                .values(enqueued_at=db_now(session.get_bind().dialect.name)),
            )
            session.commit()
            if not taken or job_id in carried[lane]:
                continue
            queue.enqueue(job_id, kind, priority)
            sent.append(job_id)
            log.warning("job.delivered_again", job_id=job_id, kind=kind)
        return sent


PASS_ON_DELAY_S = 2.0


def pass_on(queue: Any, job_id: int) -> bool:
    """Whether this worker passes job ``job_id`` on instead of running it: it cannot run the
    job's kind (``queue.unable``). The id goes back on its lane for another worker when a live
    one can run it; with none, the job fails at once with the reason (the one sentence a
    one-machine install without weights always gave) instead of waiting for nobody."""
    from app.jobs.runner import able_workers

    with queue.session_factory() as session:
        row = session.execute(
            sa.select(Job.kind, Job.priority).where(
                Job.id == job_id, Job.status == JobStatus.queued
            )
        ).one_or_none()
    if row is None or row.kind not in queue.unable:
        return False
    reason = queue.unable[row.kind]
    if able_workers(queue.session_factory, queue.settings.job_stale_after_s, row.kind):
        queue.enqueue_later(job_id, row.kind, row.priority, PASS_ON_DELAY_S)
        return True
    with queue.session_factory() as session:
        session.execute(
            sa.update(Job)
            .where(Job.id == job_id, Job.status == JobStatus.queued)
            .values(status=JobStatus.failed, error=reason, finished_at=utcnow())
        )
        session.commit()
    log.warning("job.no_able_worker", job_id=job_id, kind=row.kind, reason=reason)
    return True
