"""Standalone worker processes: a job through the real Redis, and a worker killed mid-job."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory
from app.core.models import Job, JobStatus, Role, User, Worker
from app.core.schema import migrate
from app.jobs.queue import JobQueue
from app.jobs.service import create_job
from app.main import create_app
from tests.helpers import REPO, auth, make_settings, wait_for

pytestmark = pytest.mark.slow


def _env(settings: Settings) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        {
            "WELDPOOL_HOME": str(settings.home),
            "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
            "WELDPOOL_QUEUE_NAME": settings.queue_name,
            "WELDPOOL_JOB_HEARTBEAT_S": str(settings.job_heartbeat_s),
            "WELDPOOL_JOB_STALE_AFTER_S": str(settings.job_stale_after_s),
        }
    )
    env.pop("WELDPOOL_QUEUE_URL", None)
    if settings.queue_url:
        env["WELDPOOL_QUEUE_URL"] = settings.queue_url
    return env


@pytest.fixture
def spawn_worker(tmp_path: Path) -> Iterator:
    procs: list[subprocess.Popen] = []

    def spawn(settings: Settings) -> subprocess.Popen:
        log = open(tmp_path / f"worker-{len(procs)}.log", "w")  # noqa: SIM115
        proc = subprocess.Popen(
            [sys.executable, "-m", "app", "worker"],
            env=_env(settings),
            cwd=REPO,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        procs.append(proc)
        return proc

    yield spawn
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _setup(settings: Settings):
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    factory = create_session_factory(engine)
    with factory() as session:
        admin = User(username="admin", password_hash="x", role=Role.admin)
        session.add(admin)
        session.commit()
    return factory, admin


def _job(factory, job_id: int) -> Job:
    with factory() as session:
        return session.get_one(Job, job_id)


@pytest.mark.redis
def test_job_through_real_redis_and_a_separate_worker(
    tmp_path: Path, redis_url: str, postgres_url: str, spawn_worker
) -> None:
    settings = make_settings(tmp_path / "home", database_url=postgres_url, queue_url=redis_url)
    factory, admin = _setup(settings)
    queue = JobQueue(settings, factory)
    assert queue.backend == "redis"
    with factory() as session:
        job = create_job(session, queue, "diagnostic", {"seconds": 0.5}, admin)
    assert queue.pending() == 1
    worker = spawn_worker(settings)
    done = wait_for(lambda: (j := _job(factory, job.id)).status.finished and j, timeout=60)
    assert done.status == JobStatus.succeeded, done.error
    assert done.result["pid"] == worker.pid != os.getpid()
    assert queue.pending() == 0

    # The API, without an embedded worker, sees the worker and enqueues through Redis too.
    with factory() as session:
        from app.core.security import issue_token

        _, token = issue_token(session, session.get_one(User, admin.id), "t")
        session.commit()
    with TestClient(create_app(settings)) as client:
        health = client.get("/api/v1/health").json()
        assert health["queue"]["backend"] == "redis" and health["queue"]["alive"] == 1
        response = client.post("/api/v1/jobs/diagnostic", json={"seconds": 0}, headers=auth(token))
        job_id = response.json()["job_id"]
        wait_for(lambda: _job(factory, job_id).status == JobStatus.succeeded, timeout=30)

    worker.send_signal(signal.SIGTERM)
    assert worker.wait(timeout=20) == 0
    with factory() as session:
        assert session.query(Worker).count() == 0  # a clean stop unregisters the worker


def test_killed_worker_does_not_leave_its_job_running(
    tmp_path: Path, database_url: str, spawn_worker
) -> None:
    settings = make_settings(tmp_path / "home", database_url=database_url)
    factory, admin = _setup(settings)
    queue = JobQueue(settings, factory)
    with factory() as session:
        job = create_job(session, queue, "diagnostic", {"seconds": 120}, admin)
    doomed = spawn_worker(settings)
    wait_for(lambda: _job(factory, job.id).status == JobStatus.running, timeout=60)
    doomed.kill()
    doomed.wait()
    assert _job(factory, job.id).status == JobStatus.running  # nobody has noticed yet

    spawn_worker(settings)  # a new worker on this host sees that the pid is dead
    lost = wait_for(lambda: (j := _job(factory, job.id)).status.finished and j, timeout=60)
    assert lost.status == JobStatus.failed
    assert lost.error.startswith("The worker running this job stopped without finishing it")
    assert str(doomed.pid) in lost.error


def test_with_no_worker_left_the_server_reaps_and_health_says_so(
    tmp_path: Path, database_url: str, spawn_worker
) -> None:
    """`serve --no-worker` + one worker killed mid-training: the web process itself fails the
    lost job (no other worker starts), a new training is accepted, and health warns."""
    settings = make_settings(tmp_path / "home", database_url=database_url)
    factory, admin = _setup(settings)
    with factory() as session:
        from app.core.security import issue_token

        _, token = issue_token(session, session.get_one(User, admin.id), "t")
        session.commit()
    with TestClient(create_app(settings)) as client:  # no embedded worker
        doomed = spawn_worker(settings)
        wait_for(lambda: client.get("/api/v1/health").json()["queue"]["alive"] == 1, timeout=60)
        queue = client.app.state.queue
        with factory() as session:
            job = create_job(session, queue, "diagnostic", {"seconds": 120}, admin)
        running = wait_for(lambda: (j := _job(factory, job.id)).status == JobStatus.running and j)
        doomed.kill()
        doomed.wait()
        # A training job of the same dead worker, as if it had been training: it blocks the
        # next training until someone reaps it.
        with factory() as session:
            stuck = Job(
                kind="train_student",
                status=JobStatus.running,
                worker_id=running.worker_id,
                heartbeat_at=running.heartbeat_at,
                attempts=1,
                max_attempts=1,
            )
            session.add(stuck)
            session.commit()
            stuck_id = stuck.id
        lost = wait_for(lambda: (j := _job(factory, job.id)).status.finished and j, timeout=60)
        assert lost.status == JobStatus.failed and str(doomed.pid) in lost.error
        wait_for(lambda: _job(factory, stuck_id).status == JobStatus.failed, timeout=60)
        health = wait_for(
            lambda: (h := client.get("/api/v1/health")).json()["queue"]["alive"] == 0 and h,
            timeout=60,
        )  # the dead worker's last heartbeat has aged past job_stale_after_s
        assert health.status_code == 200
        body = health.json()
        assert body["status"] == "degraded" and body["queue"]["alive"] == 0
        assert any("No worker is alive" in warning for warning in body["warnings"])
        assert client.get("/api/v1/jobs", headers=auth(token)).status_code == 200
