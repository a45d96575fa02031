"""Per-class figures on the metrics page, on SQLite and PostgreSQL, against a hand-counted
fixture with the review stage on: frames labelled with each class, its objects, the frames
among them approved; frames per tag; the CSV."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Role
from tests.factories import frame_ids
from tests.helpers import auth, corrected_label, make_settings

W, H = 40, 30
LAB = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points"},
    ],
    "frame_tags": ["humping", "arc unstable", "porosity"],
}


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return make_settings(tmp_path / "home", database_url=database_url, review_stage=True)


def _pool() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[10:20, 10:25] = True
    return mask


def _spatter(x: int) -> dict:
    return {"class": "spatter", "polygons": [[[x, 2], [x + 4, 2], [x + 4, 6], [x, 6]]]}


def test_class_and_tag_figures_count_what_the_labels_hold(client: TestClient, make_user) -> None:
    """Four labelled frames (a fifth without a label): a reviewer's labels are approved, an
    annotator's await review.
    1 reviewer: pool, wire, 3 spatter, humping · 2 annotator: pool, wire, 1 spatter, humping +
    arc unstable · 3 reviewer: rejected, 1 spatter, arc unstable · 4 annotator: pool, 2 tips."""
    admin = make_user("ada", Role.admin)[1]
    anna = make_user("anna", Role.annotator)[1]
    assert client.put("/api/v1/label-config", json=LAB, headers=auth(admin)).is_success
    images = [
        (f"{i}.png", cv2.imencode(".png", np.full((H, W, 3), 20 * i, np.uint8))[1].tobytes())
        for i in range(5)
    ]
    ids = frame_ids(client, admin, images)
    wire = {"class": "wire", "polygons": [[[0, 0], [30, 0], [30, 4], [0, 4]]]}
    tip = {"class": "wire tip", "points": {"tip": [1, 1]}}
    saves = [
        (admin, {"objects": [wire, _spatter(2), _spatter(10), _spatter(20)], "tags": ["humping"]}),
        (anna, {"objects": [wire, _spatter(2)], "tags": ["humping", "arc unstable"]}),
        (admin, {"status": "rejected", "objects": [_spatter(5)], "tags": ["arc unstable"]}),
        (anna, {"objects": [tip, tip]}),
    ]
    for frame_id, (token, extra) in zip(ids, saves, strict=False):
        body = corrected_label(_pool()) | extra
        if extra.get("status") == "rejected":
            body.pop("mask_png")
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    figures = client.get("/api/v1/metrics", headers=auth(admin)).json()["classes"]
    assert figures == client.get("/api/v1/metrics/classes", headers=auth(anna)).json()
    by_name = {c["name"]: (c["frames"], c["objects"], c["reviewed"]) for c in figures["classes"]}
    assert [c["name"] for c in figures["classes"]] == ["pool", "wire", "spatter", "wire tip"]
    assert by_name == {
        "pool": (3, 3, 1),  # frames 1, 2, 4 (3 is rejected); 1 approved
        "wire": (2, 2, 1),
        "spatter": (3, 5, 2),  # frames 1, 2, 3; 3 + 1 + 1 objects; 1 and 3 approved
        "wire tip": (1, 2, 0),
    }
    tags = {t["name"]: t["frames"] for t in figures["tags"]}
    assert tags == {"humping": 2, "arc unstable": 2, "porosity": 0}
    # approving the annotator's label moves it into "reviewed"
    label = client.get(f"/api/v1/frames/{ids[1]}/label", headers=auth(admin)).json()
    approve = {"decision": "approve", "base_revision": label["revision"]}
    assert client.post(
        f"/api/v1/frames/{ids[1]}/label/review", json=approve, headers=auth(admin)
    ).is_success
    after = client.get("/api/v1/metrics/classes", headers=auth(admin)).json()
    assert {c["name"]: c["reviewed"] for c in after["classes"]}["wire"] == 2
    text = client.get("/api/v1/metrics/classes?format=csv", headers=auth(admin)).text
    rows = list(csv.DictReader(io.StringIO(text)))
    spatter = next(r for r in rows if r["name"] == "spatter")
    assert (spatter["what"], spatter["frames"], spatter["objects"], spatter["reviewed"]) == (
        "class",
        "3",
        "5",
        "3",
    )
    assert next(r for r in rows if r["name"] == "porosity")["frames"] == "0"
