"""Jobs through the embedded worker: progress, success, failure, cancellation, lost workers."""

from __future__ import annotations

import datetime as dt
import threading
import time

import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import create_db_engine, create_session_factory, utcnow
from app.core.models import Job, JobStatus, Role, User
from app.core.schema import migrate
from app.jobs.registry import JobContext, JobLost, job_handler
from app.jobs.runner import execute_job, reap_lost_jobs
from app.jobs.service import cancel_job, create_job
from tests.helpers import auth, wait_for, wait_for_job

release = threading.Event()


@job_handler("test-crash")
def _crash(ctx: JobContext) -> dict:
    ctx.progress(0.5, "about to crash")
    raise ZeroDivisionError("division by zero")


@job_handler("test-wait")
def _wait(ctx: JobContext) -> dict:
    while not release.wait(0.05):
        ctx.progress(0.1, "waiting")
    return {"waited": True}


@job_handler("test-retry", max_attempts=2)
def _retry(ctx: JobContext) -> dict:
    return {"attempt": "second"}


def _start(client: TestClient, token: str, **params: object) -> int:
    response = client.post("/api/v1/jobs/diagnostic", json=params, headers=auth(token))
    assert response.status_code == 202, response.text
    return int(response.json()["job_id"])


def test_job_runs_with_progress_and_result(client: TestClient, make_user) -> None:
    _, token = make_user("admin", Role.admin)
    job_id = _start(client, token, seconds=1.0)
    seen = wait_for(
        lambda: (
            (b := client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json())["status"]
            == "running"
            and 0 < b["progress"] < 1
        )
    )
    assert seen
    job = wait_for_job(client, job_id, token)
    assert job["status"] == "succeeded"
    assert job["progress"] == 1.0
    assert job["result"]["seconds"] == 1.0
    assert job["error"] is None and job["attempts"] == 1
    assert job["started_at"] and job["finished_at"]
    listed = client.get("/api/v1/jobs", params={"kind": "diagnostic"}, headers=auth(token)).json()
    assert listed["total"] == 1 and listed["items"][0]["id"] == job_id


def test_job_that_raises_is_failed_with_its_message(client: TestClient, make_user) -> None:
    _, token = make_user("admin", Role.admin)
    job = wait_for_job(client, _start(client, token, seconds=0, fail="The camera is off."), token)
    assert job["status"] == "failed"
    assert job["error"] == "The camera is off."


def test_unexpected_exception_is_recorded(client: TestClient, make_user, session_factory) -> None:
    admin, token = make_user("admin", Role.admin)
    with session_factory() as session:
        job = create_job(session, client.app.state.queue, "test-crash", {}, admin)
    body = wait_for_job(client, job.id, token)
    assert body["status"] == "failed"
    assert body["error"] == "Unexpected error (ZeroDivisionError): division by zero"
    assert body["progress"] == 0.5


def test_cancel_running_and_queued_jobs(client: TestClient, make_user, session_factory) -> None:
    admin, token = make_user("admin", Role.admin)
    release.clear()
    queue = client.app.state.queue
    with session_factory() as session:
        running = create_job(session, queue, "test-wait", {}, admin)
        wait_for(
            lambda: (
                client.get(f"/api/v1/jobs/{running.id}", headers=auth(token)).json()["status"]
                == "running"
            )
        )
        queued = create_job(session, queue, "test-wait", {}, admin)  # one worker: stays queued
    response = client.post(f"/api/v1/jobs/{queued.id}/cancel", headers=auth(token))
    assert response.json()["status"] == "cancelled"
    response = client.post(f"/api/v1/jobs/{running.id}/cancel", headers=auth(token))
    assert response.json()["cancel_requested"] is True
    assert wait_for_job(client, running.id, token)["status"] == "cancelled"
    release.set()
    time.sleep(0.3)  # the cancelled queued job is dequeued and skipped, never run
    assert client.get(f"/api/v1/jobs/{queued.id}", headers=auth(token)).json()["attempts"] == 0


