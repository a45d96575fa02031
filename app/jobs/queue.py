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
from functools import cache
from typing import TYPE_CHECKING, Any

import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.core.config import Settings
from app.core.db import utcnow
from app.core.errors import ConfigurationError
from app.core.models import Worker
from app.core.periodic import Periodic
from app.jobs.delivery import deliver_again, mark_enqueued, pass_on
from app.jobs.registry import LANES, kinds_in, lane_of
from app.jobs.runner import execute_job, new_worker_id, reap_lost_jobs, record_heartbeat

if TYPE_CHECKING:
    from huey import Huey
    from huey.consumer import Consumer

log = structlog.get_logger(__name__)

SHUTDOWN_TIMEOUT_S = 30.0  # how long a stopping worker waits for running jobs to notice


class JobQueue:
    """A Huey instance per lane with the one task that runs a job row by id.

    Each lane (``app.jobs.registry.LANES``) is its own queue, ``<queue name>.<lane>``, so a
    quick job never waits behind model work; within a lane a higher priority goes first (a
    person's job before automatic work). Delivery is at least once: a job id may arrive twice
    (``deliver_again``), and only the first claim of a queued row runs it."""

    def __init__(self, settings: Settings, session_factory: sessionmaker[Session]) -> None:
        self.settings = settings
        self.session_factory = session_factory
        self.worker_id = new_worker_id()
        self.stopping = threading.Event()  # set when this process's worker shuts down
        self.backend = "redis" if settings.queue_url else "sqlite"
        self.unable: dict[str, str] = {}  # kinds this process's worker cannot run, and why
        self._hueys: dict[str, Huey] = {}
        self._tasks: dict[str, Any] = {}
        self._lock = threading.Lock()
        if self.backend == "sqlite":
            settings.home.mkdir(parents=True, exist_ok=True)

    def lane_name(self, lane: str) -> str:
        return f"{self.settings.queue_name}.{lane}"

    def huey(self, lane: str) -> Huey:
        """The lane's Huey instance, made (and Huey imported) on first use."""
        with self._lock:
            if lane not in self._hueys:
                from huey import PriorityRedisHuey, SqliteHuey

                name = self.lane_name(lane)
                if self.backend == "redis":
                    huey: Huey = PriorityRedisHuey(name, url=self.settings.queue_url, results=False)
                else:
                    filename = str(self.settings.queue_file)
                    huey = SqliteHuey(name, filename=filename, results=False)
                self._hueys[lane] = huey
                self._tasks[lane] = huey.task(name="weldpool.run_job")(self._execute)
            return self._hueys[lane]

    def _execute(self, job_id: int) -> None:
        if self.unable and pass_on(self, job_id):
            return
        execute_job(
            job_id, self.settings, self.session_factory, self.worker_id, self.stopping, self
        )

    def enqueue(self, job_id: int, kind: str, priority: int = 0) -> None:
        """Put a job id on its kind's lane; raises ConfigurationError when the queue is
        unreachable. The row's ``enqueued_at`` says when (``deliver_again`` reads it)."""
        lane = lane_of(kind)
        try:
            self.huey(lane)
            self._tasks[lane](job_id, priority=priority)
        except Exception as exc:
            raise ConfigurationError(
                f"The job queue ({self.backend}) is unreachable: {exc}; check WELDPOOL_QUEUE_URL."
            ) from exc
        mark_enqueued(self.session_factory, job_id)

    def enqueue_later(self, job_id: int, kind: str, priority: int, delay_s: float) -> None:
        """Put a job id back on its lane, to be delivered after ``delay_s``."""
        lane = lane_of(kind)
        self.huey(lane)
        self._tasks[lane].schedule((job_id,), delay=delay_s, priority=priority)
        mark_enqueued(self.session_factory, job_id)

    def pending(self, lane: str | None = None) -> int:
        """How many job ids wait in one lane or in all (raises when the queue is unreachable)."""
        lanes = LANES if lane is None else (lane,)
        if self.backend == "sqlite":
            filename = str(self.settings.queue_file)
            return sum(sqlite_queue_count(filename, self.lane_name(name)) for name in lanes)
        return sum(int(self.huey(name).pending_count()) for name in lanes)

    def carried(self, lane: str) -> set[int]:
        """The job ids the lane's queue holds now."""
        return {int(task.args[0]) for task in self.huey(lane).pending() if task.args}

    def close(self) -> None:
        """Release the lanes' connections: Huey holds a SQLite file (and its journal) or a
        Redis pool open per lane for the life of the instance. The next use opens them again."""
        with self._lock:
            for huey in self._hueys.values():
                pool = getattr(huey.storage, "pool", None)  # Redis: its connection pool
                if pool is not None:
                    pool.disconnect()
                else:
                    huey.storage.close()

    def consumer(self, lane: str, threads: int, embedded: bool = False) -> Consumer:
        """A Huey consumer for one lane; an embedded one installs no signal handlers."""
        from huey.consumer import Consumer

        huey = self.huey(lane)  # the task is registered before the consumer reads tasks
        cls = _embedded_consumer() if embedded else Consumer
        # max_delay bounds how long an idle SQLite queue waits between polls (Redis blocks).
        return cls(
            huey,
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
    """Registers a worker with its lanes and what it cannot run, reports its heartbeat, reaps
    jobs of dead workers and sends again what the queue lost."""

    def __init__(self, queue: JobQueue, threads: int, lanes: tuple[str, ...] = LANES) -> None:
        self.queue = queue
        host, pid, _ = queue.worker_id.split(":")
        self.row = Worker(
            id=queue.worker_id,
            hostname=host,
            pid=int(pid),
            threads=threads,
            started_at=utcnow(),
            lanes=",".join(lanes),
            unable=queue.unable,
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="weldpool-presence", daemon=True)

    def beat(self) -> None:
        """One heartbeat, one reaping pass and one delivery pass."""
        record_heartbeat(self.queue.session_factory, self.row)
        upkeep(self.queue)

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


def upkeep(queue: JobQueue) -> list[int]:
    """Reap jobs of dead workers and send again the queued jobs the queue lost (ids handled)."""
    stale = queue.settings.job_stale_after_s
    reaped = reap_lost_jobs(queue.session_factory, stale, queue.enqueue)
    return reaped + deliver_again(queue, stale)


class JobReaper(Periodic):
    """Reaps jobs of dead workers, and sends again lost deliveries, from the web process of
    ``serve --no-worker``.

    Workers do it for each other, but with every worker gone nobody would: the job would stay
    "running" and block new trainings. So the web process runs one pass per heartbeat period as
    well (a conditional update takes each job once, whoever runs the pass).
    """

    def __init__(self, queue: JobQueue) -> None:
        self.queue = queue
        super().__init__("reaper", queue.settings.job_heartbeat_s, self.reap)

    def reap(self) -> list[int]:
        return upkeep(self.queue)


def find_unable(
    queue: JobQueue, lanes: tuple[str, ...], standalone: bool = False
) -> dict[str, str]:
    """What this process's worker cannot run (``app.system.status.unable_kinds``), recorded on
    the queue so that it passes those jobs on instead of failing them; a ``standalone``
    worker (on a machine of its own) also checks that its store is the web process's."""
    from app.system.status import unable_kinds

    factory = queue.session_factory if standalone else None
    queue.unable = unable_kinds(queue.settings, kinds_in(lanes), factory)
    return queue.unable


class EmbeddedWorker:
    """The worker that ``weldpool serve`` runs in its own process, in threads: both lanes, the
    model lane with ``threads`` and the quick lane with its own."""

    def __init__(self, queue: JobQueue, threads: int) -> None:
        self.queue = queue
        find_unable(queue, LANES)
        self.consumers = [
            queue.consumer(lane, lane_threads(queue.settings, lane, threads), embedded=True)
            for lane in LANES
        ]
        self.presence = WorkerPresence(queue, threads)

    def start(self) -> None:
        self.presence.start()
        for consumer in self.consumers:
            consumer.start()
        log.info("worker.embedded_started", worker=self.presence.row.id)

    def stop(self) -> None:
        """Interrupt running jobs at their next progress report (they are re-queued), wait
        for the worker threads, then unregister."""
        self.queue.stopping.set()
        for consumer in self.consumers:
            consumer.stop(graceful=True)
        self.presence.stop()


def lane_threads(settings: Settings, lane: str, threads: int) -> int:
    """A lane's worker threads: the model lane ``threads``, the quick lane its own setting."""
    return threads if lane == "model" else settings.quick_workers


def run_standalone_worker(queue: JobQueue, threads: int, lanes: tuple[str, ...] = LANES) -> None:
    """Consume ``lanes`` until SIGINT/SIGTERM (``weldpool worker``): the last lane's consumer
    runs in the main thread (it handles the signals), the others in threads."""
    presence = WorkerPresence(queue, threads, lanes)
    presence.start()
    log.info(
        "worker.started",
        worker=presence.row.id,
        queue=queue.backend,
        threads=threads,
        lanes=",".join(lanes),
        unable=sorted(queue.unable),
    )
    others = [
        queue.consumer(lane, lane_threads(queue.settings, lane, threads), embedded=True)
        for lane in lanes[:-1]
    ]
    try:
        for consumer in others:
            consumer.start()
        queue.consumer(lanes[-1], lane_threads(queue.settings, lanes[-1], threads)).run()
    finally:
        queue.stopping.set()  # running jobs stop at their next progress report, re-queued
        for consumer in others:
            consumer.stop(graceful=True)
        presence.stop()


def describe(queue: JobQueue) -> dict[str, Any]:
    """The queue's part of /health."""
    try:
        return {"status": "ok", "backend": queue.backend, "pending": queue.pending()}
    except Exception as exc:
        return {"status": "error", "backend": queue.backend, "detail": str(exc)}
