"""Labels made elsewhere, with everything that can be wrong with them: each bad item is listed
with one sentence and the rest is imported; a request that cannot start is a 4xx; a batch
that fails leaves nothing of itself behind."""

from __future__ import annotations

import base64
import io
import json
import zipfile

import numpy as np
import pytest
import sqlalchemy as sa

from app.core.models import Frame, Label, LabelRevision, Role
from tests.helpers import auth, image_bytes, wait_for_job
from tests.imports.common import H, W, label_mask, start_import, stored_labels, zipped
from weldpool_core.annotations.shapes import cvat_rle, to_cvat_rle
from weldpool_core.io import encode_mask_png


def _by_name(client, token) -> dict[str, dict | None]:
    return {frame["original_name"]: label for frame, label in stored_labels(client, token)}


def _reasons(result: dict) -> dict[str, str]:
    return {r["item"]: r["reason"] for r in result["refused"]}


def test_a_foreign_coco_file_imports_what_is_right_and_says_what_is_not(client, make_user) -> None:
    _, token = make_user("lab", Role.annotator)
    square = np.zeros((H, W), np.uint8)
    square[10:30, 10:40] = 1
    counts, previous, run = [], 0, 0
    for value in np.asfortranarray(square).reshape(-1, order="F"):  # uncompressed RLE, by hand
        if value != previous:
            counts.append(run)
            previous, run = value, 0
        run += 1
    counts.append(run)
    images = [{"id": i, "file_name": f"f{i}.png", "width": W, "height": H} for i in range(1, 8)]
    annotations = [
        {
            "id": 1,
            "image_id": 1,
            "category_id": 1,
            "iscrowd": 1,
            "segmentation": {"size": [H, W], "counts": counts},
        },
        {
            "id": 2,
            "image_id": 2,
            "category_id": 1,
            "iscrowd": 0,
            "segmentation": [[10, 10, 50, 10, 50, 40, 10, 40]],
            "keypoints": [12, 12, 2, 48, 38, 2, 0, 0, 0],
        },
        {"id": 3, "image_id": 99, "category_id": 1, "segmentation": [[1, 1, 5, 1, 5, 5]]},
        {
            "id": 4,
            "image_id": 3,
            "category_id": 1,
            "segmentation": {"size": [10, 10], "counts": [100]},
        },
        {
            "id": 5,
            "image_id": 4,
            "category_id": 1,
            "segmentation": [[10, 10, 500, 10, 500, 40, 10, 40]],
        },
        {"id": 6, "image_id": 5, "category_id": 2, "segmentation": [[1, 1, 5, 1, 5, 5]]},
        {"id": 7, "image_id": 6, "category_id": 1, "segmentation": "nonsense"},
        {"id": 8, "image_id": 7, "category_id": 1, "segmentation": [[1, 1, 5, 1, 5, 5]]},
    ]
    coco = {
        "images": images,
        "annotations": annotations,
        "categories": [{"id": 1, "name": "melt pool"}, {"id": 2, "name": "spatter"}],
    }
    files = {"annotations.json": json.dumps(coco).encode()}
    files |= {f"images/f{i}.png": image_bytes(W, H, seed=900 + i) for i in range(1, 7)}
    files["../evil.png"] = image_bytes(W, H, seed=999)
    files["images/f7.png"] = b"not an image at all"
    result = start_import(client, token, zipped(files), "coco")["result"]
    reasons = _reasons(result)
    assert reasons == {
        "annotations.json: annotation 3": "It names image 99, which the file does not list.",
        "annotations.json: f3.png": "The mask is 10×10; the frame is 96×64.",
        "annotations.json: annotation 7": "The segmentation is neither RLE nor polygons (lists "
        "of 3 or more x, y pairs).",
        "../evil.png": "The path leaves the archive; it is not read.",
        "annotations.json: f4.png": "The polygon's point (500, 10) lies outside the 96×64 frame.",
        "annotations.json: f7.png": reasons.get("annotations.json: f7.png", "?"),
    }, reasons
    assert reasons["annotations.json: f7.png"].startswith("The image is refused: ")
    assert result["classes"]["without_pool"] == {"spatter": 1}  # image 5 has no pool: counted
    assert result["labels"] == 2 and result["keypoints"] == 1
    labels = _by_name(client, token)
    assert (label_mask(labels["f1.png"]) == square.astype(bool)).all()  # crowd RLE, as it is
    polygon = label_mask(labels["f2.png"])
    assert polygon[10:40, 10:50].all() and polygon.sum() == 40 * 30  # pycocotools' own fill
    assert labels["f4.png"] is None and "evil.png" not in labels
    frame = next(f for f, _ in stored_labels(client, token) if f["original_name"] == "f2.png")
    manual = client.get(f"/api/v1/frames/{frame['id']}/validation-keypoints", headers=auth(token))
    assert manual.json()["keypoints"] == [[12.0, 12.0], [48.0, 38.0]]  # hand-placed elsewhere


