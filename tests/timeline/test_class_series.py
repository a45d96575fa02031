"""The timeline's other classes: per frame, each class's object count, summed area (px and mm²)
and mean point positions from its label, and the frame's tags; on SQLite and PostgreSQL."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.helpers import auth, corrected_label, image_bytes, mask_b64

W, H = 40, 30
LAB = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip"]},
    ],
    "frame_tags": ["humping", "arc unstable"],
}


def _rect(x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[y0:y1, x0:x1] = True
    return mask


def _region(name: str, mask: np.ndarray) -> dict:
    return {"class": name, "mask_png": mask_b64(mask)}


@pytest.fixture
def run(client: TestClient, make_user) -> dict:
    """A run of three frames at 0.1 mm per pixel: 1 a wire of 5×40 px, two spatters of 3×4 and
    5×5 px, two wire tips at (4, 6) and (8, 10), humping · 2 a wire of 2×10 px, humping and arc
    unstable · 3 no label."""
    token = make_user("ada", Role.admin)[1]
    assert client.put("/api/v1/label-config", json=LAB, headers=auth(token)).is_success
    sequence = client.post("/api/v1/sequences", json={"name": "Run"}, headers=auth(token)).json()
    client.patch(
        f"/api/v1/sequences/{sequence['id']}", json={"mm_per_px": 0.1}, headers=auth(token)
    )
    files = [("files", (f"t{i}.png", image_bytes(W, H, seed=i), "image/png")) for i in range(3)]
    stored = client.post(
        "/api/v1/frames", files=files, data={"sequence_id": sequence["id"]}, headers=auth(token)
    ).json()["stored"]
    ids = [f["id"] for f in stored]
    pool = _rect(10, 25, 10, 20)
    first = {
        "objects": [
            _region("wire", _rect(0, 40, 0, 5)),
            _region("spatter", _rect(30, 33, 20, 24)),
            _region("spatter", _rect(0, 5, 25, 30)),
            {"class": "wire tip", "points": {"tip": [4, 6]}},
            {"class": "wire tip", "points": {"tip": [8, 10]}},
        ],
        "tags": ["humping"],
    }
    second = {"objects": [_region("wire", _rect(0, 10, 0, 2))], "tags": ["arc unstable", "humping"]}
    for frame_id, extra in zip(ids, (first, second), strict=False):
        body = corrected_label(pool) | extra
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    return {"token": token, "sequence_id": sequence["id"], "ids": ids}


def test_each_frame_has_its_classes_figures_and_tags(client: TestClient, run: dict) -> None:
    timeline = client.get(
        f"/api/v1/sequences/{run['sequence_id']}/geometry", headers=auth(run["token"])
    ).json()
    assert [c["name"] for c in timeline["classes"]] == ["wire", "spatter", "wire tip"]
    assert timeline["frame_tags"] == ["humping", "arc unstable"]
    first, second, third = timeline["frames"]
    assert first["classes"]["wire"] == {
        "count": 1,
        "area_px": 200,
        "area_mm2": pytest.approx(2.0),
        "points": {},
    }
    spatter = first["classes"]["spatter"]
    assert spatter["count"] == 2 and spatter["area_px"] == 12 + 25
    assert spatter["area_mm2"] == pytest.approx(0.37)
    tips = first["classes"]["wire tip"]
    assert tips["count"] == 2 and tips["area_px"] is None
    assert tips["points"] == {"tip": [6.0, 8.0]}  # the mean of (4, 6) and (8, 10)
    assert first["tags"] == ["humping"]
    assert second["classes"] == {
        "wire": {"count": 1, "area_px": 20, "area_mm2": pytest.approx(0.2), "points": {}}
    }
    assert second["tags"] == ["arc unstable", "humping"]  # as the label stores them
    assert third["classes"] == {} and third["tags"] == []


def test_the_csv_has_the_tags_and_each_classs_objects_and_area(
    client: TestClient, run: dict
) -> None:
    text = client.get(
        f"/api/v1/sequences/{run['sequence_id']}/geometry",
        params={"format": "csv"},
        headers=auth(run["token"]),
    ).text
    rows = list(csv.DictReader(io.StringIO(text)))
    picked = [
        (
            r["tags"],
            r["wire objects"],
            r["wire area_px"],
            r["spatter objects"],
            r["spatter area_px"],
        )
        for r in rows
    ]
    assert picked == [
        ("humping", "1", "200", "2", "37"),
        ("arc unstable;humping", "1", "20", "0", ""),
        ("", "", "", "", ""),  # no label: nothing known
    ]
    assert rows[0]["wire tip objects"] == "2" and rows[0]["wire tip area_px"] == ""
