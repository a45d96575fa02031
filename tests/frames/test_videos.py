"""Video upload: stored, checked, and every n-th frame extracted by a worker job."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Role
from tests.helpers import SHARED_DATA, auth, image_bytes, run_cli, wait_for_job


def synthetic_avi(path: Path, frames: int = 30, fps: float = 10.0) -> Path:
    """A small MJPG AVI whose frames differ (a bright disc moving across a dark field)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    assert writer.isOpened()
    for index in range(frames):
        frame = np.full((48, 64, 3), 30, np.uint8)
        cv2.circle(frame, (8 + index, 24), 6, (200, 120, 40), -1)
        writer.write(frame)
    writer.release()
    return path


@pytest.fixture
def token(make_user) -> str:
    return make_user("filmmaker", Role.annotator)[1]


def _upload(client: TestClient, token: str, path: Path, **data: str):
    with open(path, "rb") as handle:
        return client.post(
            "/api/v1/videos",
            files={"file": (path.name, handle, "video/avi")},
            data=data,
            headers=auth(token),
        )


def test_avi_every_nth_frame_into_a_new_sequence(client: TestClient, token: str, tmp_path):
    video = synthetic_avi(tmp_path / "weld run 7.avi", frames=30, fps=10.0)
    response = _upload(client, token, video, every_nth="3")
    assert response.status_code == 202, response.text
    body = response.json()
    assert body["video"] == body["video"] | {
        "container": "avi",
        "width": 64,
        "height": 48,
        "fps": 10.0,
        "every_nth": 3,
    }
    job = wait_for_job(client, body["job_id"], token, timeout=60)
    assert job["status"] == "succeeded", job
    assert job["result"] == job["result"] | {"frames": 10, "duplicates": 0}
    assert job["message"] == f"10 frames stored in sequence #{body['video']['sequence_id']}"
    sequence = client.get(
        f"/api/v1/sequences/{body['video']['sequence_id']}", headers=auth(token)
    ).json()
    assert sequence["name"] == "weld run 7" and sequence["frame_count"] == 10
    frames = client.get(
        "/api/v1/frames",
        params={"sequence_id": sequence["id"], "order": "frame_index"},
        headers=auth(token),
    ).json()["items"]
    assert [f["frame_index"] for f in frames] == list(range(0, 30, 3))
    assert [round(f["timestamp_s"], 3) for f in frames] == [i / 10 for i in range(0, 30, 3)]
    assert all(f["video_id"] == body["video"]["id"] and f["channels"] == 3 for f in frames)
    assert frames[0]["original_name"] == "weld run 7_f000000.png"


def test_real_weld_video(client: TestClient, token: str) -> None:
    video = SHARED_DATA / "waam" / "video" / "compressed_0mm.mp4"
    if not video.exists():
        pytest.skip("../shared/data/waam/video is absent (a fresh checkout has no ../shared)")
    run = client.post("/api/v1/sequences", json={"name": "0mm"}, headers=auth(token)).json()
    response = _upload(client, token, video, every_nth="25", sequence_id=str(run["id"]))
    assert response.status_code == 202
    assert response.json()["video"]["frame_count"] == 496
    job = wait_for_job(client, response.json()["job_id"], token, timeout=120)
    assert job["status"] == "succeeded", job
    frames = client.get(
        "/api/v1/frames",
        params={"sequence_id": run["id"], "limit": 100, "order": "frame_index"},
        headers=auth(token),
    ).json()
    assert frames["total"] == 20  # frames 0, 25, …, 475
    first, last = frames["items"][0], frames["items"][-1]
    assert (first["width"], first["height"], first["channels"]) == (1280, 800, 1)  # gray
    assert last["frame_index"] == 475 and abs(last["timestamp_s"] - 475 / 15) < 1e-6


def test_video_refusals(client: TestClient, token: str, tmp_path: Path, settings: Settings):
    fake = tmp_path / "fake.mp4"
    fake.write_bytes(b"this is not a video at all")
    response = _upload(client, token, fake)
    assert response.status_code == 400
    assert response.json()["detail"] == "The file is not a video; upload an MP4 or AVI video."
    image = tmp_path / "frame.avi"
    image.write_bytes(image_bytes())
    assert _upload(client, token, image).status_code == 400
    broken = tmp_path / "broken.avi"
    broken.write_bytes(synthetic_avi(tmp_path / "ok.avi").read_bytes()[:100])
    assert _upload(client, token, broken).status_code == 400
    good = synthetic_avi(tmp_path / "good.avi")
    assert _upload(client, token, good, every_nth="0").status_code == 400
    assert _upload(client, token, good, sequence_id="77").status_code == 404
    with open(good, "rb") as handle:
        windows = client.post(
            "/api/v1/videos",
            files={"file": ("C:\\Users\\me\\good.avi", handle, "video/avi")},
            headers=auth(token),
        )
    assert windows.status_code == 400 and "path parts" in windows.json()["detail"]
    videos = settings.home / "videos"
    assert not videos.exists() or not [p for p in videos.rglob("*") if p.is_file()]
    assert client.get("/api/v1/jobs", headers=auth(token)).json()["total"] == 0


def test_command_line_import(tmp_path: Path, settings: Settings, session_factory) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for index in range(3):
        (folder / f"f{index}.png").write_bytes(image_bytes(seed=100 + index, bit_depth=16))
    (folder / "readme.txt").write_text("not a frame")  # ignored: not an image name
    (folder / "bad.png").write_bytes(b"broken")
    video = synthetic_avi(tmp_path / "clip.avi", frames=12)
    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
    }
    result = run_cli("import", folder, video, "--sequence", "bulk", "--every-nth", "4", env=env)
    assert result.returncode == 0, result.stderr
    assert "refused bad.png: The file is not a readable image" in result.stderr
    assert "sequence 'bulk': 6 frames stored, 0 duplicates, 1 refused" in result.stderr
    again = run_cli("import", folder, "--sequence", "bulk", env=env)
    assert "0 frames stored, 3 duplicates" in again.stderr
    missing = run_cli("import", tmp_path / "nope", "--sequence", "x", env=env)
    assert missing.returncode == 2 and missing.stderr.strip().endswith("does not exist.")
