"""A run's timeline when one frame's mask file is lost: the run still answers, that frame has
no geometry and says which file is missing and what restores it."""

from __future__ import annotations

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import Label, Role
from tests.helpers import auth, corrected_label, image_bytes


def test_a_lost_mask_leaves_its_frame_without_geometry_not_the_run(
    client: TestClient, settings, session_factory, make_user
) -> None:
    _, token = make_user("timeline", Role.reviewer)
    sequence = client.post("/api/v1/sequences", json={"name": "Run"}, headers=auth(token)).json()
    files = [
        ("files", (f"t{i}.png", image_bytes(160, 100, seed=90 + i), "image/png")) for i in range(2)
    ]
    stored = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": sequence["id"]}, headers=auth(token)
    ).json()["stored"]
    lost, kept = (f["id"] for f in stored)
    for frame_id, width in ((lost, 30), (kept, 60)):
        mask = np.zeros((100, 160), bool)
        mask[40:50, 20 : 20 + width] = True
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
    with session_factory() as session:
        path = session.scalar(sa.select(Label.mask_path).where(Label.frame_id == lost))
    (settings.home / path).unlink()

    url = f"/api/v1/sequences/{sequence['id']}/geometry"
    answer = client.get(url, headers=auth(token))
    assert answer.status_code == 200, answer.text
    rows = {row["frame_id"]: row for row in answer.json()["frames"]}
    assert rows[lost]["area_px"] is None and rows[lost]["source"] == "label"
    assert rows[lost]["missing_file"] == (
        f"Frame {lost}'s label mask ({path}) is missing from the store; draw and save the "
        "frame's label again to replace it."
    )
    assert rows[kept]["area_px"] == 600 and rows[kept]["missing_file"] is None
    csv = client.get(url, params={"format": "csv"}, headers=auth(token))
    assert csv.status_code == 200 and len(csv.text.splitlines()) == 3
