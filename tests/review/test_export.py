"""Exports of reviewed labels (COCO and the DATASET layout), the demo, and `weldpool export`."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Role
from app.demo import fill_demo
from tests.helpers import auth, run_cli
from weldpool_core.io import decode_mask_png


def _demo(settings: Settings, session_factory, frames: int = 8) -> str:
    with session_factory() as session:
        return fill_demo(session, settings, frames=frames, seed=3, progress=lambda _t: None)


def test_demo_then_masks_export_in_the_dataset_layout(
    client, settings, session_factory, make_user
) -> None:
    summary = _demo(settings, session_factory)
    assert "8 frames; 6 labelled from ground truth, 2 of them held out for validation" in summary
    assert "Teacher job" in summary  # the tiny teacher's weights are configured here
    _, token = make_user("exporter", Role.annotator)
    response = client.get("/api/v1/export", params={"format": "masks"}, headers=auth(token))
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/zip"
    archive = zipfile.ZipFile(io.BytesIO(response.content))
    names = archive.namelist()
    images = sorted(n for n in names if n.startswith("images/"))
    assert len(images) == 6  # the held-out frames too: their masks are labels
    for image in images:
        stem = Path(image).stem
        mask = decode_mask_png(archive.read(f"masks/{stem}.png"))
        assert mask.shape == (800, 1280) and mask.any()
        assert len(json.loads(archive.read(f"keypoints/{stem}.json"))["keypoints"]) == 4
    manifest = json.loads(archive.read("manifest.json"))["frames"]
    assert {m["label"] for m in manifest} == {"accepted"}
    process = manifest[0]["process"]  # the weld run's parameters travel with the masks too
    assert process["voltage_v"] == 22.5 and process["joint_type"] == "fillet"
    leftovers = [p for p in (settings.home / "tmp").glob("*.zip")]
    assert leftovers == []  # the temporary zip is removed after sending


def test_coco_export_carries_process_parameters(
    client, settings, session_factory, make_user
) -> None:
    _demo(settings, session_factory, frames=4)
    _, token = make_user("cocoa", Role.annotator)
    response = client.get("/api/v1/export", params={"format": "coco"}, headers=auth(token))
    coco = json.loads(zipfile.ZipFile(io.BytesIO(response.content)).read("annotations.json"))
    assert len(coco["images"]) == len(coco["annotations"]) == 3
    image, annotation = coco["images"][0], coco["annotations"][0]
    assert image["process"]["voltage_v"] == 22.5 and image["process"]["joint_type"] == "fillet"
    assert annotation["num_keypoints"] == 4 and len(annotation["keypoints"]) == 12
    _, _, w, h = annotation["bbox"]
    assert w > 0 and h > 0 and annotation["area"] > 0
    assert annotation["segmentation"]["size"] == [800, 1280]
    assert coco["categories"][0]["keypoints"] == [f"keypoint_{i}" for i in range(1, 5)]


def test_coco_masks_read_back_exactly_with_their_holes(
    client, settings, session_factory, make_user
) -> None:
    """A reviewed mask with a hole (an oxide island the reviewer cut out) comes back from the
    COCO file, read by pycocotools' own API, pixel for pixel; area and box match it."""
    from pycocotools.coco import COCO

    from tests.helpers import corrected_label, image_bytes

    _, token = make_user("holes", Role.reviewer)
    upload = [("files", ("h.png", image_bytes(160, 100, seed=9), "image/png"))]
    frame_id = client.post("/api/v1/frames", files=upload, headers=auth(token)).json()["stored"][0][
        "id"
    ]
    mask = np.zeros((100, 160), bool)
    mask[20:80, 30:130] = True
    mask[40:60, 60:90] = False  # the hole
    saved = client.put(
        f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
    )
    assert saved.status_code == 200
    response = client.get("/api/v1/export", params={"format": "coco"}, headers=auth(token))
    path = settings.home / "coco.json"
    path.write_bytes(zipfile.ZipFile(io.BytesIO(response.content)).read("annotations.json"))
    coco = COCO(str(path))
    annotation = coco.loadAnns(coco.getAnnIds(imgIds=[frame_id]))[0]
    back = coco.annToMask(annotation).astype(bool)
    assert np.array_equal(back, mask)
    assert annotation["area"] == int(mask.sum()) == 100 * 60 - 30 * 20
    assert annotation["bbox"] == [30, 20, 100, 60]