def test_labelme_files_with_their_images_beside_or_inside(client, make_user) -> None:
    _, token = make_user("labelme", Role.annotator)
    part = np.zeros((8, 10), bool)
    part[2:6, 3:8] = True
    shapes = [
        {
            "label": "weld_pool",
            "shape_type": "polygon",
            "points": [[10, 10], [40, 10], [40, 30], [10, 30]],
        },
        {
            "label": "weld_pool",
            "shape_type": "mask",
            "points": [[60, 40], [69, 47]],
            "mask": base64.b64encode(encode_mask_png(part)).decode(),
        },
        {"label": "weld_pool", "shape_type": "point", "points": [[20, 20]]},
    ]
    beside = {"shapes": shapes, "imagePath": "a.png", "imageHeight": H, "imageWidth": W}
    inside = {
        "shapes": [{"label": "weld_pool", "points": [[5, 5], [20, 5], [20, 20]]}],
        "imagePath": "elsewhere/b.png",
        "imageData": base64.b64encode(image_bytes(W, H, seed=42)).decode(),
    }
    line = {
        "shapes": [{"label": "weld_pool", "shape_type": "line", "points": [[1, 1], [9, 9]]}],
        "imagePath": "c.png",
    }
    files = {
        "a.json": json.dumps(beside).encode(),
        "a.png": image_bytes(W, H, seed=41),
        "b.json": json.dumps(inside).encode(),
        "c.json": json.dumps(line).encode(),
        "c.png": image_bytes(W, H, seed=43),
        "d.json": b"{not json",
        "e.json": b"[" * 100_000 + b"]" * 100_000,  # too deep to parse (the job failed)
    }
    result = start_import(client, token, zipped(files), "labelme")["result"]
    assert _reasons(result) == {
        "c.json: shape 1": "A line shape has no pool area to import.",
        "d.json": "The file is not valid JSON.",
        "e.json": "The file is not valid JSON.",
    }
    assert result["labels"] == 2 and result["keypoints"] == 1 and result["frames"] == 2
    labels = _by_name(client, token)
    a = label_mask(labels["a.png"])
    expected = np.zeros((H, W), bool)
    expected[10:31, 10:41] = True  # the polygon through pixel centres, edges included
    expected[42:46, 63:68] = True  # the mask shape at its box's corner
    assert (a == expected).all()
    assert label_mask(labels["b.png"]).sum() > 0


def test_cvat_rle_is_the_box_row_by_row_starting_with_zeros() -> None:
    box = np.array([[0, 1, 1], [1, 0, 0]], bool)
    assert to_cvat_rle(box) == [1, 3, 2]
    assert to_cvat_rle(~box) == [0, 1, 3, 2]
    assert (cvat_rle([1, 3, 2], 3, 2) == box).all()
    rng = np.random.default_rng(0)
    for _ in range(20):
        pixels = rng.random((rng.integers(1, 9), rng.integers(1, 9))) > 0.5
        h, w = pixels.shape
        assert (cvat_rle(to_cvat_rle(pixels), w, h) == pixels).all()


