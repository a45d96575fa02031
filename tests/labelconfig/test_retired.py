"""A class, tag or attribute removed from the label configuration with ``force``: its objects
and values stay on their labels through any save that does not remove them by name
(``remove_retired``), on SQLite and PostgreSQL."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import frame_ids
from tests.helpers import auth, corrected_label, mask_b64

W, H = 40, 30
LAB = {
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points"},
    ],
    "frame_tags": ["humping", "arc unstable"],
    "frame_attributes": [{"name": "note", "type": "text"}, {"name": "gas", "type": "flag"}],
}
LESS = {  # spatter, the "humping" tag and the "note" attribute removed
    "classes": [{"name": "wire", "kind": "mask"}, {"name": "wire tip", "kind": "points"}],
    "frame_tags": ["arc unstable"],
    "frame_attributes": [{"name": "gas", "type": "flag"}],
}


def _box(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[y0:y1, x0:x1] = True
    return mask


@pytest.fixture
def labelled(client: TestClient, make_user) -> tuple[str, int, dict]:
    """An annotator's token, a frame whose label holds two spatter objects, a wire tip, a
    tag and an attribute each about to be removed, and the label as read after ``force``."""
    admin, anna = make_user("ada", Role.admin)[1], make_user("anna")[1]
    put = client.put("/api/v1/label-config", json=LAB | {"version": 0}, headers=auth(admin))
    assert put.status_code == 200, put.text
    _, data = cv2.imencode(".png", np.full((H, W, 3), 90, np.uint8))
    frame = frame_ids(client, anna, [("f.png", data.tobytes())])[0]
    body = corrected_label(_box(10, 10, 25, 20)) | {
        "objects": [
            {"class": "spatter", "mask_png": mask_b64(_box(1, 1, 4, 4))},
            {"class": "wire tip", "points": {"tip": [5, 5]}},
            {"class": "spatter", "mask_png": mask_b64(_box(30, 20, 35, 25))},
        ],
        "tags": ["humping", "arc unstable"],
        "attributes": {"note": "porous", "gas": True},
    }
    saved = client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(anna))
    assert saved.status_code == 200, saved.text
    forced = client.put(
        "/api/v1/label-config", json=LESS | {"version": 1, "force": True}, headers=auth(admin)
    )
    assert forced.status_code == 200, forced.text
    label = client.get(f"/api/v1/frames/{frame}/label", headers=auth(anna)).json()
    return anna, frame, label


def _save(client: TestClient, token: str, frame: int, label: dict, **body) -> dict:
    response = client.put(
        f"/api/v1/frames/{frame}/label",
        json=corrected_label(_box(10, 10, 25, 20), label["revision"]) | body,
        headers=auth(token),
    )
    assert response.status_code == 200, response.text
    return response.json()


def test_the_label_lists_what_the_configuration_retired(labelled) -> None:
    _, _, label = labelled
    assert label["retired"] == {"objects": [0, 2], "tags": ["humping"], "attributes": ["note"]}


def test_a_changed_save_keeps_retired_objects_tags_and_attributes(
    client: TestClient, labelled
) -> None:
    """The page sends only what the configuration accepts: a new wire tip, no tags, a new gas
    flag; the spatter objects, the humping tag and the note stay as they were."""
    anna, frame, label = labelled
    spatter = [label["objects"][0], label["objects"][2]]
    saved = _save(
        client,
        anna,
        frame,
        label,
        objects=[{"class": "wire tip", "points": {"tip": [8, 9]}}],
        tags=[],
        attributes={"gas": False},
    )
    assert saved["objects"] == [{"class": "wire tip", "points": {"tip": [8.0, 9.0]}}, *spatter]
    assert saved["tags"] == ["humping"]
    assert saved["attributes"] == {"note": "porous", "gas": False}
    assert saved["retired"] == {"objects": [1, 2], "tags": ["humping"], "attributes": ["note"]}
    # Sent back as read (a client that echoes the label) they are kept once, not refused.
    again = _save(
        client, anna, frame, saved, objects=saved["objects"], tags=saved["tags"],
        attributes=saved["attributes"],
    )  # fmt: skip
    assert again["objects"] == saved["objects"] and again["tags"] == ["humping"]
    assert again["attributes"] == saved["attributes"]


def test_retired_parts_go_only_when_a_save_names_them(client: TestClient, labelled) -> None:
    anna, frame, label = labelled
    saved = _save(
        client,
        anna,
        frame,
        label,
        remove_retired={"objects": [2], "tags": ["humping"], "attributes": ["note"]},
    )
    assert [o["class"] for o in saved["objects"]] == ["spatter", "wire tip"]
    assert saved["objects"][0]["bbox"] == [1, 1, 3, 3]  # the one not named stays
    assert saved["tags"] == ["arc unstable"] and saved["attributes"] == {"gas": True}
    assert saved["retired"] == {"objects": [0], "tags": [], "attributes": []}


def test_removing_what_is_not_retired_is_a_clear_400(client: TestClient, labelled) -> None:
    anna, frame, label = labelled
    for removal, words in [
        ({"objects": [1]}, "Object 1 of the label is not of a class the configuration removed"),
        ({"tags": ["arc unstable"]}, "no frame tag 'arc unstable' that was removed"),
        ({"objects": [5000]}, "position is from 0 to 999"),
    ]:
        response = client.put(
            f"/api/v1/frames/{frame}/label",
            json=corrected_label(_box(10, 10, 25, 20), label["revision"])
            | {"remove_retired": removal},
            headers=auth(anna),
        )
        assert response.status_code in (400, 422) and words in response.text, response.text
    still = client.get(f"/api/v1/frames/{frame}/label", headers=auth(anna)).json()
    assert still["revision"] == label["revision"] and still["objects"] == label["objects"]
    # A retired class's object that is not one the label holds is still not accepted.
    new = {"class": "spatter", "mask_png": mask_b64(_box(5, 5, 9, 9))}
    refused = client.put(
        f"/api/v1/frames/{frame}/label",
        json=corrected_label(_box(10, 10, 25, 20), label["revision"]) | {"objects": [new]},
        headers=auth(anna),
    )
    assert refused.status_code == 400 and "no class 'spatter'" in refused.json()["detail"]
