"""Agreement of every class, on SQLite and PostgreSQL: two annotators label one frame with a
mask class, instances, named points, tags and an attribute whose overlaps and offsets are known
by hand; the frame's figures, the run's, and "save my own label" keeping her objects and tags
(and a chosen label bringing them to the frame's label)."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import frame_ids, random_images
from tests.helpers import auth, mask_b64

LAB = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "torch", "kind": "points", "point_names": ["tip", "root"]},
    ],
    "frame_tags": ["humping", "arc unstable"],
    "frame_attributes": [{"name": "joint", "type": "choice", "options": ["butt", "fillet"]}],
}


def _box(rows: slice, cols: slice) -> str:
    mask = np.zeros((48, 64), bool)
    mask[rows, cols] = True
    return mask_b64(mask)


POOL = _box(slice(30, 40), slice(20, 40))
# wire: 200 px each, 100 shared → IoU 1/3. spatter: anna's two boxes (200 px), otto's one
# 50 px inside her first → IoU 0.25, one object fewer. torch: tip moved by (3, 4) → 5 px,
# root where hers is → 0 px. Tags: humping hers only; joint butt against fillet.
ANNA = {
    "objects": [
        {"class": "wire", "mask_png": _box(slice(0, 10), slice(0, 20))},
        {"class": "spatter", "mask_png": _box(slice(20, 30), slice(0, 10))},
        {"class": "spatter", "mask_png": _box(slice(20, 30), slice(44, 54))},
        {"class": "torch", "points": {"tip": [10, 10], "root": [20, 40]}},
    ],
    "tags": ["humping"],
    "attributes": {"joint": "butt"},
}
OTTO = {
    "objects": [
        {"class": "wire", "mask_png": _box(slice(0, 10), slice(10, 30))},
        {"class": "spatter", "mask_png": _box(slice(20, 30), slice(5, 10))},
        {"class": "torch", "points": {"tip": [13, 14], "root": [20, 40]}},
    ],
    "tags": [],
    "attributes": {"joint": "fillet"},
}


def test_every_class_measured_and_kept(client: TestClient, make_user) -> None:
    admin = make_user("ada", Role.admin)[1]
    put = client.put("/api/v1/label-config", json=LAB, headers=auth(admin))
    assert put.status_code == 200, put.text
    run = client.post("/api/v1/sequences", json={"name": "run"}, headers=auth(admin)).json()
    (frame,) = frame_ids(client, admin, random_images([("1", 1)]), sequence_id=run["id"])
    people = {name: make_user(name) for name in ("anna", "otto")}
    ids = [user.id for user, _ in people.values()]
    given = {"frame_ids": [frame], "user_ids": ids}
    assert client.post("/api/v1/frames/overlap", json=given, headers=auth(admin)).is_success

    url = f"/api/v1/frames/{frame}/overlap/mine"
    for name, body in (("anna", ANNA), ("otto", OTTO)):
        saved = client.put(url, json={"mask_png": POOL, **body}, headers=auth(people[name][1]))
        assert saved.status_code == 200, saved.text
    # Saved again with the pool alone: her objects, tags and attributes stay as they were.
    anna = people["anna"][1]
    assert client.put(url, json={"mask_png": POOL}, headers=auth(anna)).status_code == 200
    own = client.get(f"/api/v1/frames/{frame}/overlap", headers=auth(anna)).json()["labels"][0]
    assert [o["class"] for o in own["objects"]] == ["wire", "spatter", "spatter", "torch"]
    assert own["objects"][3]["points"] == {"tip": [10.0, 10.0], "root": [20.0, 40.0]}
    assert own["tags"] == ["humping"] and own["attributes"] == {"joint": "butt"}
    bad = client.put(url, json={"mask_png": POOL, "tags": ["nope"]}, headers=auth(anna))
    assert bad.status_code == 400 and "no frame tag 'nope'" in bad.json()["detail"]

    seen = client.get(f"/api/v1/frames/{frame}/overlap", headers=auth(admin)).json()
    assert seen["mask_iou"] == pytest.approx(1.0)  # the same pool
    by_class = {c["class"]: c for c in seen["classes"]}
    assert sorted(by_class) == ["spatter", "torch", "wire"]
    assert by_class["wire"]["iou"] == pytest.approx(1 / 3)
    assert by_class["wire"]["count_diff"] is None  # one mask per frame: nothing to count
    assert by_class["spatter"]["iou"] == pytest.approx(0.25)
    assert by_class["spatter"]["count_diff"] == 1
    assert by_class["torch"]["points_px"] == {"tip": pytest.approx(5.0), "root": 0.0}
    assert by_class["torch"]["iou"] is None
    assert seen["differ"] == {"tags": ["humping"], "attributes": ["joint"]}

    runs = client.get("/api/v1/metrics", headers=auth(admin)).json()["agreement"]
    assert runs[0]["tags_differ"] == 1
    summary = {c["class"]: c for c in runs[0]["classes"]}
    assert summary["spatter"]["iou"] == pytest.approx(0.25) and summary["spatter"]["frames"] == 1
    assert summary["torch"]["points_px"]["tip"] == pytest.approx(5.0)

    chosen = client.post(
        f"/api/v1/frames/{frame}/overlap/settle", json={"choose": ids[1]}, headers=auth(admin)
    )
    assert chosen.status_code == 200, chosen.text
    label = chosen.json()
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter", "torch"]
    assert label["objects"][2]["points"]["tip"] == [13.0, 14.0]
    assert label["tags"] == [] and label["attributes"] == {"joint": "fillet"}


def test_an_approved_label_keeps_the_polygons_its_objects_were_drawn_as(
    client: TestClient, make_user
) -> None:
    admin = make_user("ada", Role.admin)[1]
    assert client.put("/api/v1/label-config", json=LAB, headers=auth(admin)).is_success
    (frame,) = frame_ids(client, admin, random_images([("1", 1)]))
    people = {name: make_user(name) for name in ("anna", "otto")}
    given = {"frame_ids": [frame], "user_ids": [user.id for user, _ in people.values()]}
    assert client.post("/api/v1/frames/overlap", json=given, headers=auth(admin)).is_success
    drawn = {"class": "spatter", "polygons": [[[5, 20], [15, 20], [15, 30], [5, 30]]]}
    body = {"mask_png": POOL, "objects": [drawn]}
    url = f"/api/v1/frames/{frame}/overlap/mine"
    assert client.put(url, json=body, headers=auth(people["anna"][1])).status_code == 200
    own = client.get(f"/api/v1/frames/{frame}/overlap", headers=auth(people["anna"][1]))
    stored = own.json()["labels"][0]["objects"][0]
    assert stored["polygons"] and stored["rle"]
    chosen = client.post(
        f"/api/v1/frames/{frame}/overlap/settle",
        json={"choose": people["anna"][0].id},
        headers=auth(admin),
    )
    assert chosen.status_code == 200, chosen.text
    (approved,) = chosen.json()["objects"]
    assert approved["polygons"] == stored["polygons"] and approved["rle"] == stored["rle"]


def test_an_annotator_label_with_parts_retired_since_is_approved_without_them(
    client: TestClient, make_user
) -> None:
    admin = make_user("ada", Role.admin)[1]
    assert client.put("/api/v1/label-config", json=LAB, headers=auth(admin)).is_success
    (frame,) = frame_ids(client, admin, random_images([("1", 1)]))
    people = {name: make_user(name) for name in ("anna", "otto")}
    given = {"frame_ids": [frame], "user_ids": [user.id for user, _ in people.values()]}
    assert client.post("/api/v1/frames/overlap", json=given, headers=auth(admin)).is_success
    body = {"mask_png": POOL, **ANNA}
    url = f"/api/v1/frames/{frame}/overlap/mine"
    assert client.put(url, json=body, headers=auth(people["anna"][1])).status_code == 200
    later = {  # spatter and the tag "humping" removed with force after she saved
        "version": 1,
        "force": True,
        "classes": [c for c in LAB["classes"] if c["name"] != "spatter"],
        "frame_tags": ["arc unstable"],
        "frame_attributes": LAB["frame_attributes"],
    }
    assert client.put("/api/v1/label-config", json=later, headers=auth(admin)).is_success
    chosen = client.post(
        f"/api/v1/frames/{frame}/overlap/settle",
        json={"choose": people["anna"][0].id},
        headers=auth(admin),
    )
    assert chosen.status_code == 200, chosen.text
    label = chosen.json()
    assert [o["class"] for o in label["objects"]] == ["wire", "torch"]
    assert label["tags"] == [] and label["attributes"] == {"joint": "butt"}
