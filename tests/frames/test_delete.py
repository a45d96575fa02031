"""Deleting frames and weld runs: reviewed work is guarded, rows and files go together, files
still named by another row (content is shared by hash) stay."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import random_images, upload_frames
from tests.helpers import age_stored_files, auth, corrected_label, image_bytes


def _files(settings) -> set[str]:  # type: ignore[no-untyped-def]
    return {
        p.relative_to(settings.home).as_posix()
        for area in ("frames", "artefacts")
        for p in (settings.home / area).rglob("*")
        if p.is_file()
    }


def test_deleting_frames_and_a_sequence(client: TestClient, make_user, settings) -> None:
    _, token = make_user("rev", Role.reviewer)
    _, annotator = make_user("ann")
    run = client.post("/api/v1/sequences", json={"name": "wrong upload"}, headers=auth(token))
    other = client.post("/api/v1/sequences", json={"name": "keeper"}, headers=auth(token))
    run_id, other_id = run.json()["id"], other.json()["id"]
    a, b, c = upload_frames(
        client, token, random_images([("a.png", 1), ("b.png", 2), ("c.png", 3)]), sequence_id=run_id
    )
    shared = upload_frames(
        client, token, random_images([("a-again.png", 1)]), sequence_id=other_id
    )[0]  # a's content, shared
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:40] = True
    labelled = client.put(
        f"/api/v1/frames/{b['id']}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert labelled.status_code == 200
    before = _files(settings)

    assert client.delete(f"/api/v1/frames/{a['id']}", headers=auth(annotator)).status_code == 403
    guarded = client.delete(f"/api/v1/frames/{b['id']}", headers=auth(token))
    assert guarded.status_code == 409
    assert "1 frame of the selection has reviewed labels" in guarded.json()["detail"]
    assert client.get(f"/api/v1/frames/{b['id']}", headers=auth(token)).status_code == 200
    assert _files(settings) == before

    gone = client.delete(f"/api/v1/frames/{a['id']}", headers=auth(token))
    assert gone.json() == {"deleted_frames": 1, "deleted_reviewed": 0, "removed_files": 0}
    assert _files(settings) == before  # the keeper's frame still names a's content
    assert client.get(f"/api/v1/frames/{a['id']}", headers=auth(token)).status_code == 404

    missing = client.post(
        "/api/v1/frames/delete", json={"frame_ids": [c["id"], 999999]}, headers=auth(token)
    )
    assert missing.status_code == 404
    assert client.get(f"/api/v1/frames/{c['id']}", headers=auth(token)).status_code == 200

    refused = client.delete(f"/api/v1/sequences/{run_id}", headers=auth(token))
    assert refused.status_code == 409 and "'wrong upload'" in refused.json()["detail"]
    age_stored_files(settings.home, settings.file_grace_s + 1)  # uploaded a while ago
    whole = client.delete(
        f"/api/v1/sequences/{run_id}", params={"force": "true"}, headers=auth(token)
    )
    assert whole.status_code == 200, whole.text
    assert whole.json() == {"deleted_frames": 2, "deleted_reviewed": 1, "removed_files": 3}
    assert client.get(f"/api/v1/sequences/{run_id}", headers=auth(token)).status_code == 404
    for frame in (b, c):
        assert client.get(f"/api/v1/frames/{frame['id']}", headers=auth(token)).status_code == 404
    left = _files(settings)
    assert len(left) == 1 and left <= before  # only the keeper's image remains
    kept = client.get(f"/api/v1/frames/{shared['id']}/image", headers=auth(token))
    assert kept.status_code == 200


def test_a_deleted_newest_frame_or_run_gives_its_id_to_nobody(
    client: TestClient, make_user
) -> None:
    """A page still open on a deleted newest frame or run reaches nothing: the next upload and
    the next run get new ids (SQLite reused the highest; PostgreSQL never did), so a label saved
    from that page is the frame's 404 and an upload naming that run is the run's 404."""
    _, token = make_user("rev", Role.reviewer)
    run_id = client.post("/api/v1/sequences", json={"name": "r"}, headers=auth(token)).json()["id"]
    (first,) = upload_frames(client, token, random_images([("a.png", 1)]), sequence_id=run_id)
    assert client.delete(f"/api/v1/frames/{first['id']}", headers=auth(token)).status_code == 200
    (second,) = upload_frames(client, token, random_images([("b.png", 2)]), sequence_id=run_id)
    assert second["id"] > first["id"]
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:40] = True
    stale = client.put(
        f"/api/v1/frames/{first['id']}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert stale.status_code == 404
    kept = client.get(f"/api/v1/frames/{second['id']}/label", headers=auth(token))
    assert kept.status_code == 404  # no label was saved onto the other image

    assert client.delete(f"/api/v1/sequences/{run_id}", headers=auth(token)).status_code == 200
    new_run = client.post("/api/v1/sequences", json={"name": "s"}, headers=auth(token)).json()
    assert new_run["id"] > run_id
    files = [("files", ("c.png", image_bytes(seed=3), "image/png"))]
    into_old = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": str(run_id)}, headers=auth(token)
    )
    assert into_old.status_code == 404
