"""What a worker does with a job id: claim the row, run the handler, record the outcome.

Also the reaper, which finds jobs whose worker died and fails or re-queues them.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import socket
import threading
from collections.abc import Callable
from typing import Any

import sqlalchemy as sa
import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.core import budgets
from app.core.config import Settings
from app.core.db import changed, db_now, updated_one, utcnow
from app.core.errors import failure_sentence, store_outage, without_server_paths
from app.core.models import Job, JobStatus, Worker
from app.jobs.registry import (
    JobCancelled,
    JobContext,
    JobInterrupted,
    JobLost,
    JobYielded,
    job_spec,
)
from weldpool_core.errors import WeldpoolError

log = structlog.get_logger(__name__)

HOSTNAME = socket.gethostname()


def new_worker_id() -> str:
    """host:pid:random, so that a worker on the same host can tell whether its peer is alive."""
    return f"{HOSTNAME}:{os.getpid()}:{os.urandom(3).hex()}"


def _finish(context: JobContext, **values: object) -> bool:
    """Write a final state, only if this attempt still holds the running job (its fencing
    token: a reaped attempt that wakes up writes nothing)."""
    if isinstance(error := values.get("error"), str):
        values["error"] = without_server_paths(error, context.settings.home)
    with context.session_factory() as session:
        done = updated_one(
            session,
            sa.update(Job)
            .where(context.holds())
            .values(**({"finished_at": utcnow(), "heartbeat_at": utcnow()} | values)),
        )
        session.commit()
        return done


def _claim(session_factory: sessionmaker[Session], job_id: int, worker_id: str) -> Job | None:
    """Take the job if it is still queued: its row as claimed (None: it was cancelled or
    another worker took it)."""
    with session_factory() as session:
        now = db_now(session.get_bind().dialect.name)
        claimed = updated_one(
            session,
            sa.update(Job)
            .where(Job.id == job_id, Job.status == JobStatus.queued)
            .values(
                status=JobStatus.running,
                worker_id=worker_id,
                attempts=Job.attempts + 1,
                started_at=now,
                heartbeat_at=now,
                progress=0.0,
                message="",
            ),
        )
        session.commit()
        if not claimed:
            return None
        return session.get_one(Job, job_id)


def _run_handler(context: JobContext, handler: Callable[[JobContext], Any], queue: Any) -> None:
    """The handler, and its outcome in the job's row: succeeded with its result, queued again
    after a worker shutdown, cancelled, failed (one sentence), or left alone when the lease
    was lost to another worker."""
    job_id = context.job_id
    try:
        result = handler(context)
    except JobLost:
        log.warning("job.lost_lease", job_id=job_id, attempt=context.attempt)
    except JobYielded as exc:
        _yield(context, queue, exc.waiting)
    except JobInterrupted:
        requeued = _finish(
            context,
            status=JobStatus.queued,
            finished_at=None,
            worker_id=None,
            message="interrupted by a worker shutdown; it will run again",
        )
        if requeued and queue is not None:
            queue.enqueue(job_id, context.kind, context.priority)
        log.info("job.interrupted", job_id=job_id)
    except JobCancelled:
        _finish(context, status=JobStatus.cancelled, message="cancelled by a user")
        log.info("job.cancelled", job_id=job_id)
    except Exception as exc:
        if store_outage(exc):
            _pause(context, queue, failure_sentence(exc))
        else:
            _finish(context, status=JobStatus.failed, error=failure_sentence(exc))
            log.log(
                logging.WARNING if isinstance(exc, WeldpoolError) else logging.ERROR,
                "job.failed",
                job_id=job_id,
                error=failure_sentence(exc),
                exc_info=not isinstance(exc, WeldpoolError),
            )
    else:
        finished = _finish(
            context,
            status=JobStatus.succeeded,
            progress=1.0,
            result=result or {},
            **({"message": context.summary[:500]} if context.summary else {}),
        )
        log.info("job.succeeded" if finished else "job.lost_lease", job_id=job_id)


def _yield(context: JobContext, queue: Any, waiting: int) -> None:
    """Automatic work gave way to job ``waiting``, which a person asked for: queued again
    behind it (its attempt not counted: it was not lost), going on from what it recorded."""
    yielded = _finish(
        context,
        status=JobStatus.queued,
        finished_at=None,
        worker_id=None,
        attempts=Job.attempts - 1,
        message=f"waiting: job #{waiting}, which a person asked for, goes first",
    )
    if yielded and queue is not None:
        queue.enqueue(context.job_id, context.kind, context.priority)
    log.info("job.yielded", job_id=context.job_id, to=waiting)


STORE_RETRIES = 5
"""How often a job paused by the object store or the network runs again (beyond the attempts its
kind allows a lost run) before it fails with the store's sentence."""
PAUSE_S = 30.0
"""How long a paused job waits before it runs again."""


