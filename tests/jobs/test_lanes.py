"""Lanes, priorities and delivery: a quick job never waits behind model work, a person's job
goes before automatic work, a queued row is delivered whatever the queue forgot, heartbeats
are read on the database's clock, and a worker passes on what it cannot run."""

from __future__ import annotations

import datetime as dt
import threading
import time

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.db import create_db_engine, create_session_factory, utcnow
from app.core.models import Job, JobChunk, JobStatus, Role, Worker
from app.core.schema import migrate
from app.jobs import runner
from app.jobs.delivery import deliver_again, pass_on
from app.jobs.fanout import Fanout
from app.jobs.queue import JobQueue
from app.jobs.registry import JobContext, job_handler
from app.jobs.service import create_job
from tests.helpers import auth, make_settings, wait_for, wait_for_job

gate = threading.Event()
order: list[str] = []


@job_handler("lane-block")
def _block(ctx: JobContext) -> dict:
    while not gate.wait(0.05):
        ctx.progress(0.1, "holding the model lane")
    return {}


@job_handler("lane-record")
def _record(ctx: JobContext) -> dict:
    order.append(ctx.params["tag"])
    return {}


def _status(session_factory, job_id: int) -> JobStatus:
    with session_factory() as session:
        return session.get_one(Job, job_id).status


def test_a_quick_job_never_waits_behind_model_work_and_a_person_goes_first(
    client: TestClient, make_user, session_factory
) -> None:
    """With the defaults (the embedded worker, one model thread) held by model work, a quick
    job (a diagnostic, like an export) runs at once; within the model lane a person's job goes
    before automatic work queued before it."""
    gate.clear()
    order.clear()
    user, token = make_user("admin", Role.admin)
    queue = client.app.state.queue  # type: ignore[attr-defined]
    with session_factory() as session:
        blocker = create_job(session, queue, "lane-block", {}, user).id
    wait_for(lambda: _status(session_factory, blocker) == JobStatus.running)
    quick = client.post("/api/v1/jobs/diagnostic", json={"seconds": 0}, headers=auth(token))
    assert wait_for_job(client, quick.json()["job_id"], token)["status"] == "succeeded"
    assert _status(session_factory, blocker) == JobStatus.running

    with session_factory() as session:
        automatic = create_job(session, queue, "lane-record", {"tag": "automatic"}, None).id
        person = create_job(session, queue, "lane-record", {"tag": "person"}, user).id
    gate.set()
    for job_id in (blocker, automatic, person):
        wait_for(lambda job_id=job_id: _status(session_factory, job_id) == JobStatus.succeeded)
    assert order == ["person", "automatic"]


slow_log: list[int] = []


@job_handler("fan-slow", fanout=True)
def _fan_slow(ctx: JobContext) -> dict:
    """Automatic work in chunks that records each item once it is done (as the teacher skips a
    frame it already proposed), between items asking whether to give way."""
    fan = Fanout(ctx, 3)
    if not ctx.helper:
        fan.plan(lambda: list(range(int(ctx.params["n"]))))
    for index in fan.chunks():
        with fan.working(index) as result:
            for item in fan.items(index):
                if item not in slow_log:
                    time.sleep(0.1)
                    slow_log.append(item)
                ctx.check_cancelled()
            result["items"] = list(fan.items(index))
        ctx.progress(fan.progress(), fan.message())
    return {"items": sorted(i for r in fan.results() for i in r["items"])}


