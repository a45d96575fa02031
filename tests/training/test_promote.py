"""`POST /models/{id}/promote`: what a promotion queues, and what its errors say."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import utcnow
from app.core.models import Job, JobStatus, ModelVersion, Role
from app.frames.listing import scope_frames
from app.jobs.runner import new_worker_id
from app.main import create_app
from tests.helpers import auth, corrected_label, image_bytes


@pytest.fixture
def idle_client(settings: Settings, session_factory) -> Iterator[TestClient]:
    """The app with no worker: queued jobs stay queued."""
    with TestClient(create_app(settings, embedded_worker=False)) as test_client:
        yield test_client


def _versions(session_factory, *names: str, **fields) -> list[int]:
    with session_factory() as session:
        rows = [ModelVersion(name=name, **fields) for name in names]
        session.add_all(rows)
        session.commit()
        return [row.id for row in rows]


def _student_jobs(session_factory) -> list[tuple[str, dict]]:
    with session_factory() as session:
        jobs = session.scalars(sa.select(Job).where(Job.kind == "student").order_by(Job.id))
        return [(job.status.value, dict(job.params)) for job in jobs]


def test_promotions_queue_one_pending_student_run(
    idle_client: TestClient, make_user, session_factory
) -> None:
    """Sixteen promotions while no worker is free queue one run (the newest version's), not
    sixteen; a run a user asked for is left alone, and one already running is not changed."""
    _, token = make_user("promoter", Role.reviewer)
    files = [("files", (f"{i}.png", image_bytes(32, 24, seed=i), "image/png")) for i in range(2)]
    frames = [
        f["id"]
        for f in idle_client.post("/api/v1/frames", files=files, headers=auth(token)).json()[
            "stored"
        ]
    ]
    versions = _versions(session_factory, *(f"student-v{i}" for i in range(1, 17)))

    def promote(version: int) -> None:
        answer = idle_client.post(
            f"/api/v1/models/{version}/promote", params={"force": True}, headers=auth(token)
        )
        assert answer.status_code == 200 and answer.json()["is_promoted"], answer.text

    promote(versions[0])
    asked = idle_client.post(
        "/api/v1/student/runs", json={"frame_ids": frames[:1]}, headers=auth(token)
    )
    assert asked.status_code == 202, asked.text
    for version in versions[1:]:
        promote(version)
    jobs = _student_jobs(session_factory)
    assert [(status, params["model_version_id"]) for status, params in jobs] == [
        ("queued", versions[-1]),  # the first promotion's run, handed on to the newest version
        ("queued", versions[0]),  # the user's own run
    ]
    # each run's scope as a scope: the frames still to review when it starts, or the frames
    # the user listed, kept beside the job; no parameters list frame ids
    assert all("frame_ids" not in params for _, params in jobs)
    assert (jobs[0][1]["scope"], jobs[0][1]["frames"]) == ("unreviewed", 2)
    assert (jobs[1][1]["listed"], jobs[1][1]["frames"]) == (True, 1)
    with session_factory() as session:
        ids = [job.id for job in session.scalars(sa.select(Job).where(Job.kind == "student"))]
        assert scope_frames(session, ids[0], jobs[0][1]) == frames
        assert scope_frames(session, ids[1], jobs[1][1]) == frames[:1]

    with session_factory() as session:  # a live worker (this process) claims the runs
        claimed = {"status": JobStatus.running, "worker_id": new_worker_id()}
        session.execute(
            sa.update(Job).where(Job.kind == "student").values(**claimed, heartbeat_at=utcnow())
        )
        session.commit()
    promote(versions[3])
    jobs = _student_jobs(session_factory)
    assert [(s, p["model_version_id"]) for s, p in jobs][-1] == ("queued", versions[3])
    assert len(jobs) == 3


def test_a_promotion_that_cannot_read_the_weights_names_no_server_path(
    client: TestClient, make_user, session_factory, settings: Settings
) -> None:
    """A version whose folder lost its files: the 400 names the version and its folder relative
    to the home, never the home's absolute path."""
    _, token = make_user("promoter", Role.reviewer)
    files = [("files", ("held.png", image_bytes(32, 24, seed=5), "image/png"))]
    (frame,) = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    mask = np.zeros((24, 32), bool)
    mask[8:16, 8:24] = True
    labelled = client.put(
        f"/api/v1/frames/{frame['id']}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert labelled.status_code == 200, labelled.text
    (Path(settings.home) / "models" / "student-v9").mkdir(parents=True)  # no config.json
    (version,) = _versions(
        session_factory,
        "student-v9",
        checkpoint_path="models/student-v9",
        held_out_frame_ids=[frame["id"]],
    )
    answer = client.post(f"/api/v1/models/{version}/promote", headers=auth(token))
    assert answer.status_code == 400, answer.text
    detail = answer.json()["detail"]
    assert str(Path(settings.home).resolve()) not in detail and "/tmp" not in detail, detail
    assert detail.startswith("student-v9 cannot be measured: models/student-v9 ")
    assert "config.json is missing" in detail


def test_promoting_the_promoted_version_again_queues_no_second_run(
    idle_client: TestClient, make_user, session_factory
) -> None:
    """While the promoted version's run is running, promoting that version again queues
    nothing beside it (it ran a second full student run); another version's promotion does."""
    _, token = make_user("promoter", Role.reviewer)
    files = [("files", ("a.png", image_bytes(32, 24, seed=1), "image/png"))]
    assert idle_client.post("/api/v1/frames", files=files, headers=auth(token)).status_code == 201
    first, second = _versions(session_factory, "student-a", "student-b")

    def promote(version: int) -> None:
        answer = idle_client.post(
            f"/api/v1/models/{version}/promote", params={"force": True}, headers=auth(token)
        )
        assert answer.status_code == 200, answer.text

    promote(first)
    with session_factory() as session:  # a live worker (this process) runs it
        claimed = {"status": JobStatus.running, "worker_id": new_worker_id()}
        session.execute(
            sa.update(Job).where(Job.kind == "student").values(**claimed, heartbeat_at=utcnow())
        )
        session.commit()
    promote(first)
    assert [(s, p["model_version_id"]) for s, p in _student_jobs(session_factory)] == [
        ("running", first)
    ]
    promote(second)
    assert [(s, p["model_version_id"]) for s, p in _student_jobs(session_factory)] == [
        ("running", first),
        ("queued", second),
    ]
