"""The job queue: Huey on a SQLite file by default, on Redis for workers on other machines.

The queue carries only job ids; the jobs table is the truth about a job's state. A worker is a
Huey consumer plus a presence thread that reports heartbeats and reaps jobs of dead workers.

Huey (which imports redis and psycopg, ~0.12 s) is imported when a job is first enqueued or a
consumer starts, not when the web process starts: ``serve --no-worker`` on SQLite answers
``/health`` by counting the queue's table itself (`sqlite_queue_count`).
"""

from __future__ import annotations

import sqlite3
import threading
from contextlib import closing
from functools import cache, cached_property
from typing import TYPE_CHECKING, Any

import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import utcnow
from app.errors import ConfigurationError
from app.jobs.runner import execute_job, new_worker_id, reap_lost_jobs, record_heartbeat
from app.models import Worker
from app.periodic import Periodic

if TYPE_CHECKING:
    from huey import Huey
    from huey.consumer import Consumer

log = structlog.get_logger(__name__)

SHUTDOWN_TIMEOUT_S = 30.0  # how long a stopping worker waits for running jobs to notice


class JobQueue:
    """A Huey instance with the one task that runs a job row by id."""

    def __init__(self, settings: Settings, session_factory: sessionmaker[Session]) -> None:
        self.settings = settings
        self.session_factory = session_factory
        self.worker_id = new_worker_id()
        self.stopping = threading.Event()  # set when this process's worker shuts down
        self.backend = "redis" if settings.queue_url else "sqlite"
        if self.backend == "sqlite":
            settings.home.mkdir(parents=True, exist_ok=True)

    @cached_property
    def huey(self) -> Huey:
        """The Huey instance, made (and Huey imported) on first use."""
        from huey import RedisHuey, SqliteHuey

        if self.backend == "redis":
            huey: Huey = RedisHuey(
                self.settings.queue_name, url=self.settings.queue_url, results=False
            )
        else:
            huey = SqliteHuey(
                self.settings.queue_name, filename=str(self.settings.queue_file), results=False
            )
        return huey

    @cached_property
    def _run_job(self) -> Any:
        """The one task: run the job row with this id."""
        return self.huey.task(name="weldpool.run_job")(self._execute)

    def _execute(self, job_id: int) -> None:
        execute_job(
            job_id, self.settings, self.session_factory, self.worker_id, self.stopping, self
        )

    def enqueue(self, job_id: int) -> None:
        """Put a job id on the queue; raises ConfigurationError when the queue is unreachable."""
        try:
            self._run_job(job_id)
        except Exception as exc:
            raise ConfigurationError(
                f"The job queue ({self.backend}) is unreachable: {exc}; check WELDPOOL_QUEUE_URL."
            ) from exc

    def pending(self) -> int:
        """How many job ids wait in the queue (raises when the queue is unreachable)."""
        if self.backend == "sqlite":
            return sqlite_queue_count(str(self.settings.queue_file), self.settings.queue_name)
        return int(self.huey.pending_count())

    def consumer(self, threads: int, embedded: bool = False) -> Consumer:
        """A Huey consumer for this queue; an embedded one installs no signal handlers."""
        from huey.consumer import Consumer

        self._run_job  # noqa: B018 (the task is registered before the consumer reads tasks)
        cls = _embedded_consumer() if embedded else Consumer
        # max_delay bounds how long an idle SQLite queue waits between polls (Redis blocks).
        return cls(
            self.huey,
            workers=threads,
            worker_type="thread",
            periodic=False,
            check_worker_health=True,
            max_delay=1.0,
            shutdown_timeout=SHUTDOWN_TIMEOUT_S,
        )


@cache
def _embedded_consumer() -> type[Consumer]:
    """A consumer that runs inside the web server's process, whose signals belong to uvicorn."""
    from huey.consumer import Consumer

    class EmbeddedConsumer(Consumer):  # type: ignore[misc]
        def _set_signal_handlers(self) -> None:
            pass

    return EmbeddedConsumer


