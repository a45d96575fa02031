"""A frame whose stored file is lost (gone from disk, or from the bucket and the cache): its own
requests answer one sentence naming the frame, the file and what restores it; the other
frames are untouched."""

from __future__ import annotations

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Frame, Label, Role
from tests.helpers import auth, corrected_label, image_bytes


def _box(x0: int, x1: int) -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, x0:x1] = True
    return mask


def test_a_lost_image_or_mask_is_its_frames_409_and_a_new_upload_restores_it(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("keeper", Role.reviewer)
    files = [
        ("files", (f"m{i}.png", image_bytes(64, 48, seed=70 + i), "image/png")) for i in (0, 1)
    ]
    stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    lost, kept = (f["id"] for f in stored)
    for frame_id, x0 in ((lost, 5), (kept, 30)):
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label",
            json=corrected_label(_box(x0, x0 + 20)),
            headers=auth(token),
        )
        assert saved.status_code == 200, saved.text
    with session_factory() as session:
        path = session.get_one(Frame, lost).path
    (settings.home / path).unlink()

    for variant in ("original", "display", "thumb"):
        answer = client.get(
            f"/api/v1/frames/{lost}/image", params={"variant": variant}, headers=auth(token)
        )
        assert answer.status_code == 409, (variant, answer.text)
        detail = answer.json()["detail"]
        assert detail.startswith(f"Frame {lost}'s image ({path}) is missing from the store;")
        assert "upload the same image again" in detail and str(settings.home) not in detail
    assert client.get(f"/api/v1/frames/{kept}/image", headers=auth(token)).status_code == 200

    again = [("files", ("again.png", image_bytes(64, 48, seed=70), "image/png"))]
    client.post("/api/v1/frames", files=again, headers=auth(token))
    restored = client.get(f"/api/v1/frames/{lost}/image", headers=auth(token))
    assert restored.status_code == 200 and restored.content == image_bytes(64, 48, seed=70)

    with session_factory() as session:
        mask_path = session.scalar(sa.select(Label.mask_path).where(Label.frame_id == kept))
    (settings.home / mask_path).unlink()
    answer = client.get(f"/api/v1/frames/{kept}/label", headers=auth(token))
    assert answer.status_code == 409, answer.text
    assert answer.json()["detail"] == (
        f"Frame {kept}'s label mask ({mask_path}) is missing from the store; draw and save the "
        "frame's label again to replace it."
    )
    assert client.get(f"/api/v1/frames/{lost}/label", headers=auth(token)).status_code == 200
