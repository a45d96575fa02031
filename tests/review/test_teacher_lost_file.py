"""A teacher run over a frame whose image file is lost: the other frames get their proposals,
and the lost one's failure says which file and what restores it."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.models import Frame, Role
from tests.helpers import auth, image_bytes, wait_for_job


def test_a_teacher_run_names_the_frame_whose_image_is_lost_and_does_the_others(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("teacher", Role.annotator)
    files = [
        ("files", (f"t{i}.png", image_bytes(64, 48, seed=60 + i), "image/png")) for i in (0, 1)
    ]
    stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    lost, kept = (f["id"] for f in stored)
    with session_factory() as session:
        path = session.get_one(Frame, lost).path
    (settings.home / path).unlink()
    started = client.post(
        "/api/v1/teacher/runs", json={"frame_ids": [lost, kept]}, headers=auth(token)
    )
    job = wait_for_job(client, started.json()["job_id"], token, timeout=120)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["proposed"] == 1
    (failed,) = job["result"]["failed"]
    assert failed["frame_id"] == lost
    assert failed["error"] == (
        f"Frame {lost}'s image ({path}) is missing from the store; upload the same image again "
        "(into any run) to restore it, or delete the frame."
    )