def _pause(context: JobContext, queue: Any, sentence: str) -> None:
    """The store or the network failed under the job (not its work): queue it again after
    ``PAUSE_S``, where it goes on from what it recorded (skipped frames, done chunks); fail it
    with the sentence once it has paused ``STORE_RETRIES`` times."""
    spec = job_spec(context.kind)
    if context.attempt >= (spec.max_attempts if spec else 1) + STORE_RETRIES:
        _finish(context, status=JobStatus.failed, error=sentence)
        log.warning("job.failed", job_id=context.job_id, error=sentence)
        return
    paused = _finish(
        context,
        status=JobStatus.queued,
        finished_at=None,
        worker_id=None,
        message=f"paused: {sentence} It runs again in {PAUSE_S:g} s."[:500],
    )
    if paused and queue is not None:
        queue.enqueue_later(context.job_id, context.kind, context.priority, PAUSE_S)
    log.warning("job.paused", job_id=context.job_id, error=sentence)


def execute_job(
    job_id: int,
    settings: Settings,
    session_factory: sessionmaker[Session],
    worker_id: str,
    stopping: threading.Event | None = None,
    queue: Any = None,
) -> None:
    """Run job ``job_id`` if it is still queued; every outcome ends up in its row."""
    claimed = _claim(session_factory, job_id, worker_id)
    if claimed is None:
        joined = _join(job_id, settings, session_factory, worker_id, stopping, queue)
        if not joined:
            log.info("job.skipped", job_id=job_id, reason="not queued (cancelled or taken)")
        return
    kind, attempt = claimed.kind, claimed.attempts
    log.info("job.started", job_id=job_id, kind=kind, worker=worker_id, attempt=attempt)
    context = JobContext(
        job_id,
        dict(claimed.params or {}),
        settings,
        session_factory,
        worker_id,
        stopping or threading.Event(),
        queue,
        attempt=attempt,
        kind=kind,
        priority=claimed.priority,
    )
    spec = job_spec(kind)
    budgets.start_batch(settings)  # this thread now runs below the web process's clicks
    if spec is None:
        _finish(
            context,
            status=JobStatus.failed,
            error=f"This worker does not know job kind {kind!r}; update the worker.",
        )
        return
    _run_handler(context, spec.handler, queue)


def _join(
    job_id: int,
    settings: Settings,
    session_factory: sessionmaker[Session],
    worker_id: str,
    stopping: threading.Event | None,
    queue: Any,
) -> bool:
    """Help with a running job whose kind fans out (``app.jobs.fanout``): its handler as a
    helper, which takes free chunks and writes neither progress nor the job's outcome."""
    with session_factory() as session:
        row = session.execute(
            sa.select(Job.kind, Job.params, Job.attempts, Job.priority, Job.worker_id).where(
                Job.id == job_id, Job.status == JobStatus.running
            )
        ).one_or_none()
    spec = job_spec(row.kind) if row is not None else None
    if row is None or spec is None or not spec.fanout or row.worker_id == worker_id:
        return False
    context = JobContext(
        job_id,
        dict(row.params or {}),
        settings,
        session_factory,
        worker_id,
        stopping or threading.Event(),
        queue,
        attempt=row.attempts,
        kind=row.kind,
        priority=row.priority,
        helper=True,
    )
    log.info("job.joined", job_id=job_id, kind=row.kind, worker=worker_id)
    budgets.start_batch(settings)
    try:
        spec.handler(context)
    except (JobCancelled, JobLost, JobInterrupted):
        log.info("job.helper_stopped", job_id=job_id, worker=worker_id)
    except Exception:  # the owner sees the chunk given back and works it itself
        log.exception("job.helper_failed", job_id=job_id, worker=worker_id)
    return True