def test_automatic_work_gives_way_to_a_person_between_two_items(
    client: TestClient, make_user, session_factory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the one model thread busy with automatic work that goes on from what it recorded
    (the import's embedding run), a person's job that has waited runs at once: the automatic
    job is queued again behind it, its attempt not counted, and then finishes every item once."""
    from app.jobs import registry

    monkeypatch.setattr(registry, "YIELD_AFTER_S", 0.3)
    monkeypatch.setattr(registry, "YIELD_CHECK_S", 0.1)
    order.clear()
    slow_log.clear()
    user, _ = make_user("admin", Role.admin)
    queue = client.app.state.queue  # type: ignore[attr-defined]
    with session_factory() as session:
        automatic = create_job(session, queue, "fan-slow", {"n": 40}, None).id
    wait_for(lambda: len(slow_log) >= 2)
    with session_factory() as session:
        person = create_job(session, queue, "lane-record", {"tag": "person"}, user).id
    wait_for(lambda: _status(session_factory, person) == JobStatus.succeeded)
    assert len(slow_log) < 30  # it ran while the automatic job still had most of its work
    wait_for(lambda: _status(session_factory, automatic) == JobStatus.succeeded, timeout=30)
    with session_factory() as session:
        done = session.get_one(Job, automatic)
        assert done.attempts == 1 and done.result["items"] == list(range(40))
    assert sorted(slow_log) == list(range(40))  # each item once


@pytest.fixture(params=["sqlite", pytest.param("redis", marks=pytest.mark.redis)])
def idle_queue(request: pytest.FixtureRequest, tmp_path, database_url: str):
    """A queue (a SQLite file, or the real Redis) that no worker consumes, over a database."""
    queue_url = request.getfixturevalue("redis_url") if request.param == "redis" else None
    settings = make_settings(tmp_path / "home", database_url=database_url, queue_url=queue_url)
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    queue = JobQueue(settings, create_session_factory(engine))
    yield queue
    queue.huey("quick").flush()
    queue.huey("model").flush()
    engine.dispose()


def test_a_queued_job_the_queue_forgot_is_delivered_once(idle_queue: JobQueue) -> None:
    """The queue emptied under a queued row (Redis restarted): the delivery pass sends it
    again, once — a job its lane still holds is not sent twice — and an id delivered twice
    runs once."""
    queue = idle_queue
    with queue.session_factory() as session:
        job = create_job(session, queue, "diagnostic", {"seconds": 0}, None)
    assert queue.pending("quick") == 1
    assert deliver_again(queue, older_than_s=0) == []  # its lane holds it
    assert queue.pending("quick") == 1
    queue.huey("quick").flush()  # the restart
    assert deliver_again(queue, older_than_s=3600) == []  # not overdue yet
    assert deliver_again(queue, older_than_s=0) == [job.id]
    assert queue.carried("quick") == {job.id}
    queue.enqueue(job.id, "diagnostic")  # and once more: at least once, run once
    huey = queue.huey("quick")
    while (task := huey.dequeue()) is not None:
        huey.execute(task)
    with queue.session_factory() as session:
        done = session.get_one(Job, job.id)
        assert (done.status, done.attempts) == (JobStatus.succeeded, 1)


@pytest.mark.postgres
def test_a_worker_whose_clock_runs_behind_keeps_its_job(
    postgres_url: str, tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A worker whose clock is 90 s behind writes its heartbeat on the database's clock, so
    another machine's reaper (60 s) leaves its live job alone (it was reaped at once)."""
    engine = create_db_engine(postgres_url)
    migrate(engine)
    factory = create_session_factory(engine)
    worker = Worker(
        id="elsewhere:1:abc",
        hostname="elsewhere",
        pid=1,
        threads=1,
        started_at=utcnow(),
        lanes="quick,model",
        unable={},
    )
    with factory() as session:
        job = Job(kind="diagnostic", status=JobStatus.running, worker_id=worker.id, attempts=1)
        session.add(job)
        session.commit()
    behind = utcnow() - dt.timedelta(seconds=90)
    with monkeypatch.context() as patch:  # the worker's machine
        patch.setattr(runner, "utcnow", lambda: behind)
        patch.setattr("app.core.db.utcnow", lambda: behind)
        runner.record_heartbeat(factory, worker)
    assert runner.reap_lost_jobs(factory, 60.0, lambda *_: None) == []
    with factory() as session:
        assert session.get_one(Job, job.id).status == JobStatus.running
    engine.dispose()


def test_a_worker_passes_on_what_it_cannot_run(idle_queue: JobQueue) -> None:
    """A worker without the teacher's weights takes no teacher job: with an able worker alive
    the id goes back on the lane for it; with none the job fails at once with the reason, and
    /health's figures name the kind no worker can run."""
    queue = idle_queue
    queue.unable = {"teacher": "The teacher cannot run: its weights are missing."}
    lacking = Worker(id="here:1:a", hostname="here", pid=1, threads=1, started_at=utcnow())
    lacking.lanes, lacking.unable = "quick,model", dict(queue.unable)
    able = Worker(id="there:2:b", hostname="there", pid=2, threads=1, started_at=utcnow())
    able.lanes, able.unable = "model", {}
    assert runner.unserved_kinds([lacking], [("teacher", "model"), ("export", "quick")]) == {
        "teacher": "The teacher cannot run: its weights are missing."
    }
    assert runner.unserved_kinds([able], [("teacher", "model"), ("export", "quick")]) == {
        "export": "no live worker serves the quick lane"
    }
    with queue.session_factory() as session:
        passed, failed = (create_job(session, queue, "teacher", {}, None) for _ in range(2))
    queue.huey("model").flush()
    runner.record_heartbeat(queue.session_factory, able)
    assert pass_on(queue, passed.id) is True
    assert queue.carried("model") == {passed.id}  # back on the lane (after a delay), for it
    assert pass_on(queue, passed.id + 1000) is False  # no such queued job: nothing to pass on
    queue.unable = {}
    assert pass_on(queue, passed.id) is False  # a worker that can run it runs it
    queue.unable = dict(lacking.unable or {})
    with queue.session_factory() as session:
        session.execute(sa.delete(Worker))
        session.commit()
    assert pass_on(queue, failed.id) is True
    with queue.session_factory() as session:
        row = session.get_one(Job, failed.id)
        assert (row.status, row.attempts) == (JobStatus.failed, 0)
        assert row.error == "The teacher cannot run: its weights are missing."
        assert session.get_one(Job, passed.id).status == JobStatus.queued


def test_a_worker_whose_store_is_not_the_webs_takes_no_job(
    client: TestClient, make_user, settings, database_url: str, tmp_path
) -> None:
    """A worker on another machine without the web process's store (here: a home of its own
    over the same database) can run no kind once frames are stored; the web's own store can."""
    from app.jobs.queue import find_unable
    from app.system.status import unable_kinds
    from tests.helpers import image_bytes

    kinds = [("teacher", "model"), ("export", "quick")]
    elsewhere = make_settings(tmp_path / "elsewhere", database_url=database_url)
    queue = client.app.state.queue  # type: ignore[attr-defined]
    assert "export" not in unable_kinds(elsewhere, kinds, queue.session_factory)  # no telling
    _, token = make_user("admin", Role.admin)
    files = [("files", ("w.png", image_bytes(32, 24, seed=3), "image/png"))]
    assert client.post("/api/v1/frames", files=files, headers=auth(token)).status_code == 201
    unable = unable_kinds(elsewhere, kinds, queue.session_factory)
    assert set(unable) == {"teacher", "export"}
    assert unable["export"].startswith("This worker's file store (this machine's WELDPOOL_HOME)")
    assert "export" not in unable_kinds(settings, kinds, queue.session_factory)
    other = JobQueue(elsewhere, queue.session_factory)
    assert "export" in find_unable(other, ("quick",), standalone=True)
    assert "export" not in find_unable(other, ("quick",))  # the embedded worker: the web's store


def test_a_queued_job_says_what_it_waits_behind(session_factory) -> None:
    """The Jobs page's words for a queued job: the running job of its own lane with the time
    its pace leaves, and the queued jobs that go first (a person's before automatic work);
    a quick job is next whatever the model lane does."""
    from app.jobs.service import waiting_for

    with session_factory() as session:
        started = utcnow() - dt.timedelta(seconds=240)
        training = Job(kind="train_student", status=JobStatus.running, progress=0.5)
        training.started_at = started
        automatic = Job(kind="teacher", priority=0)
        person = Job(kind="teacher", priority=1)
        export = Job(kind="export")
        session.add_all([training, automatic, person, export])
        session.commit()
        words = waiting_for(session, [automatic, person, export])
    assert words == {
        person.id: f"queued in the model lane behind train_student #{training.id} "
        "(about 4 min left)",
        automatic.id: f"queued in the model lane behind train_student #{training.id} "
        "(about 4 min left) and 1 queued job",
        export.id: "queued in the quick lane: next",
    }


fan_log: list[tuple[str, int]] = []


@job_handler("fan-test", fanout=True)
def _fan(ctx: JobContext) -> dict:
    fan = Fanout(ctx, 2)
    if not ctx.helper:
        fan.plan(lambda: list(range(int(ctx.params["n"]))))
        fan.invite()
    for index in fan.chunks():
        with fan.working(index) as result:
            for item in fan.items(index):
                time.sleep(0.05)
                fan_log.append((ctx.worker_id, item))
            result["items"] = list(fan.items(index))
        ctx.progress(fan.progress(), fan.message())
    if ctx.helper:
        return {}
    return {"items": sorted(i for r in fan.results() for i in r["items"]), "workers": fan.workers()}


def _presence(queue: JobQueue) -> Worker:
    host, pid, _ = queue.worker_id.split(":")
    row = Worker(id=queue.worker_id, hostname="far-" + host, pid=int(pid), threads=1)
    row.started_at, row.lanes, row.unable = utcnow(), "quick,model", {}
    runner.record_heartbeat(queue.session_factory, row)
    return row


def test_one_run_is_shared_by_two_workers_each_item_once(idle_queue: JobQueue) -> None:
    """A fan-out job's owner invites the other live worker (its id goes on the lane again);
    that worker joins and takes free chunks; every item is worked once, by both workers, and
    the owner alone writes one progress and one result — and takes over a chunk whose worker
    is gone."""
    fan_log.clear()
    owner, other = idle_queue, JobQueue(idle_queue.settings, idle_queue.session_factory)
    _presence(owner), _presence(other)
    with owner.session_factory() as session:
        job = create_job(session, owner, "fan-test", {"n": 20}, None)
        # a worker that is gone planned it and held chunk 3 (a retried job keeps its plan)
        for chunk in range(10):
            held = "gone:1:dead" if chunk == 3 else None
            session.add(
                JobChunk(
                    job_id=job.id, chunk=chunk, items=[2 * chunk, 2 * chunk + 1], worker_id=held
                )
            )
        session.commit()
    huey = owner.huey("model")
    first = huey.dequeue()
    owning = threading.Thread(target=huey.execute, args=(first,))
    owning.start()
    helping = other.huey("model")  # the same lane, read by the other worker
    invited = wait_for(lambda: helping.dequeue(), timeout=20)  # the owner's invitation
    helping.execute(invited)  # the other worker joins and helps
    owning.join(timeout=60)
    with owner.session_factory() as session:
        done = session.get_one(Job, job.id)
        assert done.status == JobStatus.succeeded, done.error
        assert done.result["items"] == list(range(20))
        assert sorted(done.result["workers"]) == sorted([owner.worker_id, other.worker_id])
    items = [item for _, item in fan_log]
    assert sorted(items) == list(range(20))  # each once
    assert {worker for worker, _ in fan_log} == {owner.worker_id, other.worker_id}
    assert (owner.worker_id, 6) in fan_log and (owner.worker_id, 7) in fan_log  # taken over


@job_handler("store-blip")
def _store_blip(ctx: JobContext) -> dict:
    from botocore.exceptions import EndpointConnectionError

    if ctx.params.get("broken") == "store":
        raise EndpointConnectionError(endpoint_url="http://127.0.0.1:9/bucket")
    raise ValueError("the work itself is wrong")


class _Later:
    def __init__(self) -> None:
        self.later: list[tuple[int, float]] = []

    def enqueue_later(self, job_id: int, kind: str, priority: int, delay_s: float) -> None:
        self.later.append((job_id, delay_s))


def test_a_store_that_does_not_answer_pauses_the_job_it_never_fails_it_at_once(
    session_factory, settings
) -> None:
    """An outage of the store or the network (not the work) queues the job again after a pause,
    saying so, until its retries are spent; an error of the work still fails it at once."""
    from app.core.errors import store_outage
    from app.jobs.runner import PAUSE_S, STORE_RETRIES, execute_job

    queue = _Later()
    with session_factory() as session:
        blip = Job(kind="store-blip", params={"broken": "store"})
        wrong = Job(kind="store-blip", params={})
        session.add_all([blip, wrong])
        session.commit()
    execute_job(blip.id, settings, session_factory, "w:1:a", queue=queue)
    with session_factory() as session:
        row = session.get_one(Job, blip.id)
        assert (row.status, row.attempts, row.error) == (JobStatus.queued, 1, None)
        assert row.message.startswith("paused: The object store failed (EndpointConnectionError)")
        assert row.message.endswith(f"It runs again in {PAUSE_S:g} s.")
        assert "127.0.0.1:9" not in row.message  # no store address in what users read
    assert queue.later == [(blip.id, PAUSE_S)]
    for _ in range(STORE_RETRIES):
        execute_job(blip.id, settings, session_factory, "w:1:a", queue=queue)
    with session_factory() as session:
        row = session.get_one(Job, blip.id)
        assert (row.status, row.attempts) == (JobStatus.failed, 1 + STORE_RETRIES)
        assert row.error.startswith("The object store failed (EndpointConnectionError)")
    execute_job(wrong.id, settings, session_factory, "w:1:a", queue=queue)
    with session_factory() as session:
        row = session.get_one(Job, wrong.id)
        assert row.status == JobStatus.failed and "the work itself is wrong" in row.error
    assert not store_outage(ValueError("x")) and store_outage(ConnectionResetError())