def test_nothing_to_export_is_a_clear_400(client: TestClient, make_user) -> None:
    _, token = make_user("empty", Role.annotator)
    response = client.get("/api/v1/export", headers=auth(token))
    assert response.status_code == 400
    assert response.json()["detail"] == "There are no accepted or corrected labels to export."
    bad = client.get("/api/v1/export", params={"format": "pascal"}, headers=auth(token))
    assert bad.status_code == 422


def test_command_line_export(settings: Settings, session_factory, tmp_path: Path) -> None:
    _demo(settings, session_factory, frames=4)
    env = {
        "WELDPOOL_HOME": str(settings.home),
        "WELDPOOL_DATABASE_URL": settings.resolved_database_url,
    }
    out = tmp_path / "export" / "labels.zip"
    result = run_cli("export", "--out", out, "--sequence", "demo weld run (synthetic)", env=env)
    assert result.returncode == 0, result.stderr
    assert len([n for n in zipfile.ZipFile(out).namelist() if n.startswith("masks/")]) == 3
    missing = run_cli("export", "--out", out, "--sequence", "nope", env=env)
    assert missing.returncode == 2 and "There is no sequence named 'nope'." in missing.stderr


def test_yolo_export_as_a_job_reads_back_as_the_masks(
    client, settings, session_factory, make_user
) -> None:
    """`POST /exports` runs the export as a job with progress; its zip is the Ultralytics YOLO
    segmentation layout: one polygon line per region, x over the width and y over the height,
    frames in the folder of their split; filled back, the polygons are the reviewed masks."""
    import cv2

    from tests.helpers import corrected_label, image_bytes, wait_for_job

    _, token = make_user("yolo", Role.reviewer)
    masks = {}
    for seed in range(2):
        upload = [("files", (f"y{seed}.png", image_bytes(160, 100, seed=20 + seed), "image/png"))]
        response = client.post("/api/v1/frames", files=upload, headers=auth(token))
        frame_id = response.json()["stored"][0]["id"]
        mask = np.zeros((100, 160), bool)
        mask[20:80, 30:130] = True  # wider than high: a swapped x / y shows
        if seed == 1:
            mask[5:15, 140:155] = True  # a second region: a second line
        masks[frame_id] = mask
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200
    first, second = masks
    moved = client.put(
        f"/api/v1/frames/{second}/validation-keypoints",
        json={"keypoints": [[40, 30], [120, 30], [120, 70], [40, 70]]},
        headers=auth(token),
    )
    assert moved.status_code == 200

    started = client.post("/api/v1/exports", json={"format": "yolo"}, headers=auth(token))
    assert started.status_code == 202, started.text
    job = wait_for_job(client, started.json()["job_id"], token)
    assert job["status"] == "succeeded" and job["progress"] == 1.0
    assert job["message"].startswith("yolo export ready")
    response = client.get(f"/api/v1/exports/{job['id']}", headers=auth(token))
    assert response.status_code == 200
    archive = zipfile.ZipFile(io.BytesIO(response.content))
    data = archive.read("data.yaml").decode()
    assert "train: images/train" in data and "val: images/val" in data and "0: weld_pool" in data
    assert "test:" not in data
    for frame_id, split in ((first, "train"), (second, "val")):
        stem = f"y{list(masks).index(frame_id)}"  # the image's own name (y0.png, y1.png)
        assert f"images/{split}/{stem}.png" in archive.namelist()
        lines = archive.read(f"labels/{split}/{stem}.txt").decode().splitlines()
        assert len(lines) == (1 if frame_id == first else 2)
        back = np.zeros((100, 160), np.uint8)
        for line in lines:
            cls, *values = line.split()
            assert cls == "0" and all(0.0 <= float(v) <= 1.0 for v in values)
            xy = np.array(values, float).reshape(-1, 2) * [160, 100] - 0.5
            cv2.fillPoly(back, [np.rint(xy).astype(np.int32)], 1)
        mask = masks[frame_id]
        assert (back.astype(bool) & mask).sum() / (back.astype(bool) | mask).sum() > 0.97

    # Labels saved before their outlines were stored trace the mask decoded from their RLE,
    # and those saved before that the mask PNG: the same lines either way.
    from app.core.models import Label

    def yolo_labels() -> dict[str, bytes]:
        got = client.get("/api/v1/export", params={"format": "yolo"}, headers=auth(token))
        files = zipfile.ZipFile(io.BytesIO(got.content))
        return {n: files.read(n) for n in files.namelist() if n.startswith("labels/")}

    written = yolo_labels()
    assert written == {n: archive.read(n) for n in archive.namelist() if n.startswith("labels/")}
    for forgotten in ({"mask_outlines": None}, {"mask_rle": None}):
        with session_factory() as session:
            session.execute(sa.update(Label).values(**forgotten))
            session.commit()
        assert yolo_labels() == written, forgotten
    # …and stored outlines are what the export writes (a triangle stored in place of one).
    with session_factory() as session:
        session.execute(
            sa.update(Label)
            .where(Label.frame_id == first)
            .values(mask_outlines=[[[0, 0], [159, 0], [0, 99]]])
        )
        session.commit()
    triangle = yolo_labels()["labels/train/y0.txt"].decode()
    assert triangle == "0 0.003125 0.005000 0.996875 0.005000 0.003125 0.995000\n"

    assert client.get("/api/v1/exports/999999", headers=auth(token)).status_code == 404
    other = client.post(
        "/api/v1/teacher/runs", json={"frame_ids": [first]}, headers=auth(token)
    ).json()
    wrong_kind = client.get(f"/api/v1/exports/{other['job_id']}", headers=auth(token))
    assert wrong_kind.status_code == 404 and "no export job" in wrong_kind.json()["detail"]
    empty = client.post(
        "/api/v1/exports", json={"format": "coco", "split": "test"}, headers=auth(token)
    )
    assert empty.status_code == 400
    wait_for_job(client, other["job_id"], token)


