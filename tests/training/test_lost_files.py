"""Training when the store lost a labelled frame's image or mask: the student trains on the
rest and the job names the frame it left out; with nothing left, the job says so."""

from __future__ import annotations

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Frame, Label, ModelVersion, Role
from tests.factories import frame_ids, numbered, random_images
from tests.helpers import auth, corrected_label, wait_for_job


def _labelled(client: TestClient, token: str, count: int) -> list[int]:
    images = random_images(numbered(count, first_seed=50, name="l{i}.png"), width=160, height=100)
    ids = frame_ids(client, token, images)
    for i, frame_id in enumerate(ids):
        mask = np.zeros((100, 160), bool)
        mask[30:70, 20 + 5 * i : 120] = True
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
    return ids


def _lose_image(settings, session_factory, frame_id: int) -> str:
    with session_factory() as session:
        path = session.get_one(Frame, frame_id).path
    (settings.home / path).unlink()
    return path


def test_training_with_every_labelled_file_lost_fails_in_one_sentence(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("trainer", Role.reviewer)
    first, second = _labelled(client, token, 2)
    path = _lose_image(settings, session_factory, first)
    with session_factory() as session:
        mask = session.scalar(sa.select(Label.mask_path).where(Label.frame_id == second))
    (settings.home / mask).unlink()
    started = client.post("/api/v1/student/train", json={"epochs": 1}, headers=auth(token))
    job = wait_for_job(client, started.json()["job_id"], token)
    assert job["status"] == "failed"
    assert job["error"].startswith(
        "Every labelled frame to train on has lost files (2 frames), so nothing was trained; "
        f"the first: Frame {first}'s image ({path}) is missing from the store;"
    )
    assert "Unexpected error" not in job["error"]


def test_a_frame_whose_image_is_lost_is_left_out_and_named_by_the_training(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("trainer", Role.reviewer)
    ids = _labelled(client, token, 4)
    path = _lose_image(settings, session_factory, ids[0])
    started = client.post(
        "/api/v1/student/train", json={"epochs": 1, "size": "light"}, headers=auth(token)
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=300)
    assert job["status"] == "succeeded", job["error"]
    (skipped,) = job["result"]["skipped_frames"]
    assert skipped["frame_id"] == ids[0] and path in skipped["reason"]
    assert "upload the same image again" in skipped["reason"]
    assert job["message"].endswith("; 1 frame left out, their files are lost")
    with session_factory() as session:
        version = session.get_one(ModelVersion, job["result"]["model_version_id"])
        assert sorted(version.train_frame_ids + version.held_out_frame_ids) == ids[1:]
