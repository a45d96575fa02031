"""A teacher run over a frame whose image file is lost: the other frames get their proposals,
and the lost one's failure says which file and what restores it."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.core.models import Frame, Role
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


def test_a_store_outage_pauses_the_teacher_run_and_fails_no_frame(
    client: TestClient, settings, session_factory, make_user, monkeypatch
) -> None:
    """The store not answering while the teacher reads a frame is not the frame's failure: no
    frame is marked "teacher failed", and the run pauses to run again (it 'succeeded' with the
    frames reached meanwhile marked failed)."""
    from botocore.exceptions import EndpointConnectionError

    import app.teacher.tasks as tasks
    from tests.helpers import wait_for

    _, token = make_user("teacher", Role.annotator)
    files = [("files", ("o.png", image_bytes(64, 48, seed=70), "image/png"))]
    (frame,) = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]

    def unreachable(storage, row):  # type: ignore[no-untyped-def]
        raise EndpointConnectionError(endpoint_url="http://127.0.0.1:9/bucket")

    monkeypatch.setattr(tasks, "frame_rgb", unreachable)
    started = client.post(
        "/api/v1/teacher/runs", json={"frame_ids": [frame["id"]]}, headers=auth(token)
    )
    job_id = started.json()["job_id"]

    def paused() -> dict | None:
        job = client.get(f"/api/v1/jobs/{job_id}", headers=auth(token)).json()
        return job if job["message"].startswith("paused:") else None

    job = wait_for(paused, timeout=120)
    assert job["status"] == "queued" and job["error"] is None
    with session_factory() as session:
        assert session.get_one(Frame, frame["id"]).teacher_error is None
