"""Automatic retraining, promotion of a new model only on merit, and the metrics figures."""

from __future__ import annotations

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Job, JobStatus, Role
from app.main import create_app
from tests.factories import frame_ids, numbered, random_images, run_teacher, upload_synthetic
from tests.helpers import auth, corrected_label


def test_retraining_starts_once_per_threshold_and_never_twice(
    settings, session_factory, make_user
) -> None:
    _, token = make_user("trainer", Role.reviewer)
    every_two = settings.model_copy(update={"retrain_every": 2})
    with TestClient(create_app(every_two)) as client:  # no worker: jobs stay queued
        ids = frame_ids(
            client, token, random_images(numbered(5, first_seed=200), width=32, height=24)
        )
        mask = np.zeros((24, 32), bool)
        mask[4:20, 6:26] = True
        body = corrected_label(mask)

        def trainings() -> list[Job]:
            with session_factory() as session:
                return list(session.scalars(sa.select(Job).where(Job.kind == "train_student")))

        client.put(f"/api/v1/frames/{ids[0]}/label", json=body, headers=auth(token))
        assert trainings() == []
        client.put(f"/api/v1/frames/{ids[1]}/label", json=body, headers=auth(token))
        assert len(trainings()) == 1 and trainings()[0].params == {"automatic": True}
        for frame_id in ids[2:]:  # two more labels while the first job is still queued
            client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert len(trainings()) == 1  # never a second one at the same time
        manual = client.post("/api/v1/student/train", json={}, headers=auth(token))
        assert manual.status_code == 409 and "already queued or running" in manual.json()["detail"]
        with session_factory() as session:
            job = session.get_one(Job, trainings()[0].id)
            job.status = JobStatus.failed
            session.commit()
        again = client.put(
            f"/api/v1/frames/{ids[2]}/label", json=body | {"base_revision": 1}, headers=auth(token)
        )
        assert again.status_code == 200
        assert len(trainings()) == 2  # 3 new labels since the last job: a new one starts


def test_metrics_figures(client: TestClient, make_user) -> None:
    _, token = make_user("metrics", Role.reviewer)
    ids = upload_synthetic(client, token, 2)
    assert run_teacher(client, token, ids)["status"] == "succeeded"
    client.put(
        f"/api/v1/frames/{ids[0]}/label",
        json={"status": "accepted", "base_revision": 0},
        headers=auth(token),
    )
    mask = np.zeros((100, 160), bool)
    mask[10:90, 10:150] = True
    client.put(
        f"/api/v1/frames/{ids[1]}/label",
        headers=auth(token),
        json=corrected_label(mask),
    )
    figures = client.get("/api/v1/metrics", headers=auth(token)).json()
    assert figures["review"]["labels"] == {"accepted": 1, "corrected": 1, "rejected": 0}
    assert figures["review"]["teacher_acceptance_rate"] == 0.5
    # The label accepted unchanged *is* the teacher's mask (IoU 1 by construction): the fair
    # figure leaves it out, as the training gate does; `including_unchanged` keeps it.
    teacher, everything = figures["teacher"]["overall"], figures["teacher"]["including_unchanged"]
    assert teacher["frames"] == 1 and figures["teacher"]["left_out"] == 1
    assert everything["frames"] == 2
    assert 0 <= teacher["mIoU"] < 1.0
    assert everything["mIoU"] == pytest.approx((teacher["mIoU"] + 1.0) / 2)
    assert [s["frames"] for s in figures["teacher"]["by_sequence"]] == [1]
    assert figures["student"] == [] and figures["queue"]["scored_frames"] == 2
    assert figures["review"]["over_time"][0]["accepted"] == 1


def test_an_untrained_new_model_is_not_promoted(
    client: TestClient, settings, session_factory, make_user
):
    """One epoch on three frames: the gate measures it on the held-out frame and refuses it
    (tests/training/test_gate.py covers each rule of the gate). A model folder left by
    a crash does not block the new version's name."""
    from app.core.models import ModelVersion
    from tests.helpers import wait_for_job

    _, token = make_user("promoter", Role.reviewer)
    with session_factory() as session:
        session.add(
            ModelVersion(name="student-v0", metrics={"mED": 0.01, "mIoU": 0.999}, is_promoted=True)
        )
        session.commit()
    ids = frame_ids(client, token, random_images(numbered(3, first_seed=200), width=32, height=24))
    mask = np.zeros((24, 32), bool)
    mask[4:20, 6:26] = True
    for frame_id in ids:
        client.put(
            f"/api/v1/frames/{frame_id}/label",
            headers=auth(token),
            json=corrected_label(mask),
        )
    leftover = settings.home / "models" / "student-v2"  # the name the new version would take
    leftover.mkdir(parents=True)
    (leftover / "model.safetensors").write_bytes(b"left by a crash")
    job_id = client.post(
        "/api/v1/student/train", json={"epochs": 1, "size": "light"}, headers=auth(token)
    ).json()["job_id"]
    job = wait_for_job(client, job_id, token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["promoted"] is False and job["result"]["name"] == "student-v3"
    assert job["result"]["gate"]["usable"] is False, job["result"]["gate"]
    assert "below the minimum quality" in job["result"]["gate"]["reason"]
    models = {m["name"]: m for m in client.get("/api/v1/models", headers=auth(token)).json()}
    assert models["student-v0"]["is_promoted"] and not models[job["result"]["name"]]["is_promoted"]
    new = models[job["result"]["name"]]
    assert new["train_label_count"] == 2 and len(new["gate"]["frames"]) == 1
    assert new["gate"]["frames"][0] in ids
    assert (
        client.get("/api/v1/jobs", params={"kind": "student"}, headers=auth(token)).json()["total"]
        == 0
    )  # no re-scoring by a loser
