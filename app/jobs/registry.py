"""Job kinds and their handlers: each domain's ``tasks.py`` registers what its jobs do."""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import utcnow
from app.models import Job, JobStatus

# Modules whose import registers job handlers (each domain's tasks.py).
HANDLER_MODULES = (
    "app.jobs.tasks",
    "app.frames.tasks",
    "app.review.tasks",
    "app.training.tasks",
)


def counted(n: int, word: str, plural: str | None = None) -> str:
    """ "1 frame", "3 frames": a count in a job's message, as the pages write it (format.js)."""
    return f"{n} {word if n == 1 else (plural or word + 's')}"


class JobCancelled(Exception):
    """Raised inside a handler when a user asked to cancel its job."""


class JobInterrupted(Exception):
    """Raised inside a handler when its worker is shutting down; the job runs again later."""


@dataclass(frozen=True)
class JobSpec:
    """What a job kind runs, and how often a lost run may be tried again."""

    kind: str
    handler: Callable[[JobContext], dict[str, Any] | None]
    max_attempts: int = 1


_HANDLERS: dict[str, JobSpec] = {}
_loaded = False


def job_handler(
    kind: str, *, max_attempts: int = 1
) -> Callable[[Callable[[JobContext], dict[str, Any] | None]], Callable[..., Any]]:
    """Register ``handler`` as what jobs of ``kind`` run (in a worker)."""

    def register(
        handler: Callable[[JobContext], dict[str, Any] | None],
    ) -> Callable[[JobContext], dict[str, Any] | None]:
        _HANDLERS[kind] = JobSpec(kind, handler, max_attempts)
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


def job_spec(kind: str) -> JobSpec | None:
    """The registered spec of a job kind."""
    load_job_handlers()
    return _HANDLERS.get(kind)


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
    min_interval_s: float = 0.25
    _last_write: float = field(default=0.0, repr=False)
    summary: str | None = None
    """What the job did, in one line: its message once it succeeded (else the last progress)."""

    def progress(self, fraction: float, message: str = "") -> None:
        """Record progress (0..1); raises JobCancelled when a user asked to cancel, and
        JobInterrupted when the worker is shutting down."""
        if self.stopping.is_set():
            raise JobInterrupted()
        now = time.monotonic()
        if now - self._last_write < self.min_interval_s and fraction < 1.0:
            return
        self._last_write = now
        with self.session_factory() as session:
            session.execute(
                sa.update(Job)
                .where(Job.id == self.job_id, Job.worker_id == self.worker_id)
                .values(
                    progress=min(max(fraction, 0.0), 1.0),
                    message=message[:500],
                    heartbeat_at=utcnow(),
                )
            )
            session.commit()
        self.check_cancelled()

    def check_cancelled(self) -> None:
        """Raise JobCancelled when a user asked to cancel this job, JobInterrupted when the
        worker is shutting down."""
        if self.stopping.is_set():
            raise JobInterrupted()
        with self.session_factory() as session:
            row = session.execute(
                sa.select(Job.cancel_requested, Job.status).where(Job.id == self.job_id)
            ).one()
        if row.cancel_requested or row.status != JobStatus.running:
            raise JobCancelled()