def _pid_is_dead(worker_id: str) -> bool:
    host, _, rest = worker_id.partition(":")
    pid_text = rest.partition(":")[0]
    if host != HOSTNAME or not pid_text.isdigit() or int(pid_text) == os.getpid():
        return False
    try:
        os.kill(int(pid_text), 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def reap_lost_jobs(
    session_factory: sessionmaker[Session],
    stale_after_s: float,
    enqueue: Callable[[int, str, int], None],
) -> list[int]:
    """Fail or re-queue running jobs whose worker died (a dead pid here, or no heartbeat by the
    database's clock).

    Returns the ids of the jobs it handled. Safe to run in many workers at once: each job is
    taken by one conditional update.
    """
    handled: list[int] = []
    with session_factory() as session:
        cutoff = db_now(session.get_bind().dialect.name) - dt.timedelta(seconds=stale_after_s)
        stale_beat = sa.or_(Job.heartbeat_at.is_(None), Job.heartbeat_at < cutoff)
        running = session.execute(
            sa.select(
                Job.id,
                Job.kind,
                Job.priority,
                Job.worker_id,
                Job.heartbeat_at,
                Job.attempts,
                Job.max_attempts,
                stale_beat.label("stale"),
            ).where(Job.status == JobStatus.running)
        ).all()
        for (
            job_id,
            kind,
            priority,
            worker_id,
            heartbeat_at,
            attempts,
            max_attempts,
            stale,
        ) in running:
            if not stale and not _pid_is_dead(worker_id or ""):
                continue
            seen = heartbeat_at.isoformat(timespec="seconds") if heartbeat_at else "never"
            retry = attempts < max_attempts
            values: dict[str, object] = (
                {
                    "status": JobStatus.queued,
                    "worker_id": None,
                    "message": f"retrying: worker {worker_id} stopped (last seen {seen})",
                }
                if retry
                else {
                    "status": JobStatus.failed,
                    "finished_at": utcnow(),
                    "error": f"The worker running this job stopped without finishing it "
                    f"(worker {worker_id}, last seen {seen}); start the job again.",
                }
            )
            taken = updated_one(
                session,
                sa.update(Job)
                .where(
                    Job.id == job_id, Job.status == JobStatus.running, Job.worker_id == worker_id
                )
                .values(**values),
            )
            session.commit()
            if taken:
                handled.append(job_id)
                log.warning("job.lost", job_id=job_id, worker=worker_id, retry=retry)
                if retry:
                    enqueue(job_id, kind, priority)
    return handled


def record_heartbeat(session_factory: sessionmaker[Session], worker: Worker) -> None:
    """Mark this worker and the jobs it runs as alive (by the database's clock)."""
    with session_factory() as session:
        now = db_now(session.get_bind().dialect.name)
        seen = sa.update(Worker).where(Worker.id == worker.id).values(last_seen_at=now)
        if not changed(session, seen):
            session.add(
                Worker(
                    id=worker.id,
                    hostname=worker.hostname,
                    pid=worker.pid,
                    threads=worker.threads,
                    started_at=worker.started_at,
                    last_seen_at=now,
                    lanes=worker.lanes,
                    unable=worker.unable,
                )
            )
        session.execute(
            sa.update(Job)
            .where(Job.worker_id == worker.id, Job.status == JobStatus.running)
            .values(heartbeat_at=now)
        )
        # Forget workers not seen for a day (their jobs were reaped long ago).
        session.execute(sa.delete(Worker).where(Worker.last_seen_at < now - dt.timedelta(days=1)))
        session.commit()


def live_workers(session_factory: sessionmaker[Session], stale_after_s: float) -> int:
    """How many workers reported a heartbeat within ``stale_after_s`` and, when they run on
    this host, still have a live process (a killed one is not counted until its beat ages)."""
    return len(worker_rows(session_factory, stale_after_s))


def able_workers(
    session_factory: sessionmaker[Session], stale_after_s: float, kind: str, threads: bool = False
) -> int:
    """How many live workers serve ``kind``'s lane and can run it (with ``threads``: how many
    of their threads)."""
    from app.jobs.registry import lane_of

    lane = lane_of(kind)
    with session_factory() as session:
        cutoff = db_now(session.get_bind().dialect.name) - dt.timedelta(seconds=stale_after_s)
        rows = session.execute(
            sa.select(Worker.id, Worker.lanes, Worker.unable, Worker.threads).where(
                Worker.last_seen_at >= cutoff
            )
        ).all()
    return sum(
        (count if threads else 1)
        for worker_id, lanes, unable, count in rows
        if lane in lanes.split(",") and kind not in (unable or {}) and not _pid_is_dead(worker_id)
    )


def worker_rows(session_factory: sessionmaker[Session], stale_after_s: float) -> list[Worker]:
    """The live workers (as ``live_workers`` counts them), with their lanes and abilities."""
    with session_factory() as session:
        cutoff = db_now(session.get_bind().dialect.name) - dt.timedelta(seconds=stale_after_s)
        rows = session.scalars(
            sa.select(Worker).where(Worker.last_seen_at >= cutoff).order_by(Worker.started_at)
        ).all()
    return [row for row in rows if not _pid_is_dead(row.id)]


def unserved_kinds(workers: list[Worker], kinds: list[tuple[str, str]]) -> dict[str, str]:
    """The job kinds no live worker can run, each with why (one worker's reason, or that no
    worker serves its lane); empty with no worker at all (health says that on its own)."""
    if not workers:
        return {}
    unserved: dict[str, str] = {}
    for kind, lane in kinds:
        serving = [w for w in workers if lane in w.lanes.split(",")]
        if not serving:
            unserved[kind] = f"no live worker serves the {lane} lane"
        elif all(kind in (w.unable or {}) for w in serving):
            unserved[kind] = (serving[0].unable or {})[kind]
    return unserved