def test_an_annotator_cancels_only_their_own_jobs(
    client: TestClient, make_user, session_factory
) -> None:
    mine, mine_token = make_user("ann-one")
    other, other_token = make_user("ann-two")
    _, reviewer_token = make_user("rev", Role.reviewer)
    queue = client.app.state.queue
    release.clear()
    try:
        with session_factory() as session:
            first = create_job(session, queue, "test-wait", {}, mine)
            second = create_job(session, queue, "test-wait", {}, mine)
        refused = client.post(f"/api/v1/jobs/{first.id}/cancel", headers=auth(other_token))
        assert refused.status_code == 403
        assert "started by someone else" in refused.json()["detail"]
        assert (
            client.get(f"/api/v1/jobs/{first.id}", headers=auth(other_token)).json()[
                "cancel_requested"
            ]
            is False
        )
        own = client.post(f"/api/v1/jobs/{first.id}/cancel", headers=auth(mine_token))
        assert own.status_code == 200 and own.json()["cancel_requested"] is True
        assert own.json()["created_by"] == "ann-one"  # the jobs page shows who started it
        by_reviewer = client.post(f"/api/v1/jobs/{second.id}/cancel", headers=auth(reviewer_token))
        assert by_reviewer.status_code == 200 and by_reviewer.json()["cancel_requested"] is True
        assert other.id != mine.id
    finally:
        release.set()


def test_cancel_reaches_a_job_the_worker_claimed_in_between(session_factory, make_user) -> None:
    """The page read the job as queued; the worker claimed it before the cancel wrote."""
    user, _ = make_user("ann")
    with session_factory() as seen, session_factory() as worker:
        job = Job(kind="test-wait", status=JobStatus.queued, created_by_id=user.id)
        seen.add(job)
        seen.commit()
        assert seen.get_one(Job, job.id).status == JobStatus.queued  # cached as queued
        worker.execute(
            sa.update(Job)
            .where(Job.id == job.id)
            .values(status=JobStatus.running, worker_id="w:1:a", attempts=1)
        )
        worker.commit()
        cancel_job(seen, job.id, seen.get_one(User, user.id))
    with session_factory() as session:
        row = session.get_one(Job, job.id)
        assert (row.status, row.cancel_requested) == (JobStatus.running, True)


def test_unknown_job_is_404(client: TestClient, make_user) -> None:
    _, token = make_user("someone")
    response = client.get("/api/v1/jobs/12345", headers=auth(token))
    assert response.status_code == 404
    assert response.json()["detail"] == "There is no job 12345."


def _running_job(session_factory, kind: str, worker_id: str, seconds_ago: float) -> int:
    with session_factory() as session:
        job = Job(
            kind=kind,
            status=JobStatus.running,
            worker_id=worker_id,
            attempts=1,
            max_attempts=2 if kind == "test-retry" else 1,
            heartbeat_at=utcnow() - dt.timedelta(seconds=seconds_ago),
        )
        session.add(job)
        session.commit()
        return job.id


def test_reaper_fails_or_retries_jobs_of_silent_workers(
    session_factory, settings: Settings
) -> None:
    enqueued: list[int] = []
    silent = _running_job(session_factory, "diagnostic", "elsewhere:1:abc", seconds_ago=120)
    retried = _running_job(session_factory, "test-retry", "elsewhere:1:abc", seconds_ago=120)
    alive = _running_job(session_factory, "diagnostic", "elsewhere:2:def", seconds_ago=1)
    handled = reap_lost_jobs(
        session_factory, 60.0, lambda job_id, kind, priority: enqueued.append(job_id)
    )
    assert sorted(handled) == sorted([silent, retried])
    assert enqueued == [retried]
    with session_factory() as session:
        failed = session.get_one(Job, silent)
        assert failed.status == JobStatus.failed
        assert failed.error.startswith("The worker running this job stopped without finishing")
        assert session.get_one(Job, retried).status == JobStatus.queued
        assert session.get_one(Job, alive).status == JobStatus.running
    # The re-queued job runs again and finishes.
    execute_job(retried, settings, session_factory, "here:1:xyz")
    with session_factory() as session:
        job = session.get_one(Job, retried)
        assert (job.status, job.attempts, job.result) == (
            JobStatus.succeeded,
            2,
            {"attempt": "second"},
        )


