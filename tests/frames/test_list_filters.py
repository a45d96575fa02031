"""The frames list filtered by what labels hold, on SQLite and PostgreSQL: a class present
(`pool`: a pool mask), a frame tag, a frame attribute's value; combined with the other filters
and paging; refused in one sentence for names the configuration does not have; and the facet
rows they read kept with the label on save, update, deletion and import."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.models import LabelFacet, Role
from tests.factories import frame_ids
from tests.helpers import auth, corrected_label
from tests.imports.common import start_import, zipped

LAB = {
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip"]},
    ],
    "frame_tags": ["humping", "arc unstable"],
    "frame_attributes": [
        {"name": "joint", "type": "choice", "options": ["butt", "fillet"]},
        {"name": "hot", "type": "flag"},
        {"name": "current", "type": "number"},
        {"name": "note", "type": "text"},
    ],
}
W, H = 40, 30
SQUARE = [[2, 2], [12, 2], [12, 12], [2, 12]]


def _pool() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[10:20, 10:25] = True
    return mask


def _box(x: int, y: int) -> dict:
    return {"polygons": [[[x, y], [x + 5, y], [x + 5, y + 5], [x, y + 5]]]}


@pytest.fixture
def lab(client: TestClient, make_user) -> dict:
    """Six frames of one run (a seventh in another) with labels of several classes and tags:
    1 pool + wire, humping, joint butt · 2 pool + 2 spatter, humping + arc unstable, hot ·
    3 rejected, arc unstable, current 3 · 4 pool alone, current 3.5, a note · 5 no label ·
    6 pool + wire tip, joint fillet · 7 (other run) pool + wire, humping."""
    admin = make_user("ada", Role.admin)[1]
    put = client.put("/api/v1/label-config", json=LAB | {"version": 0}, headers=auth(admin))
    assert put.status_code == 200, put.text
    run = client.post("/api/v1/sequences", json={"name": "r"}, headers=auth(admin)).json()["id"]
    other = client.post("/api/v1/sequences", json={"name": "o"}, headers=auth(admin)).json()["id"]
    images = [
        (f"{i}.png", cv2.imencode(".png", np.full((H, W, 3), 10 * i, np.uint8))[1].tobytes())
        for i in range(1, 8)
    ]
    ids = frame_ids(client, admin, images[:6], sequence_id=run)
    ids += frame_ids(client, admin, images[6:], sequence_id=other)
    wire = {"class": "wire", "polygons": [SQUARE]}
    bodies = {
        1: {"objects": [wire], "tags": ["humping"], "attributes": {"joint": "butt"}},
        2: {
            "objects": [{"class": "spatter", **_box(20, 2)}, {"class": "spatter", **_box(30, 2)}],
            "tags": ["humping", "arc unstable"],
            "attributes": {"hot": True},
        },
        3: {"status": "rejected", "tags": ["arc unstable"], "attributes": {"current": 3}},
        4: {"attributes": {"current": 3.5, "note": "porosity: some"}},
        6: {
            "objects": [{"class": "wire tip", "points": {"tip": [5, 5]}}],
            "attributes": {"joint": "fillet", "hot": False},
        },
        7: {"objects": [wire], "tags": ["humping"]},
    }
    for number, extra in bodies.items():
        body = corrected_label(_pool()) | extra
        if extra.get("status") == "rejected":
            body.pop("mask_png")
        saved = client.put(
            f"/api/v1/frames/{ids[number - 1]}/label", json=body, headers=auth(admin)
        )
        assert saved.status_code == 200, saved.text
    return {"token": admin, "ids": ids, "run": run}


def _listed(client: TestClient, lab: dict, **params) -> list[int]:
    """The frame numbers (1–7) the list gives for ``params``, in id order."""
    response = client.get(
        "/api/v1/frames", params={"limit": 100} | params, headers=auth(lab["token"])
    )
    assert response.status_code == 200, response.text
    page = response.json()
    assert page["total"] == len(page["items"])
    return [lab["ids"].index(f["id"]) + 1 for f in page["items"]]


CASES = [
    ({"class": "wire"}, [1, 7]),
    ({"class": "WIRE"}, [1, 7]),  # names as the configuration spells them, ignoring case
    ({"class": "spatter"}, [2]),
    ({"class": "wire tip"}, [6]),
    ({"class": "pool"}, [1, 2, 4, 6, 7]),  # a rejected frame has no pool
    ({"class": ["pool", "wire"]}, [1, 7]),  # repeated: every one
    ({"tag": "humping"}, [1, 2, 7]),
    ({"tag": "arc unstable"}, [2, 3]),
    ({"tag": ["humping", "arc unstable"]}, [2]),
    ({"tag": "humping", "class": "spatter"}, [2]),
    ({"attr": "joint:butt"}, [1]),
    ({"attr": "joint:fillet"}, [6]),
    ({"attr": "hot:true"}, [2]),
    ({"attr": "hot:false"}, [6]),
    ({"attr": "current:3"}, [3]),
    ({"attr": "current:3.0"}, [3]),
    ({"attr": "current:3.5"}, [4]),
    ({"attr": "note:porosity: some"}, [4]),  # the first colon splits name from value
    ({"class": "wire", "sequence_id": "run"}, [1]),
    ({"tag": "arc unstable", "status": "rejected"}, [3]),
    ({"tag": "humping", "order": "-id"}, [7, 2, 1]),
]


def test_filters_give_exactly_the_frames_that_hold_it(client: TestClient, lab: dict) -> None:
    assert _listed(client, lab) == [1, 2, 3, 4, 5, 6, 7]  # unfiltered: all of them
    for params, expected in CASES:
        given = {k: lab["run"] if v == "run" else v for k, v in params.items()}
        assert _listed(client, lab, **given) == expected, params


def test_a_filtered_list_pages_by_cursor(client: TestClient, lab: dict) -> None:
    seen, after = [], None
    for _ in range(10):
        params = {"class": "pool", "limit": 2} | ({"after": after} if after else {})
        page = client.get("/api/v1/frames", params=params, headers=auth(lab["token"])).json()
        assert page["total"] == 5
        seen += [lab["ids"].index(f["id"]) + 1 for f in page["items"]]
        if not (after := page["next_after"]):
            break
    assert seen == [1, 2, 4, 6, 7]


@pytest.mark.parametrize(
    ("params", "words"),
    [
        (
            {"class": "rope"},
            "There is no class 'rope' in the label configuration (its classes: "
            "'pool', 'wire', 'spatter', 'wire tip').",
        ),
        (
            {"tag": "porosity"},
            "There is no frame tag 'porosity' in the label configuration (its "
            "tags: 'humping', 'arc unstable').",
        ),
        ({"attr": "joint"}, "name:value"),
        ({"attr": "weather:rain"}, "its frame attributes: 'joint', 'hot', 'current', 'note'"),
        ({"attr": "joint:lap"}, "its options: 'butt', 'fillet'"),
        ({"attr": "hot:maybe"}, "true or false"),
        ({"attr": "current:lots"}, "is a number"),
    ],
)
def test_unknown_names_are_refused_naming_the_known_ones(
    client: TestClient, lab: dict, params: dict, words: str
) -> None:
    response = client.get("/api/v1/frames", params=params, headers=auth(lab["token"]))
    assert response.status_code == 400
    assert words in response.json()["detail"]


def _facets(session_factory, frame_id: int) -> set[tuple[str, str, str, int]]:
    with session_factory() as session:
        rows = session.execute(
            sa.select(LabelFacet.kind, LabelFacet.key, LabelFacet.value, LabelFacet.count).where(
                LabelFacet.frame_id == frame_id
            )
        )
        return {tuple(row) for row in rows}


def test_the_facets_follow_each_save_and_go_with_the_frame(
    client: TestClient, lab: dict, session_factory
) -> None:
    token, first, second = lab["token"], lab["ids"][0], lab["ids"][1]
    assert _facets(session_factory, second) == {
        ("class", "pool", "", 1),
        ("class", "spatter", "", 2),
        ("tag", "humping", "", 1),
        ("tag", "arc unstable", "", 1),
        ("attr", "hot", "true", 1),
    }
    # an update that drops the wire and changes the tag: the list follows at once
    body = corrected_label(_pool(), base_revision=1) | {"objects": [], "tags": ["arc unstable"]}
    assert client.put(f"/api/v1/frames/{first}/label", json=body, headers=auth(token)).is_success
    assert _listed(client, lab, **{"class": "wire"}) == [7]
    assert _listed(client, lab, tag="arc unstable") == [1, 2, 3]
    assert _facets(session_factory, first) == {
        ("class", "pool", "", 1),
        ("tag", "arc unstable", "", 1),
        ("attr", "joint", "butt", 1),  # not given: kept as the label held it
    }
    # a save that says nothing of the classes keeps them (and their facets)
    body = corrected_label(_pool(), base_revision=1)
    assert client.put(f"/api/v1/frames/{second}/label", json=body, headers=auth(token)).is_success
    assert ("class", "spatter", "", 2) in _facets(session_factory, second)
    # rejected: no pool any more
    rejected = {"status": "rejected", "base_revision": 2}
    assert client.put(
        f"/api/v1/frames/{second}/label", json=rejected, headers=auth(token)
    ).is_success
    assert _listed(client, lab, **{"class": "pool"}) == [1, 4, 6, 7]
    deleted = client.request(
        "DELETE", f"/api/v1/frames/{second}", params={"force": "true"}, headers=auth(token)
    )
    assert deleted.status_code == 200, deleted.text
    assert _facets(session_factory, second) == set()


def test_an_import_writes_the_facets_of_its_labels(client: TestClient, make_user) -> None:
    admin = make_user("ada", Role.admin)[1]
    config = {"version": 0, "classes": [{"name": "wire", "kind": "mask"}]}
    assert client.put("/api/v1/label-config", json=config, headers=auth(admin)).is_success
    image = cv2.imencode(".png", np.full((H, W, 3), 90, np.uint8))[1].tobytes()
    other = cv2.imencode(".png", np.full((H, W, 3), 40, np.uint8))[1].tobytes()
    pool, wire = "0.1 0.1 0.5 0.1 0.5 0.5 0.1 0.5", "0.6 0.6 0.9 0.6 0.9 0.9 0.6 0.9"
    archive = zipped(
        {
            "data.yaml": ("names: " + json.dumps(["weld_pool", "wire"]) + "\n").encode(),
            "images/train/a.png": image,
            "labels/train/a.txt": f"0 {pool}\n1 {wire}\n".encode(),
            "images/train/b.png": other,
            "labels/train/b.txt": f"0 {pool}\n".encode(),
        }
    )
    assert start_import(client, admin, archive, "yolo")["result"]["labels"] == 2
    names = {}
    for key in ("wire", "pool"):
        page = client.get("/api/v1/frames", params={"class": key}, headers=auth(admin)).json()
        names[key] = sorted(f["original_name"] for f in page["items"])
    assert names == {"wire": ["a.png"], "pool": ["a.png", "b.png"]}
