"""Exports carry the whole label configuration where the format can: COCO and CVAT exported by
one instance and imported into a fresh one keep every object (regions pixel for pixel, named
points), every attribute and the frames' tags and attributes; YOLO keeps the regions and
counts what it leaves out in ``notes.txt``. A LabelMe file's point shapes, flags and
attributes come in too."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role
from app.core.schema import migrate
from app.main import create_app
from tests.helpers import auth, corrected_label, image_bytes, make_settings, mask_b64
from tests.imports.common import H, W, label_mask, start_import, stored_labels, token_for, zipped
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import rle_mask
from weldpool_core.student.folder import read_classes

CONFIG = {
    "version": 0,
    "classes": [
        {
            "name": "wire",
            "kind": "mask",
            "attributes": [{"name": "coated", "type": "flag"}],
        },
        {
            "name": "spatter",
            "kind": "instances",
            "attributes": [
                {"name": "size", "type": "choice", "options": ["small", "large"]},
                {"name": "count", "type": "number", "min": 0, "max": 10},
                {"name": "note", "type": "text"},
            ],
        },
        {
            "name": "wire tip",
            "kind": "points",
            "point_names": ["tip", "root"],
            "attributes": [{"name": "visible", "type": "flag"}],
        },
        {"name": "arc", "kind": "points"},
    ],
    "frame_tags": ["night", "porosity"],
    "frame_attributes": [
        {"name": "quality", "type": "choice", "options": ["good", "bad"]},
        {"name": "gap_mm", "type": "number"},
        {"name": "comment", "type": "text"},
    ],
}


def _box(top: int, bottom: int, left: int, right: int) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[top:bottom, left:right] = True
    return mask


POOL = _box(10, 40, 10, 50)
WIRE = _box(0, 8, 60, 90)
SPATTER = [_box(50, 56, 5, 12), _box(50, 60, 70, 80)]
OBJECTS = [
    {"class": "wire", "mask_png": mask_b64(WIRE), "attributes": {"coated": True}},
    {
        "class": "spatter",
        "mask_png": mask_b64(SPATTER[0]),
        "attributes": {"size": "small", "count": 3, "note": "near the torch"},
    },
    {
        "class": "wire tip",
        "points": {"tip": [30.5, 12.25], "root": [40.0, 5.0]},
        "attributes": {"visible": False},
    },
    {"class": "spatter", "mask_png": mask_b64(SPATTER[1]), "attributes": {"size": "large"}},
    {"class": "wire tip", "points": {"root": [70.75, 20.0]}},
    {"class": "arc", "points": {"left": [12.0, 30.0], "right": [48.5, 31.0]}},
]
TAGS = {"run 0001.png": ["night"], "run 0002.png": ["porosity", "night"]}
FRAME_ATTRIBUTES = {"quality": "bad", "gap_mm": 1.5, "comment": "arc blow; see log"}


def _exported(tmp_path, fmt: str) -> bytes:
    """A SQLite instance with ``CONFIG`` and two labelled frames: one with every kind of
    object, tags and frame attributes, one with a tag alone; exported in ``fmt``."""
    home = tmp_path / "source"
    settings = make_settings(home, database_url=f"sqlite:///{home / 'source.sqlite3'}")
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    _, token = token_for(create_session_factory(engine), "ada", Role.admin)
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(token)).is_success
        names = list(TAGS)
        files = [
            ("files", (n, image_bytes(W, H, seed=90 + i), "image/png")) for i, n in enumerate(names)
        ]
        stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
        ids = {f["original_name"]: f["id"] for f in stored}
        first = corrected_label(POOL) | {
            "objects": OBJECTS,
            "tags": TAGS[names[0]],
            "attributes": FRAME_ATTRIBUTES,
        }
        second = corrected_label(POOL) | {"tags": TAGS[names[1]]}
        for name, body in zip(names, [first, second], strict=True):
            saved = client.put(f"/api/v1/frames/{ids[name]}/label", json=body, headers=auth(token))
            assert saved.status_code == 200, saved.text
        response = client.get("/api/v1/export", params={"format": fmt}, headers=auth(token))
        assert response.status_code == 200, response.text
    engine.dispose()
    return response.content


def _imported(client, session_factory, archive: bytes, fmt: str) -> tuple[dict, dict]:
    _, token = token_for(session_factory, "bea", Role.admin)
    assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(token)).is_success
    result = start_import(client, token, archive, fmt)["result"]
    assert result["refused"] == [] and result["labels"] == 2, result
    labels = {frame["original_name"]: label for frame, label in stored_labels(client, token)}
    return result, labels


def _expected_objects() -> list[dict]:
    """``OBJECTS`` as a label stores them (regions as their masks)."""
    made = []
    for obj in OBJECTS:
        kept = {k: v for k, v in obj.items() if k != "mask_png"}
        if "mask_png" in obj:
            kept["mask"] = [WIRE, *SPATTER][[o for o in OBJECTS if "mask_png" in o].index(obj)]
        made.append(kept)
    return made


def _comparable(objects: list[dict]) -> list[dict]:
    return [
        {k: v for k, v in o.items() if k not in ("rle", "area", "bbox", "polygons")}
        | ({"mask": rle_mask(o["rle"])} if "rle" in o else {})
        for o in objects
    ]


def _same(got: list[dict], sent: list[dict]) -> None:
    assert len(got) == len(sent)
    for mine, theirs in zip(got, sent, strict=True):
        assert set(mine) == set(theirs), (mine.keys(), theirs.keys())
        for key, value in theirs.items():
            if key == "mask":
                assert np.array_equal(mine[key], value), mine["class"]
            else:
                assert mine[key] == value, (mine["class"], key)


@pytest.mark.parametrize("fmt", ["coco", "cvat", "labelme", "masks"])
def test_a_round_trip_keeps_points_attributes_and_tags(
    client, session_factory, tmp_path, fmt
) -> None:
    archive = _exported(tmp_path, fmt)
    result, labels = _imported(client, session_factory, archive, fmt)
    assert result["classes"]["kept"] == {"arc": 1, "spatter": 2, "wire": 1, "wire tip": 2}
    assert result["classes"]["attributes_left_out"] == {}
    assert result["classes"]["unknown_tags"] == {}
    first, second = labels["run 0001.png"], labels["run 0002.png"]
    assert np.array_equal(label_mask(first), POOL) and np.array_equal(label_mask(second), POOL)
    _same(_comparable(first["objects"]), _expected_objects())
    assert first["tags"] == ["night"] and first["attributes"] == FRAME_ATTRIBUTES
    assert second["tags"] == ["night", "porosity"] and second["attributes"] == {}
    assert second["objects"] == []


def test_coco_writes_points_classes_as_keypoint_categories(tmp_path) -> None:
    document = json.loads(
        zipfile.ZipFile(io.BytesIO(_exported(tmp_path, "coco"))).read("annotations.json")
    )
    categories = {c["name"]: c for c in document["categories"]}
    assert categories["wire tip"]["keypoints"] == ["tip", "root"]  # the class's own order
    assert categories["arc"]["keypoints"] == ["left", "right"]  # as the objects name them
    tips = [
        a["keypoints"]
        for a in document["annotations"]
        if a["category_id"] == categories["wire tip"]["id"]
    ]
    assert tips == [[30.5, 12.25, 2, 40.0, 5.0, 2], [0.0, 0.0, 0, 70.75, 20.0, 2]]
    image = next(i for i in document["images"] if i["original_name"] == "run 0001.png")
    assert image["tags"] == ["night"] and image["attributes"] == FRAME_ATTRIBUTES


def test_cvat_declares_every_label_and_attribute(tmp_path) -> None:
    root = ET.fromstring(
        zipfile.ZipFile(io.BytesIO(_exported(tmp_path, "cvat"))).read("annotations.xml")
    )
    declared = {
        label.findtext("name"): (
            label.findtext("type"),
            {a.findtext("name"): a.findtext("input_type") for a in label.iter("attribute")},
        )
        for label in root.iterfind("./meta/task/labels/label")
    }
    assert declared["wire"] == ("mask", {"coated": "checkbox"})
    assert declared["spatter"] == ("mask", {"size": "select", "count": "number", "note": "text"})
    assert declared["wire tip"] == ("points", {"visible": "checkbox", "point_names": "text"})
    assert declared["night"] == ("tag", {}) and declared["porosity"] == ("tag", {})
    assert declared["frame_attributes"][0] == "tag"
    image = next(i for i in root.iterfind("image") if i.get("name") == "run 0001.png")
    assert [t.get("label") for t in image.iterfind("tag")] == ["night", "frame_attributes"]
    tip = image.find("points[@label='wire tip']")
    assert tip is not None and tip.get("points") == "30.50,12.25;40.00,5.00"
    assert {a.get("name"): a.text for a in tip.iterfind("attribute")} == {
        "point_names": "tip;root",
        "visible": "false",
    }


def test_yolo_keeps_the_regions_and_counts_what_it_cannot_carry(
    client, session_factory, tmp_path
) -> None:
    archive = _exported(tmp_path, "yolo")
    notes = zipfile.ZipFile(io.BytesIO(archive)).read("notes.txt").decode()
    assert notes == (
        "3 points object(s) left out: YOLO segmentation has no named points\n"
        "4 object(s) with attributes left out: their attributes are not written\n"
        "2 frame(s) with tags or attributes left out: YOLO has no frame tags\n"
    )
    _, labels = _imported(client, session_factory, archive, "yolo")
    regions = [
        {k: v for k, v in o.items() if k != "attributes"}
        for o in _expected_objects()
        if "mask" in o
    ]
    _same(_comparable(labels["run 0001.png"]["objects"]), regions)
    assert labels["run 0001.png"]["tags"] == [] and labels["run 0001.png"]["attributes"] == {}


def _labelme(shapes: list[dict], **extra) -> bytes:
    document = {
        "version": "5.4.1",
        "flags": {"night": True, "porosity": False, "foggy": True},
        "shapes": shapes,
        "imagePath": "a.png",
        "imageHeight": H,
        "imageWidth": W,
    } | extra
    return zipped({"a.json": json.dumps(document).encode(), "a.png": image_bytes(W, H, seed=7)})


def _point(label: str, x: float, y: float, **extra) -> dict:
    return {"label": label, "points": [[x, y]], "shape_type": "point"} | extra


def test_labelme_points_flags_and_attributes_come_in(client, make_user) -> None:
    _, admin = make_user("ada", Role.admin)
    assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(admin)).is_success
    pool = [[10, 10], [49, 10], [49, 39], [10, 39]]
    spatter = [[5, 50], [11, 50], [11, 55], [5, 55]]
    shapes = [
        {"label": "weld_pool", "points": pool, "shape_type": "polygon"},
        {
            "label": "spatter",
            "points": spatter,
            "shape_type": "polygon",
            "attributes": {"size": "large", "count": 12, "colour": "red"},
        },
        _point("wire tip", 30, 12, description="tip", flags={"visible": True}, group_id=1),
        _point("wire tip", 40, 5, description="root", group_id=1),
        _point("wire tip", 70, 20, group_id=2),  # numbered: the class's first point
        _point("arc", 12, 30, description="left"),
    ]
    data = _labelme(shapes, attributes={"quality": "good", "gap_mm": "wide"})
    result = start_import(client, admin, data, "labelme")["result"]
    assert result["refused"] == [] and result["labels"] == 1
    assert result["classes"]["kept"] == {"arc": 1, "spatter": 1, "wire tip": 2}
    assert result["classes"]["unknown_tags"] == {"foggy": 1}
    assert result["classes"]["attributes_left_out"] == {
        "frame.gap_mm": 1,  # not a number
        "spatter.colour": 1,  # not defined
        "spatter.count": 1,  # above its max
    }
    label = next(label for _, label in stored_labels(client, admin))
    assert label["tags"] == ["night"] and label["attributes"] == {"quality": "good"}
    objects = label["objects"]
    assert objects[0]["attributes"] == {"size": "large"}
    assert objects[1:] == [
        {
            "class": "wire tip",
            "points": {"tip": [30.0, 12.0], "root": [40.0, 5.0]},
            "attributes": {"visible": True},
        },
        {"class": "wire tip", "points": {"tip": [70.0, 20.0]}},
        {"class": "arc", "points": {"left": [12.0, 30.0]}},
    ]


def test_the_masks_layout_writes_a_folder_per_class(tmp_path) -> None:
    archive = zipfile.ZipFile(io.BytesIO(_exported(tmp_path, "masks")))
    names = set(archive.namelist())
    manifest = json.loads(archive.read("manifest.json"))["frames"]
    first = next(f for f in manifest if f["original_name"] == "run 0001.png")
    stem = first["stem"]
    masks = {
        f"classes/wire/{stem}.png": WIRE,  # a mask class: one per frame
        f"classes/spatter/{stem}_1.png": SPATTER[0],  # an instances class: one per object
        f"classes/spatter/{stem}_2.png": SPATTER[1],
    }
    assert {n for n in names if n.startswith("classes/")} == set(masks)
    for name, mask in masks.items():
        assert np.array_equal(decode_mask_png(archive.read(name)), mask), name
    assert [o.get("mask") or o["class"] for o in first["objects"]] == [
        f"classes/wire/{stem}.png",
        f"classes/spatter/{stem}_1.png",
        "wire tip",
        f"classes/spatter/{stem}_2.png",
        "wire tip",
        "arc",
    ]
    assert first["tags"] == ["night"] and first["attributes"] == FRAME_ATTRIBUTES
    declared = json.loads(archive.read("manifest.json"))["classes"]
    assert declared == [
        {"name": "wire", "kind": "mask"},
        {"name": "spatter", "kind": "instances"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip", "root"]},
        {"name": "arc", "kind": "points", "point_names": ["left", "right"]},
    ]
    # `weldpool train --classes` reads the unzipped export as it is
    archive.extractall(tmp_path / "dataset")
    learned, frames = read_classes(tmp_path / "dataset", ["spatter", "wire tip", "wire"])
    assert [(c.name, c.kind, c.points) for c in learned] == [
        ("spatter", "instances", ()),
        ("wire tip", "points", ("tip", "root")),
        ("wire", "mask", ()),
    ]
    truths = {frame.name: frame.classes for frame in frames}[stem]
    assert np.array_equal(truths["wire"].mask, WIRE)
    assert np.array_equal(truths["spatter"].mask, SPATTER[0] | SPATTER[1])
    assert dict(truths["wire tip"].points) == {"tip": (30.5, 12.25), "root": (40.0, 5.0)}


def test_foreign_points_are_named_by_order_or_counted(client, make_user) -> None:
    """CVAT points without names take the class's point names in order; COCO keypoints that do
    not match their category's names, and a region of a points class, are counted, never
    refused."""
    _, admin = make_user("ada", Role.admin)
    assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(admin)).is_success
    xml = (
        f'<annotations><image id="0" name="a.png" width="{W}" height="{H}">'
        '<box label="weld_pool" xtl="10" ytl="10" xbr="40" ybr="30"/>'
        '<points label="wire tip" points="5,6;7,8"><attribute name="visible">true</attribute>'
        "</points>"
        '<polygon label="wire tip" points="1,1;9,1;9,9"/>'
        '<tag label="porosity"/><tag label="rain"/>'
        "</image></annotations>"
    )
    files = {"annotations.xml": xml.encode(), "a.png": image_bytes(W, H, seed=3)}
    result = start_import(client, admin, zipped(files), "cvat")["result"]
    assert result["refused"] == [] and result["labels"] == 1
    assert result["classes"]["no_points"] == {"wire tip": 1}
    assert result["classes"]["unknown_tags"] == {"rain": 1}
    label = next(label for _, label in stored_labels(client, admin))
    assert label["objects"] == [
        {
            "class": "wire tip",
            "points": {"tip": [5.0, 6.0], "root": [7.0, 8.0]},
            "attributes": {"visible": True},
        }
    ]
    assert label["tags"] == ["porosity"]

    document = {
        "images": [{"id": 1, "file_name": "b.png", "width": W, "height": H}],
        "annotations": [
            {"id": 1, "image_id": 1, "category_id": 1, "segmentation": [[10, 10, 40, 10, 40, 30]]},
            {"id": 2, "image_id": 1, "category_id": 2, "keypoints": [5, 6, 2]},  # 1 of 2 names
        ],
        "categories": [
            {"id": 1, "name": "weld_pool"},
            {"id": 2, "name": "wire tip", "keypoints": ["tip", "root"]},
        ],
    }
    files = {"annotations.json": json.dumps(document).encode(), "b.png": image_bytes(W, H, seed=4)}
    result = start_import(client, admin, zipped(files), "coco")["result"]
    assert result["labels"] == 1 and result["classes"]["no_points"] == {"wire tip": 1}