def test_stale_worker_cannot_overwrite_a_reaped_job(session_factory, settings: Settings) -> None:
    job_id = _running_job(session_factory, "diagnostic", "old:1:aaa", seconds_ago=120)
    reap_lost_jobs(session_factory, 60.0, lambda *_: None)
    from app.jobs.runner import _finish

    stale = JobContext(job_id, {}, settings, session_factory, "old:1:aaa", attempt=1)
    assert not _finish(stale, status=JobStatus.succeeded)
    with session_factory() as session:
        assert session.get_one(Job, job_id).status == JobStatus.failed


frozen, resumed = threading.Event(), threading.Event()
second_runs, second_may_finish = threading.Event(), threading.Event()
stale_outcomes: list[str] = []


@job_handler("test-frozen", max_attempts=2)
def _frozen(ctx: JobContext) -> dict:
    if ctx.attempt == 1:
        frozen.set()
        resumed.wait(20)  # SIGSTOP: the worker is silent past the stale limit
        try:
            ctx.progress(0.7, "the stale attempt writes")
        except JobLost:
            stale_outcomes.append("lost at progress")
        return {"by": "the stale attempt"}  # as a handler that never reports progress would
    second_runs.set()
    second_may_finish.wait(20)
    ctx.progress(0.5, "the live attempt")
    return {"by": "the live attempt"}


def test_a_reaped_attempt_that_wakes_up_writes_nothing(session_factory, settings: Settings) -> None:
    """A worker frozen past the stale limit is reaped and its job retried, here by a worker
    with the same id (its own process after SIGCONT); the old attempt, woken while the new one
    runs, can write neither progress nor a result: each write carries the attempt's token."""
    for event in (frozen, resumed, second_runs, second_may_finish):
        event.clear()
    stale_outcomes.clear()
    with session_factory() as session:
        job = Job(kind="test-frozen", params={}, max_attempts=2)
        session.add(job)
        session.commit()
        job_id = job.id
    worker = "here:1:same"
    first = threading.Thread(target=execute_job, args=(job_id, settings, session_factory, worker))
    first.start()
    assert frozen.wait(20)
    with session_factory() as session:
        session.get_one(Job, job_id).heartbeat_at = utcnow() - dt.timedelta(seconds=120)
        session.commit()
    assert reap_lost_jobs(session_factory, 60.0, lambda *_: None) == [job_id]
    second = threading.Thread(target=execute_job, args=(job_id, settings, session_factory, worker))
    second.start()
    assert second_runs.wait(20)
    resumed.set()  # SIGCONT while the live attempt runs
    first.join(20)
    with session_factory() as session:
        row = session.get_one(Job, job_id)
        assert (row.status, row.attempts, row.result) == (JobStatus.running, 2, None)
        assert row.message != "the stale attempt writes"
    assert stale_outcomes == ["lost at progress"]
    second_may_finish.set()
    second.join(20)
    with session_factory() as session:
        row = session.get_one(Job, job_id)
        assert (row.status, row.result) == (JobStatus.succeeded, {"by": "the live attempt"})


def test_unreachable_queue_fails_the_job_with_a_clear_503(
    tmp_path, make_user, session_factory, settings: Settings
) -> None:
    from app.main import create_app

    broken = settings.model_copy(update={"queue_url": "redis://127.0.0.1:1/0"})
    _, token = make_user("admin", Role.admin)
    with TestClient(create_app(broken)) as client:
        response = client.post("/api/v1/jobs/diagnostic", json={}, headers=auth(token))
        assert response.status_code == 503
        assert response.json()["detail"].startswith("The job queue (redis) is unreachable")
        health = client.get("/api/v1/health")
        assert health.status_code == 503 and health.json()["queue"]["status"] == "error"
    with session_factory() as session:
        job = session.scalars(sa.select(Job)).one()
        assert job.status == JobStatus.failed and "unreachable" in job.error