def test_the_export_streams_frame_by_frame_without_a_temporary_file(
    client, settings, session_factory, make_user
) -> None:
    """The first frame's bytes leave before the last frame is read; nothing goes to disk."""
    _demo(settings, session_factory)
    _, token = make_user("streamer", Role.annotator)
    chunks = []
    with client.stream(
        "GET", "/api/v1/export", params={"format": "coco"}, headers=auth(token)
    ) as response:
        assert response.status_code == 200 and "content-length" not in response.headers
        assert response.headers["content-disposition"] == 'attachment; filename="weldpool-coco.zip"'
        for chunk in response.iter_raw():
            chunks.append(chunk)
            assert list((settings.home / "tmp").glob("*")) == []
    assert len(chunks) >= 4  # one or more per labelled frame, then the annotations
    archive = zipfile.ZipFile(io.BytesIO(b"".join(chunks)))
    assert archive.testzip() is None
    coco = json.loads(archive.read("annotations.json"))
    assert len(coco["images"]) == len(coco["annotations"]) == 6


def test_the_short_mask_reader_encodes_exactly_what_the_mask_reader_does() -> None:
    """COCO's RLE of a mask PNG read the short way (OpenCV, transposed) equals the RLE of the
    mask as the service reads it, for 0/255 and 0/1 PNGs, holes and edges included."""
    from weldpool_core.io import decode_mask_png, encode_png
    from weldpool_core.outline import coco_mask, coco_mask_png

    mask = np.zeros((37, 53), bool)
    mask[5:30, 0:40] = True
    mask[10:15, 10:20] = False  # a hole
    mask[36, 52] = True  # a corner pixel
    for scale in (255, 1):
        assert coco_mask_png(encode_png(mask.astype(np.uint8) * scale)) == coco_mask(mask)
    # colour and 16-bit masks, and gray levels either side of the threshold: one rule for both
    rng = np.random.default_rng(5)
    for pixels in (
        rng.integers(0, 256, (37, 53, 3), dtype=np.uint8),  # channel max, not luminance
        rng.integers(0, 65536, (37, 53), dtype=np.uint16),
        rng.choice(np.array([0, 127, 128, 255], np.uint8), (37, 53)),
    ):
        data = encode_png(pixels)
        assert coco_mask_png(data) == coco_mask(decode_mask_png(data))
    coco = coco_mask(mask)
    assert coco.area == int(mask.sum()) and coco.bbox == [0, 5, 53, 32]
    assert coco_mask(mask.T).rle != coco.rle