def sqlite_queue_count(filename: str, name: str) -> int:
    """Job ids waiting in Huey's SQLite queue file, read without importing Huey.

    The same query as Huey's ``SqliteStorage.queue_size`` (a test holds the two equal); a file or
    table that does not exist yet holds none.
    """
    try:
        with closing(sqlite3.connect(f"file:{filename}?mode=ro", uri=True, timeout=5)) as conn:
            row = conn.execute("select count(id) from task where queue=?", (name,)).fetchone()
    except sqlite3.OperationalError as exc:
        if "no such table" in str(exc) or "unable to open" in str(exc):
            return 0
        raise
    return int(row[0])


class WorkerPresence:
    """Registers a worker, reports its heartbeat and reaps jobs of dead workers."""

    def __init__(self, queue: JobQueue, threads: int) -> None:
        self.queue = queue
        host, pid, _ = queue.worker_id.split(":")
        self.row = Worker(
            id=queue.worker_id, hostname=host, pid=int(pid), threads=threads, started_at=utcnow()
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="weldpool-presence", daemon=True)

    def beat(self) -> None:
        """One heartbeat and one reaping pass."""
        record_heartbeat(self.queue.session_factory, self.row)
        reap_lost_jobs(
            self.queue.session_factory, self.queue.settings.job_stale_after_s, self.queue.enqueue
        )

    def start(self) -> None:
        self.beat()
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self.queue.settings.job_heartbeat_s):
            try:
                self.beat()
            except Exception:  # a database hiccup must not kill the heartbeat
                log.exception("worker.heartbeat_failed", worker=self.row.id)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        try:
            with self.queue.session_factory() as session:
                worker = session.get(Worker, self.row.id)
                if worker is not None:
                    session.delete(worker)
                    session.commit()
        except Exception:
            log.exception("worker.unregister_failed", worker=self.row.id)


class JobReaper(Periodic):
    """Reaps jobs of dead workers from the web process of ``serve --no-worker``.

    Workers reap each other's jobs, but with every worker gone nobody would: the job would stay
    "running" and block new trainings. So the web process runs one reaping pass per heartbeat
    period as well (a conditional update takes each job once, whoever runs the pass).
    """

    def __init__(self, queue: JobQueue) -> None:
        self.queue = queue
        super().__init__("reaper", queue.settings.job_heartbeat_s, self.reap)

    def reap(self) -> list[int]:
        return reap_lost_jobs(
            self.queue.session_factory, self.queue.settings.job_stale_after_s, self.queue.enqueue
        )


class EmbeddedWorker:
    """The worker that ``weldpool serve`` runs in its own process, in threads."""

    def __init__(self, queue: JobQueue, threads: int) -> None:
        self.queue = queue
        self.consumer = queue.consumer(threads, embedded=True)
        self.presence = WorkerPresence(queue, threads)

    def start(self) -> None:
        self.presence.start()
        self.consumer.start()
        log.info("worker.embedded_started", worker=self.presence.row.id)

    def stop(self) -> None:
        """Interrupt running jobs at their next progress report (they are re-queued), wait
        for the worker threads, then unregister."""
        self.queue.stopping.set()
        self.consumer.stop(graceful=True)
        self.presence.stop()


def run_standalone_worker(queue: JobQueue, threads: int) -> None:
    """Consume the queue until SIGINT/SIGTERM (``weldpool worker``)."""
    presence = WorkerPresence(queue, threads)
    presence.start()
    log.info("worker.started", worker=presence.row.id, queue=queue.backend, threads=threads)
    try:
        queue.consumer(threads).run()
    finally:
        queue.stopping.set()  # running jobs stop at their next progress report, re-queued
        presence.stop()


def describe(queue: JobQueue) -> dict[str, Any]:
    """The queue's part of /health."""
    try:
        return {"status": "ok", "backend": queue.backend, "pending": queue.pending()}
    except Exception as exc:
        return {"status": "error", "backend": queue.backend, "detail": str(exc)}