def test_stopping_the_server_requeues_a_running_job(
    settings: Settings, session_factory, make_user
) -> None:
    from app.main import create_app

    _, token = make_user("admin", Role.admin)
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        job_id = _start(client, token, seconds=60)
        wait_for(
            lambda: (
                client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()["status"]
                == "running"
            )
        )
        started = time.monotonic()
    assert time.monotonic() - started < 10  # it noticed at its next progress report
    with session_factory() as session:
        job = session.get_one(Job, job_id)
        assert job.status == JobStatus.queued and job.worker_id is None
        assert "interrupted by a worker shutdown" in job.message
    # The next server picks it up again.
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        wait_for(
            lambda: (
                client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()["status"]
                == "running"
            ),
            timeout=30,
        )
        client.post(f"/api/v1/jobs/{job_id}/cancel", headers=auth(token))
        assert wait_for_job(client, job_id, token)["status"] == "cancelled"


@job_handler("test-missing-file")
def _missing_file(ctx: JobContext) -> dict:
    (ctx.settings.home / "frames" / "ab" / "gone.png").read_bytes()
    return {}


def test_a_job_error_names_no_server_path(session_factory, settings: Settings) -> None:
    """Every user reads a job's error: paths under the home folder are relative, other server
    paths only their last part."""
    from app.core.errors import without_server_paths

    with session_factory() as session:
        job = Job(kind="test-missing-file", params={})
        session.add(job)
        session.commit()
        job_id = job.id
    execute_job(job_id, settings, session_factory, "here:1:paths")
    with session_factory() as session:
        error = session.get_one(Job, job_id).error
    assert error.startswith("Unexpected error (FileNotFoundError)")
    assert "'frames/ab/gone.png'" in error and str(settings.home) not in error
    assert without_server_paths("at /usr/lib/x/y.py, 1/2 done", settings.home) == (
        "at y.py, 1/2 done"
    )


@job_handler("test-store-gone")
def _store_gone(ctx: JobContext) -> dict:
    from app.storage import open_storage

    open_storage(ctx.settings).put(b"content", "ab" * 32, ".png")
    return {}


def test_a_job_error_names_no_store_address(session_factory, settings: Settings) -> None:
    """A job failing on an object store that refuses connections says so in words: botocore's
    message named the endpoint's URL (and the bucket's key), which any user reads."""
    import socket

    from tests.helpers import make_settings

    with socket.create_server(("127.0.0.1", 0)) as closed:
        endpoint = f"http://127.0.0.1:{closed.getsockname()[1]}"
    store = make_settings(
        settings.home,
        database_url=settings.database_url,
        storage_url="s3://gone/lab",
        s3_endpoint_url=endpoint,
        storage_job_attempts=1,
    )
    with session_factory() as session:
        job = Job(kind="test-store-gone", params={})
        session.add(job)
        session.commit()
        job_id = job.id
    from app.jobs.runner import STORE_RETRIES

    messages = []
    for _ in range(1 + STORE_RETRIES):  # an outage pauses the job, then fails it
        execute_job(job_id, store, session_factory, "here:1:store")
        with session_factory() as session:
            row = session.get_one(Job, job_id)
            messages.append(row.message)
    assert row.status == JobStatus.failed
    assert row.error == (
        "The object store failed (EndpointConnectionError); check that it runs and answers at "
        "WELDPOOL_S3_ENDPOINT_URL, then run this again."
    )
    assert messages[0].startswith("paused: The object store failed")
    assert not any("127.0.0.1" in message for message in messages)


def test_the_sqlite_queue_is_counted_as_huey_counts_it(tmp_path) -> None:
    """`/health` counts the SQLite queue without importing Huey; the count must be Huey's own,
    for this queue's name and lane only, and 0 before the queue file exists."""
    from app.jobs.queue import JobQueue
    from tests.helpers import make_settings

    engine = create_db_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}")
    migrate(engine)
    factory = create_session_factory(engine)
    queue = JobQueue(make_settings(tmp_path / "a"), factory)
    other = JobQueue(make_settings(tmp_path / "a"), factory)
    assert queue.pending() == 0  # no file yet
    for job_id in range(3):
        queue.enqueue(job_id, "teacher")
    queue.enqueue(7, "export")
    other.enqueue(99, "teacher")
    assert queue.pending("model") == queue.huey("model").pending_count() == 3
    assert queue.pending("quick") == queue.huey("quick").pending_count() == 1
    assert queue.pending() == 4
    assert other.pending() == other.huey("model").pending_count() == 1
    queue.huey("model").dequeue()
    assert queue.pending("model") == queue.huey("model").pending_count() == 2