def test_cvat_and_yolo_refusals_are_one_sentence_each(client, make_user) -> None:
    _, token = make_user("cvat", Role.annotator)
    xml = b"""<?xml version="1.0"?><annotations><version>1.1</version>
      <image id="0" name="x.png" width="96" height="64">
        <polygon label="weld_pool" points="10,10;40,10;40,30"/>
        <polyline label="weld_pool" points="1,1;5,5"/>
      </image>
      <image id="1" name="y.png" width="96" height="64">
        <mask label="weld_pool" rle="3, 4" left="0" top="0" width="3" height="3"/>
      </image>
      <image id="2" name="z.png" width="96" height="64">
        <box label="weld_pool" xtl="10" ytl="10" xbr="20" ybr="30"/>
        <skeleton label="weld_pool">
          <points label="front" points="12.5,15"/><points label="back" points="18,25"/>
          <points label="gone" outside="1" points="0,0"/>
        </skeleton>
      </image></annotations>"""
    bomb = b"""<?xml version="1.0"?><!DOCTYPE a [<!ENTITY a "aaaaaaaaaa">
      <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]><annotations>&b;</annotations>"""
    files = {"annotations.xml": xml, "z.png": image_bytes(W, H, seed=5)}
    files |= {"x.png": image_bytes(W, H, seed=3), "y.png": image_bytes(W, H, seed=4)}
    result = start_import(client, token, zipped(files), "cvat")["result"]
    assert _reasons(result) == {
        "annotations.xml: x.png <polyline>": "A <polyline> has no pool area to import.",
        "annotations.xml: y.png <mask>": "The mask's runs cover 7 pixels, not its 3×3 box.",
    }
    assert result["labels"] == 1 and result["keypoints"] == 1
    frame = next(f for f, _ in stored_labels(client, token) if f["original_name"] == "z.png")
    manual = client.get(f"/api/v1/frames/{frame['id']}/validation-keypoints", headers=auth(token))
    assert manual.json()["keypoints"] == [[12.5, 15.0], [18.0, 25.0]]  # the skeleton's, in order
    box = label_mask(_by_name(client, token)["z.png"])
    assert box.sum() == 10 * 20 and box[10:30, 10:20].all()  # CVAT's corners, as CVAT fills
    entity = start_import(client, token, bomb, "cvat", name="bomb.xml")["result"]
    assert entity["refused"] == [
        {
            "item": "bomb.xml",
            "reason": "The XML declares entities, which a CVAT file never does; it is not read.",
        }
    ]
    yolo = {
        "images/train/p.png": image_bytes(W, H, seed=6),
        "labels/train/p.txt": b"0 0.5 0.5 0.2 0.2\n",
        "images/train/q.png": image_bytes(W, H, seed=7),
        "labels/train/q.txt": b"0 0.1 0.1 0.5 0.1 0.5 0.5\n1 0.1 0.1 0.2 0.1 0.2 0.2\n",
        "labels/train/r.txt": b"0 0.1 0.1 0.5 0.1 0.5 0.5\n",
        "data.yaml": b"names:\n  0: weld_pool\n  1: spatter\n",
    }
    result = start_import(client, token, zipped(yolo), "yolo")["result"]
    assert _reasons(result) == {
        "labels/train/p.txt": "Line 1 is a box, not a polygon; export segments.",
        "labels/train/r.txt": "It has no image of the same stem under images/.",
    }
    assert result["classes"]["unknown"] == {"spatter": 1}  # q's pool is kept, its spatter counted


def test_a_zip_bomb_entry_is_not_read(client, make_user) -> None:
    _, token = make_user("bomber", Role.annotator)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("masks/a.png", b"\0" * (64 * 1024 * 1024))
        archive.writestr("images/a.png", image_bytes(W, H, seed=1))
    result = start_import(client, token, buffer.getvalue(), "masks", name="m.zip")["result"]
    assert [r["item"] for r in result["refused"]] == ["masks/a.png", "m.zip"]
    assert (
        result["refused"][0]["reason"]
        == "The file is compressed 1,029× (a zip bomb?); it is not read."
    )
    assert result["refused"][1]["reason"] == "No masks (masks/<stem>.png) were found."


@pytest.mark.parametrize(
    ("form", "file", "status", "detail"),
    [
        (
            {"format": "pascal"},
            b"{}",
            400,
            "format must be one of coco, yolo, masks, labelme, cvat.",
        ),
        (
            {"format": "yolo"},
            b"{}",
            400,
            "A yolo import is a zip of its folders; the file is not a zip.",
        ),
        ({"format": "coco"}, b"", 400, "The file is empty."),
        ({"format": "coco", "sequence_id": "12345"}, b"{}", 404, "There is no sequence 12345."),
        ({"format": "coco", "overwrite": "maybe"}, b"{}", 400, "overwrite must be true or false."),
        (
            {"format": "coco"},
            None,
            400,
            "The request has no `file` part; attach one zip or annotation file.",
        ),
    ],
)
def test_an_import_that_cannot_start_is_a_clear_4xx(
    client, make_user, form, file, status, detail
) -> None:
    _, token = make_user("hasty", Role.annotator)
    files = (
        {"file": ("a.json", file, "application/json")} if file is not None else {"x": ("x", b"1")}
    )
    response = client.post("/api/v1/labels/import", data=form, files=files, headers=auth(token))
    assert response.status_code == status and response.json()["detail"] == detail


def test_a_batch_that_fails_leaves_no_label_and_no_mask_file(
    client, make_user, settings, session_factory, monkeypatch
) -> None:
    _, token = make_user("unlucky", Role.annotator)
    files = {f"images/{i}.png": image_bytes(W, H, seed=60 + i) for i in range(3)}
    square = np.zeros((H, W), bool)
    square[5:20, 5:20] = True
    files |= {f"masks/{i}.png": encode_mask_png(square | (np.arange(W) == i)) for i in range(3)}
    from app.imports import service

    calls = []
    real = service.write_label

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise OSError("disk full")
        return real(*args, **kwargs)

    monkeypatch.setattr(service, "write_label", failing)
    response = client.post(
        "/api/v1/labels/import",
        data={"format": "masks"},
        files={"file": ("m.zip", zipped(files), "application/zip")},
        headers=auth(token),
    )
    job = wait_for_job(client, response.json()["job_id"], token)
    assert job["status"] == "failed"
    with session_factory() as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Label)) == 0
        assert session.scalar(sa.select(sa.func.count()).select_from(LabelRevision)) == 0
        assert session.scalar(sa.select(sa.func.count()).select_from(Frame)) == 3  # an upload's
    masks = settings.home / "artefacts"  # where mask PNGs are stored
    assert not masks.exists() or not any(p.is_file() for p in masks.rglob("*"))
    assert not any((settings.home / "imports").iterdir())  # the upload is gone too


