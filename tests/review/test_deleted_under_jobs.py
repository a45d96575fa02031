"""Jobs over data deleted under them end cleanly: the teacher and propagation skip frames
deleted while they ran (succeeded, the skips named), training whose every labelled frame went
fails with one sentence; none records anything half-made or leaves a file of its own."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import STORED_PATH_COLUMNS, ModelVersion, Proposal, Role
from tests.factories import frame_ids
from tests.helpers import age_stored_files, auth, corrected_label, wait_for_job
from weldpool_core.synth import SynthParams, synth_frame

SIZE = SynthParams(width=96, height=64)


def _run(client: TestClient, token: str, count: int) -> tuple[int, list[int], list]:
    sequence = client.post("/api/v1/sequences", json={"name": "Run"}, headers=auth(token)).json()
    frames = [synth_frame(seed=700 + i, params=SIZE) for i in range(count)]
    files = [
        (f"f{i:03d}.png", cv2.imencode(".png", f.image)[1].tobytes()) for i, f in enumerate(frames)
    ]
    ids = frame_ids(client, token, files, sequence_id=sequence["id"])
    return sequence["id"], ids, frames


def _delete(client: TestClient, token: str, frame_ids: list[int]) -> None:
    answer = client.post(
        "/api/v1/frames/delete", json={"frame_ids": frame_ids, "force": True}, headers=auth(token)
    )
    assert answer.status_code == 200, answer.text


def _unnamed_files(settings, session_factory) -> list[str]:  # type: ignore[no-untyped-def]
    """Stored files no row names (what the job would have left behind)."""
    with session_factory() as session:
        named = {p for c in STORED_PATH_COLUMNS for p in session.scalars(sa.select(c)) if p}
    return sorted(
        p.relative_to(settings.home).as_posix()
        for area in ("frames", "artefacts")
        for p in (settings.home / area).rglob("*")
        if p.is_file() and p.relative_to(settings.home).as_posix() not in named
    )


def test_a_frame_deleted_while_the_teacher_runs_is_skipped(
    client: TestClient, make_user, settings, session_factory, monkeypatch
) -> None:
    from weldpool_core.teacher.teacher import Teacher

    _, token = make_user("rev", Role.reviewer)
    _, ids, _ = _run(client, token, 3)
    age_stored_files(settings.home, settings.file_grace_s + 1)  # uploaded a while ago
    real_run = Teacher.run

    def run_then_delete(self, image, *args, **kwargs):  # type: ignore[no-untyped-def]
        result = real_run(self, image, *args, **kwargs)
        if not hasattr(run_then_delete, "done"):
            run_then_delete.done = True  # type: ignore[attr-defined]
            _delete(client, token, [ids[0]])  # deleted while the teacher looked at it
        return result

    monkeypatch.setattr(Teacher, "run", run_then_delete)
    started = client.post("/api/v1/teacher/runs", json={"frame_ids": ids}, headers=auth(token))
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["deleted_frame_ids"] == [ids[0]] and job["result"]["proposed"] == 2
    assert job["result"]["failed"] == []
    assert "1 skipped (deleted while the teacher ran)" in job["message"]
    with session_factory() as session:
        assert sorted(session.scalars(sa.select(Proposal.frame_id))) == ids[1:]
    assert _unnamed_files(settings, session_factory) == []


def test_a_frame_deleted_while_propagating_is_skipped(
    client: TestClient, make_user, settings, session_factory, monkeypatch
) -> None:
    from app.review import propagation

    _, token = make_user("rev", Role.reviewer)
    sequence_id, ids, frames = _run(client, token, 5)
    saved = client.put(
        f"/api/v1/frames/{ids[0]}/label", json=corrected_label(frames[0].mask), headers=auth(token)
    )
    assert saved.status_code == 200
    age_stored_files(settings.home, settings.file_grace_s + 1)
    real_record = propagation.record

    def delete_then_record(session, storage, frame, *args, **kwargs):  # type: ignore[no-untyped-def]
        if frame.id == ids[2]:
            _delete(client, token, [ids[2]])  # its mask is computed; the frame goes now
        return real_record(session, storage, frame, *args, **kwargs)

    monkeypatch.setattr(propagation, "record", delete_then_record)
    started = client.post(
        f"/api/v1/sequences/{sequence_id}/propagate",
        json={"from_frame_ids": [ids[0]], "direction": "forward", "threshold": 0.0},
        headers=auth(token),
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["deleted_frame_ids"] == [ids[2]]
    assert job["result"]["proposed"] == 3, job["result"]
    assert "1 frame skipped (deleted meanwhile)" in job["message"]
    with session_factory() as session:
        frames_with = sorted(
            session.scalars(sa.select(Proposal.frame_id).where(Proposal.source == "propagated"))
        )
    assert frames_with == [ids[1], ids[3], ids[4]]
    assert _unnamed_files(settings, session_factory) == []


def test_training_whose_labelled_frames_are_deleted_records_no_version(
    client: TestClient, make_user, settings, session_factory, monkeypatch
) -> None:
    import app.training.tasks as training_tasks
    from weldpool_core.student import train

    _, token = make_user("rev", Role.reviewer)
    sequence_id, ids, _ = _run(client, token, 3)
    mask = np.zeros((64, 96), bool)
    mask[20:44, 30:70] = True
    for frame_id in ids:
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200
    real_train = train.train_student

    def delete_then_train(*args, **kwargs):  # type: ignore[no-untyped-def]
        deleted = client.delete(
            f"/api/v1/sequences/{sequence_id}", params={"force": "true"}, headers=auth(token)
        )
        assert deleted.status_code == 200, deleted.text
        return real_train(*args, **kwargs)

    monkeypatch.setattr(train, "train_student", delete_then_train)
    started = client.post(
        "/api/v1/student/train", json={"epochs": 1, "size": "light"}, headers=auth(token)
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert training_tasks is not None
    assert job["status"] == "failed"
    assert job["error"] == (
        "Every labelled frame it trained on was deleted during training; no version was recorded."
    )
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(ModelVersion)) == 0
    models = settings.home / "models"
    assert not models.exists() or not [p for p in models.iterdir() if p.is_dir()]


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_write_that_loses_to_a_deletion_discards_its_files(
    client: TestClient, make_user, settings, session_factory, monkeypatch
) -> None:
    """SQLite locks no row: a deletion can commit between the teacher's look at its frame and
    its insert. The insert then fails, the proposal's files (written just before) are removed
    and the frame counts as deleted. (On PostgreSQL the frame's row is locked, so the deletion
    waits for the commit instead.)"""
    from app.proposals import files as review_service

    _, token = make_user("rev", Role.reviewer)
    _, ids, _ = _run(client, token, 2)
    age_stored_files(settings.home, settings.file_grace_s + 1)
    real_heatmap = review_service.FrameWrite.heatmap

    def heatmap_then_delete(self, heatmap):  # type: ignore[no-untyped-def]
        path = real_heatmap(self, heatmap)
        if not hasattr(heatmap_then_delete, "done"):
            heatmap_then_delete.done = True  # type: ignore[attr-defined]
            _delete(client, token, [ids[0]])
        return path

    monkeypatch.setattr(review_service.FrameWrite, "heatmap", heatmap_then_delete)
    started = client.post("/api/v1/teacher/runs", json={"frame_ids": ids}, headers=auth(token))
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["deleted_frame_ids"] == [ids[0]] and job["result"]["proposed"] == 1
    assert _unnamed_files(settings, session_factory) == []


def test_a_frame_whose_file_goes_before_the_teacher_reads_it_is_skipped(
    client: TestClient, make_user, settings, session_factory, monkeypatch
) -> None:
    """The frame is deleted (and its old file collected) just before the teacher reads it:
    the read fails, the frame counts as deleted, the job goes on."""
    import app.teacher.tasks as review_tasks

    _, token = make_user("rev", Role.reviewer)
    _, ids, _ = _run(client, token, 2)
    age_stored_files(settings.home, settings.file_grace_s + 1)
    real_read = review_tasks.frame_rgb

    def delete_then_read(storage, frame):  # type: ignore[no-untyped-def]
        if frame.id == ids[0]:
            _delete(client, token, [ids[0]])
        return real_read(storage, frame)

    monkeypatch.setattr(review_tasks, "frame_rgb", delete_then_read)
    started = client.post("/api/v1/teacher/runs", json={"frame_ids": ids}, headers=auth(token))
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["deleted_frame_ids"] == [ids[0]] and job["result"]["failed"] == []
