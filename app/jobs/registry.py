"""Job kinds and their handlers: each domain's ``tasks.py`` registers what its jobs do."""

from __future__ import annotations

import datetime as dt
import importlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session, sessionmaker

from app.core import budgets
from app.core.config import Settings
from app.core.db import db_now, updated_one
from app.core.models import Job, JobStatus, Worker

# Modules whose import registers job handlers (each domain's tasks.py).
HANDLER_MODULES = (
    "app.jobs.tasks",
    "app.frames.tasks",
    "app.review.tasks",
    "app.teacher.tasks",
    "app.training.tasks",
    "app.imports.tasks",
)


def counted(n: int, word: str, plural: str | None = None) -> str:
    """ "1 frame", "3 frames": a count in a job's message, as the pages write it (format.js)."""
    return f"{n} {word if n == 1 else (plural or word + 's')}"


class JobCancelled(Exception):
    """Raised inside a handler when a user asked to cancel its job."""


class JobInterrupted(Exception):
    """Raised inside a handler when its worker is shutting down; the job runs again later."""


class JobYielded(JobInterrupted):
    """Raised inside an automatic job's handler when a job a person asked for has waited in its
    lane (``JobContext.check_cancelled``): the attempt gives its work back between two frames
    and is queued again behind that job, going on from what it recorded (done chunks, proposed
    frames). A subclass of JobInterrupted, so every handler that lets a shutdown through lets
    this through too."""

    def __init__(self, waiting: int) -> None:
        super().__init__(waiting)
        self.waiting = waiting


class JobLost(Exception):
    """Raised inside a handler whose attempt no longer holds the job: it was reaped (its worker
    looked dead, e.g. frozen past the stale limit) and retried or failed. The attempt stops and
    writes nothing more; the row belongs to the newer attempt."""


LANES = ("quick", "model")
"""The two lanes of the queue: quick jobs (exports, label imports, video extraction, int8) never
wait behind model work (training, the teacher, propagation, embeddings). A worker serves one lane
or both (``weldpool worker --lanes``); the embedded worker serves both."""


@dataclass(frozen=True)
class JobSpec:
    """What a job kind runs, in which lane, and how often a lost run may be tried again."""

    kind: str
    handler: Callable[[JobContext], dict[str, Any] | None]
    max_attempts: int = 1
    lane: str = "model"
    fanout: bool = False
    """Its handler shares its work in chunks with the workers its id reaches
    (``app.jobs.fanout``): a worker that receives the id of such a running job helps. Such a
    job goes on from what it recorded when it runs again, so an automatic one also yields to a
    person's job between two frames (``JobYielded``)."""


_HANDLERS: dict[str, JobSpec] = {}
_loaded = False


def job_handler(
    kind: str, *, max_attempts: int = 1, lane: str = "model", fanout: bool = False
) -> Callable[[Callable[[JobContext], dict[str, Any] | None]], Callable[..., Any]]:
    """Register ``handler`` as what jobs of ``kind`` run (in a worker serving ``lane``)."""
    if lane not in LANES:
        raise ValueError(f"lane must be one of {LANES}, not {lane!r}")

    def register(
        handler: Callable[[JobContext], dict[str, Any] | None],
    ) -> Callable[[JobContext], dict[str, Any] | None]:
        _HANDLERS[kind] = JobSpec(kind, handler, max_attempts, lane, fanout)
        return handler

    return register


def load_job_handlers() -> None:
    """Import every domain's handlers (once per process; the app does it at start-up, so that
    no request pays for the imports)."""
    global _loaded
    if not _loaded:
        for module in HANDLER_MODULES:
            importlib.import_module(module)
        _loaded = True


def job_kinds() -> list[str]:
    """Every registered job kind, sorted (the jobs page's Kind filter)."""
    load_job_handlers()
    return sorted(_HANDLERS)


def job_spec(kind: str) -> JobSpec | None:
    """The registered spec of a job kind."""
    load_job_handlers()
    return _HANDLERS.get(kind)


def kinds_in(lanes: tuple[str, ...]) -> list[tuple[str, str]]:
    """Every registered (kind, lane) of ``lanes``."""
    load_job_handlers()
    return sorted((kind, spec.lane) for kind, spec in _HANDLERS.items() if spec.lane in lanes)


YIELD_AFTER_S = 3.0
"""How long a person's job waits in its lane before automatic work there yields to it."""
YIELD_CHECK_S = 1.0
"""How often a running automatic job asks whether a person's job waits."""