def test_a_label_stores_its_coco_mask_when_saved_and_the_export_reads_it(
    client, settings, session_factory, make_user
) -> None:
    """Saving a label (a drawn mask, or an accepted proposal's) stores the mask's RLE, area and
    box, and its regions' outlines; the COCO export writes the stored values (changed here in
    the database, the export follows) and encodes the mask of a label saved before they were
    stored."""
    import sqlalchemy as sa
    from pycocotools import mask as coco_api

    from app.core.models import Label, Proposal
    from app.proposals.files import store_mask
    from app.storage import LocalStorage
    from tests.helpers import corrected_label, image_bytes

    _, token = make_user("rle-reviewer", Role.reviewer)
    ids = []
    for seed in range(2):
        upload = [("files", (f"r{seed}.png", image_bytes(160, 100, seed=40 + seed), "image/png"))]
        ids.append(
            client.post("/api/v1/frames", files=upload, headers=auth(token)).json()["stored"][0][
                "id"
            ]
        )
    drawn = np.zeros((100, 160), bool)
    drawn[20:70, 30:120] = True
    drawn[40:50, 60:80] = False  # a hole
    proposed = np.zeros((100, 160), bool)
    proposed[10:30, 5:25] = True
    with session_factory() as session:
        path = store_mask(LocalStorage(settings.home), proposed)
        session.add(Proposal(frame_id=ids[1], source="teacher", model_id="t", mask_path=path))
        session.commit()
    saved = client.put(
        f"/api/v1/frames/{ids[0]}/label", json=corrected_label(drawn), headers=auth(token)
    )
    assert saved.status_code == 200, saved.text
    accepted = client.put(
        f"/api/v1/frames/{ids[1]}/label",
        json={"status": "accepted", "base_revision": 0},
        headers=auth(token),
    )
    assert accepted.status_code == 200, accepted.text

    def decode(rle: dict) -> np.ndarray:
        return coco_api.decode({**rle, "counts": rle["counts"].encode()}).astype(bool)

    with session_factory() as session:
        first = session.scalars(sa.select(Label).where(Label.frame_id == ids[0])).one()
        assert first.mask_area == int(drawn.sum()) == 50 * 90 - 10 * 20
        assert first.mask_bbox == [30, 20, 90, 50]
        assert first.mask_rle is not None and np.array_equal(decode(first.mask_rle), drawn)
        second = session.scalars(sa.select(Label).where(Label.frame_id == ids[1])).one()
        assert (second.mask_area, second.mask_bbox) == (400, [5, 10, 20, 20])
        assert second.mask_rle is not None and np.array_equal(decode(second.mask_rle), proposed)
        # …and the regions' outlines YOLO writes (pixel centres of the boundary pixels).
        assert first.mask_outlines == [[[30, 20], [30, 69], [119, 69], [119, 20]]]
        assert second.mask_outlines == [[[5, 10], [5, 29], [24, 29], [24, 10]]]
        # The export reads what is stored: change it, and the export says so.
        first.mask_area, first.mask_bbox = 1, [1, 2, 3, 4]
        # A label saved before the values were stored: the export encodes its mask.
        second.mask_rle = second.mask_area = second.mask_bbox = None
        session.commit()
    response = client.get("/api/v1/export", params={"format": "coco"}, headers=auth(token))
    assert response.status_code == 200, response.text
    coco = json.loads(zipfile.ZipFile(io.BytesIO(response.content)).read("annotations.json"))
    by_frame = {a["image_id"]: a for a in coco["annotations"]}
    assert (by_frame[ids[0]]["area"], by_frame[ids[0]]["bbox"]) == (1, [1, 2, 3, 4])
    assert np.array_equal(decode(by_frame[ids[0]]["segmentation"]), drawn)
    assert (by_frame[ids[1]]["area"], by_frame[ids[1]]["bbox"]) == (400, [5, 10, 20, 20])
    assert np.array_equal(decode(by_frame[ids[1]]["segmentation"]), proposed)
