"""Deleting a frame given to several annotators removes their own labels' mask files too, and
an annotator's replaced own mask goes to the collector (no revision keeps it)."""

from __future__ import annotations

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.housekeeping import collect_doomed
from app.core.models import DoomedFile, Role
from tests.helpers import age_stored_files, auth, image_bytes, mask_b64


def _mask(right: int) -> np.ndarray:
    mask = np.zeros((48, 64), bool)
    mask[10:30, 10:right] = True
    return mask


def _masks(settings) -> set[str]:  # type: ignore[no-untyped-def]
    return {
        p.relative_to(settings.home).as_posix()
        for p in (settings.home / "artefacts").rglob("*")
        if p.is_file()
    }


def test_own_labels_files_go_with_their_frame(
    client: TestClient, make_user, settings, session_factory
) -> None:
    _, rita = make_user("rita", Role.reviewer)
    people = [make_user(name) for name in ("anna", "otto")]
    files = [("files", (f"{n}.png", image_bytes(seed=n), "image/png")) for n in (1, 2)]
    stored = client.post("/api/v1/frames", files=files, headers=auth(rita)).json()["stored"]
    frame, keeper = (f["id"] for f in stored)
    body = {"frame_ids": [frame, keeper], "user_ids": [user.id for user, _ in people]}
    assert client.post("/api/v1/frames/overlap", json=body, headers=auth(rita)).status_code == 200
    before = _masks(settings)
    for right, (_, token) in zip((40, 25), people, strict=True):
        own = {"mask_png": mask_b64(_mask(right))}
        saved = client.put(f"/api/v1/frames/{frame}/overlap/mine", json=own, headers=auth(token))
        assert saved.status_code == 200, saved.text
    keep = {"mask_png": mask_b64(_mask(50))}  # the other frame's own label stays
    kept = client.put(
        f"/api/v1/frames/{keeper}/overlap/mine", json=keep, headers=auth(people[0][1])
    )
    assert kept.status_code == 200
    own_masks = _masks(settings) - before
    assert len(own_masks) == 3
    age_stored_files(settings.home, settings.file_grace_s + 1)

    gone = client.delete(f"/api/v1/frames/{frame}", params={"force": "true"}, headers=auth(rita))
    assert gone.status_code == 200, gone.text
    assert gone.json()["removed_files"] == 3  # the image and both annotators' masks
    left = _masks(settings)
    assert len(own_masks & left) == 1  # only the other frame's
    mine = client.get(f"/api/v1/frames/{keeper}/overlap", headers=auth(people[0][1])).json()
    assert mine["labels"][0]["username"] == "anna"


def test_a_replaced_own_mask_goes_to_the_collector(
    client: TestClient, make_user, settings, session_factory
) -> None:
    _, rita = make_user("rita", Role.reviewer)
    people = [make_user(name) for name in ("anna", "otto")]
    files = [("files", ("a.png", image_bytes(seed=1), "image/png"))]
    frame = client.post("/api/v1/frames", files=files, headers=auth(rita)).json()["stored"][0]
    body = {"frame_ids": [frame["id"]], "user_ids": [user.id for user, _ in people]}
    assert client.post("/api/v1/frames/overlap", json=body, headers=auth(rita)).status_code == 200
    path = f"/api/v1/frames/{frame['id']}/overlap/mine"
    first = {"mask_png": mask_b64(_mask(40))}
    assert client.put(path, json=first, headers=auth(people[0][1])).status_code == 200
    masks = _masks(settings)
    second = {"mask_png": mask_b64(_mask(30))}
    assert client.put(path, json=second, headers=auth(people[0][1])).status_code == 200
    assert len(_masks(settings) - masks) == 1
    age_stored_files(settings.home, settings.file_grace_s + 1)
    with session_factory() as session:
        assert set(session.scalars(sa.select(DoomedFile.path))) == masks
        collect_doomed(session, client.app.state.storage)
    assert not masks & _masks(settings)