def person_waiting(
    session_factory: sessionmaker[Session], lane: str, worker_id: str, above: int = 0
) -> int | None:
    """The oldest queued job of a priority over ``above`` (a person's, over automatic work) in
    ``lane`` that has waited ``YIELD_AFTER_S`` by the database's clock and that worker ``worker_id``
    can run; None when there is none."""
    kinds = [kind for kind, _ in kinds_in((lane,))]
    with session_factory() as session:
        cutoff = db_now(session.get_bind().dialect.name) - dt.timedelta(seconds=YIELD_AFTER_S)
        unable = session.scalar(sa.select(Worker.unable).where(Worker.id == worker_id)) or {}
        return session.scalar(
            sa.select(Job.id)
            .where(
                Job.status == JobStatus.queued,
                Job.priority > above,
                Job.kind.in_([kind for kind in kinds if kind not in unable]),
                sa.func.coalesce(Job.enqueued_at, Job.created_at) <= cutoff,
            )
            .order_by(Job.priority.desc(), Job.id)
            .limit(1)
        )


def lane_of(kind: str) -> str:
    """The lane a job kind runs in (an unknown kind: the model lane, whose worker fails it)."""
    spec = job_spec(kind)
    return spec.lane if spec is not None else "model"


@dataclass
class JobContext:
    """What a running handler may use: its parameters, the database and a progress reporter."""

    job_id: int
    params: dict[str, Any]
    settings: Settings
    session_factory: sessionmaker[Session]
    worker_id: str
    stopping: threading.Event = field(default_factory=threading.Event)
    queue: Any = field(default=None, repr=False)  # the JobQueue, for jobs that start jobs
    attempt: int = 1
    """The fencing token: the row's ``attempts`` when this attempt claimed it. Every write of
    progress or outcome is conditional on it, so a reaped attempt that wakes up cannot write."""
    kind: str = ""
    priority: int = 0
    """Its kind and priority, to put it on the queue again after a worker shutdown."""
    helper: bool = False
    """A worker helping with another worker's running job (``app.jobs.fanout``): it checks
    that the job still runs but writes neither its progress nor its outcome."""
    min_interval_s: float = 0.25
    _last_write: float = field(default=0.0, repr=False)
    _next_yield_check: float = field(default=0.0, repr=False)
    summary: str | None = None
    """What the job did, in one line: its message once it succeeded (else the last progress)."""

    def progress(self, fraction: float, message: str = "") -> None:
        """Record progress (0..1); raises JobCancelled when a user asked to cancel,
        JobInterrupted when the worker is shutting down and JobLost when this attempt no
        longer holds the job."""
        if self.stopping.is_set():
            raise JobInterrupted()
        budgets.batch_checkpoint(self.settings)  # fewer threads while a reviewer clicks
        if self.helper:
            self.check_cancelled()
            return
        now = time.monotonic()
        if now - self._last_write < self.min_interval_s and fraction < 1.0:
            return
        self._last_write = now
        with self.session_factory() as session:
            written = updated_one(
                session,
                sa.update(Job)
                .where(self.holds())
                .values(
                    progress=min(max(fraction, 0.0), 1.0),
                    message=message[:500],
                    heartbeat_at=db_now(session.get_bind().dialect.name),
                ),
            )
            session.commit()
        if not written:
            self.check_cancelled()  # says which: cancelled, or lost
            raise JobLost()
        self.check_cancelled()

    def holds(self) -> sa.ColumnElement[bool]:
        """The condition under which the job's row is still this attempt's."""
        return sa.and_(
            Job.id == self.job_id,
            Job.worker_id == self.worker_id,
            Job.attempts == self.attempt,
            Job.status == JobStatus.running,
        )

    def check_cancelled(self) -> None:
        """Raise JobCancelled when a user asked to cancel this job, JobInterrupted when the
        worker is shutting down, JobLost when this attempt no longer holds it. Handlers call it
        before they commit what they made, so a lost attempt records nothing."""
        if self.stopping.is_set():
            raise JobInterrupted()
        with self.session_factory() as session:
            row = session.execute(
                sa.select(Job.cancel_requested, Job.status, Job.worker_id, Job.attempts).where(
                    Job.id == self.job_id
                )
            ).one_or_none()
        owner = self.worker_id if not self.helper else (row.worker_id if row else None)
        if row is None or row.worker_id != owner or row.attempts != self.attempt:
            raise JobLost()
        if row.cancel_requested or row.status != JobStatus.running:
            raise JobCancelled()
        self._yield_to_a_person()

    def _yield_to_a_person(self) -> None:
        """Raise JobYielded when this is automatic work of a kind that goes on from what it
        recorded and a job a person asked for has waited ``YIELD_AFTER_S`` in its lane for a
        worker (none was free); asked at most every ``YIELD_CHECK_S``."""
        now = time.monotonic()
        if self.priority > 0 or now < self._next_yield_check:
            return
        spec = job_spec(self.kind)
        if spec is None or not spec.fanout:
            return
        self._next_yield_check = now + YIELD_CHECK_S
        waiting = person_waiting(self.session_factory, spec.lane, self.worker_id, self.priority)
        if waiting is not None:
            raise JobYielded(waiting)
