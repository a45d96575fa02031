"""Two runs of the same teacher over the same frames, at once: each frame is proposed once
(``app.proposals.record.claim``), and a claim left by a run that stopped is taken over."""

from __future__ import annotations

import threading

import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Job, JobStatus, Proposal, ProposalClaim, Role
from app.jobs.runner import execute_job, new_worker_id
from app.main import create_app
from app.proposals.record import claim, release
from tests.helpers import auth, image_bytes


def _jobs(session_factory, *params: dict) -> list[int]:
    with session_factory() as session:
        jobs = [Job(kind="teacher", params=p, max_attempts=2) for p in params]
        session.add_all(jobs)
        session.commit()
        return [job.id for job in jobs]


def test_two_runs_at_once_propose_each_frame_once(settings, session_factory, make_user) -> None:
    _, token = make_user("lead", Role.reviewer)
    files = [
        ("files", (f"o{i}.png", image_bytes(64, 48, seed=80 + i), "image/png")) for i in range(6)
    ]
    with TestClient(create_app(settings, embedded_worker=False)) as client:
        stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    ids = [f["id"] for f in stored]
    first, second = _jobs(session_factory, {"frame_ids": ids}, {"frame_ids": ids[::-1][:4]})
    workers = [
        threading.Thread(target=execute_job, args=(job, settings, session_factory, new_worker_id()))
        for job in (first, second)
    ]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=300)
    with session_factory() as session:
        per_frame = dict(
            session.execute(
                sa.select(Proposal.frame_id, sa.func.count()).group_by(Proposal.frame_id)
            ).all()
        )
        done = {job.id: job for job in session.scalars(sa.select(Job))}
        assert session.scalar(sa.select(sa.func.count()).select_from(ProposalClaim)) == 0
    assert per_frame == {frame_id: 1 for frame_id in ids}
    assert all(job.status == JobStatus.succeeded for job in done.values())
    proposed = [done[job].result["proposed"] for job in (first, second)]
    assert sum(proposed) == 6  # of 10 frames asked for, 6 are distinct: each proposed once


def test_a_claim_is_held_by_a_running_run_and_taken_from_a_stopped_one(
    settings, session_factory, make_user
) -> None:
    _, token = make_user("lead", Role.reviewer)
    files = [("files", ("c.png", image_bytes(64, 48, seed=90), "image/png"))]
    with TestClient(create_app(settings, embedded_worker=False)) as client:
        (frame,) = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    running, other = _jobs(session_factory, {}, {})
    with session_factory() as session:
        session.execute(sa.update(Job).where(Job.id == running).values(status=JobStatus.running))
        session.commit()
    assert claim(session_factory, frame["id"], "t", running)
    assert claim(session_factory, frame["id"], "t", running)  # its own, again (a retry)
    assert not claim(session_factory, frame["id"], "t", other)  # held by a running run
    assert claim(session_factory, frame["id"], "u", other)  # another model: another claim
    with session_factory() as session:
        session.execute(sa.update(Job).where(Job.id == running).values(status=JobStatus.failed))
        session.commit()
    assert claim(session_factory, frame["id"], "t", other)  # the stopped run's, taken over
    with session_factory() as session:
        session.execute(sa.update(Job).where(Job.id == other).values(status=JobStatus.running))
        session.commit()
    release(session_factory, frame["id"], "t", running)  # not its claim any more: kept
    assert not claim(session_factory, frame["id"], "t", running)
    release(session_factory, frame["id"], "t", other)
    assert claim(session_factory, frame["id"], "t", running)