def test_one_annotation_file_labels_the_frames_already_stored_by_name(client, make_user) -> None:
    """The contract's single-file import: a COCO file alone, whose images were uploaded before;
    a name is matched within the run given, or anywhere when only one frame has it."""
    _, token = make_user("later", Role.annotator)
    runs = [
        client.post("/api/v1/sequences", json={"name": n}, headers=auth(token)).json()["id"]
        for n in ("left", "right")
    ]
    for seed, run in enumerate(runs):
        files = [
            ("files", ("shared.png", image_bytes(W, H, seed=500 + seed), "image/png")),
            ("files", (f"only-{seed}.png", image_bytes(W, H, seed=510 + seed), "image/png")),
        ]
        stored = client.post(
            "/api/v1/frames", data={"sequence_id": run}, files=files, headers=auth(token)
        )
        assert stored.status_code == 201, stored.text
    box = [[10, 10, 40, 10, 40, 30, 10, 30]]
    names = ["shared.png", "only-1.png", "missing.png"]
    coco = {
        "images": [{"id": i, "file_name": n, "width": W, "height": H} for i, n in enumerate(names)],
        "annotations": [
            {"id": i, "image_id": i, "category_id": 7, "segmentation": box}
            for i in range(len(names))
        ],
        "categories": [{"id": 7, "name": "pool"}],
    }
    data = json.dumps(coco).encode()
    anywhere = start_import(client, token, data, "coco", name="later.json")["result"]
    assert _reasons(anywhere) == {
        "later.json: shared.png": "More than one stored frame is named 'shared.png'; import "
        "into one sequence.",
        "later.json: missing.png": "The image 'missing.png' is neither in the import nor "
        "stored here.",
    }
    assert anywhere["labels"] == 1 and anywhere["frames"] == 0  # only-1.png, in "right"
    within = start_import(client, token, data, "coco", name="later.json", sequence_id=runs[0])
    result = within["result"]
    assert result["labels"] == 1  # shared.png of "left"
    assert _reasons(result) == {
        "later.json: only-1.png": f"The image 'only-1.png' is neither in the import nor stored "
        f"here in sequence {runs[0]}.",
        "later.json: missing.png": f"The image 'missing.png' is neither in the import nor "
        f"stored here in sequence {runs[0]}.",
    }
    left = client.get(
        "/api/v1/frames",
        params={"sequence_id": runs[0], "status": "corrected"},
        headers=auth(token),
    ).json()["items"]
    assert [f["original_name"] for f in left] == ["shared.png"]


def test_a_batch_finds_its_frames_by_name_in_one_query(client, make_user) -> None:
    """An annotation file alone: its batch's frames are looked up by name in one query and
    locked in one, not one of each per label (a thousand labels were two thousand queries)."""
    from sqlalchemy.engine import Engine

    _, token = make_user("namer", Role.annotator)
    names = [f"n{i}.png" for i in range(6)]
    files = [
        ("files", (n, image_bytes(W, H, seed=600 + i), "image/png")) for i, n in enumerate(names)
    ]
    assert client.post("/api/v1/frames", files=files, headers=auth(token)).status_code == 201
    box = [[10, 10, 40, 10, 40, 30, 10, 30]]
    coco = {
        "images": [{"id": i, "file_name": n, "width": W, "height": H} for i, n in enumerate(names)],
        "annotations": [
            {"id": i, "image_id": i, "category_id": 7, "segmentation": box}
            for i in range(len(names))
        ],
        "categories": [{"id": 7, "name": "pool"}],
    }
    statements: list[str] = []

    def seen(_conn, _cursor, statement, *_args) -> None:
        statements.append(statement)

    sa.event.listen(Engine, "before_cursor_execute", seen)
    try:
        job = start_import(client, token, json.dumps(coco).encode(), "coco", name="n.json")
    finally:
        sa.event.remove(Engine, "before_cursor_execute", seen)
    assert job["result"]["labels"] == len(names)
    by_name = [s for s in statements if "frames.original_name IN" in s]
    assert len(by_name) == 1, by_name
    one_each = [
        s for s in statements if s.startswith("SELECT frames.id \nFROM frames \nWHERE frames.id = ")
    ]
    assert not one_each, one_each  # no lock (or look-up) per frame
    frame_locks = [s for s in statements if "FOR UPDATE" in s and "FROM frames" in s]
    assert len(frame_locks) <= 1  # PostgreSQL: the batch's
