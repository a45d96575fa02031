"""Exports when the store lost a frame's image or a label's mask: every format, streamed or as a
job, is a whole zip of the other frames that lists the frames it left out and why."""

from __future__ import annotations

import io
import json
import zipfile

import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Frame, Label, LabelStatus, Role
from app.demo import fill_demo
from tests.helpers import auth, wait_for_job

STEMS: dict[str, int] = {}
"""The demo frames' own names (stems) → their ids: YOLO and CVAT exports keep the names."""


def _lose_files(settings: Settings, session_factory) -> tuple[list[int], int, int, str, str]:
    """A demo; then one labelled frame's image and another's mask file are deleted. Returns
    the labelled frames, the two frames and the two lost paths."""
    with session_factory() as session:
        fill_demo(session, settings, frames=6, seed=3, progress=lambda _t: None)
        rows = session.execute(
            sa.select(Frame.id, Frame.path, Label.mask_path, Frame.original_name)
            .join(Label, Label.frame_id == Frame.id)
            .where(Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]))
            .order_by(Frame.id)
        ).all()
    (no_image, image, _, _), (no_mask, _, mask, _) = rows[0], rows[1]
    STEMS.update({row.original_name.rsplit(".", 1)[0]: row.id for row in rows})
    assert len({row.mask_path for row in rows}) == len(rows)  # each mask is its frame's alone
    (settings.home / image).unlink()
    (settings.home / mask).unlink()
    return [row.id for row in rows], no_image, no_mask, image, mask


def _check(archive: zipfile.ZipFile, labelled: list[int], left_out: dict[int, str]) -> None:
    """A valid zip holding every labelled frame's image but those left out, which
    ``skipped.txt`` names with their lost file."""
    assert archive.testzip() is None
    stems = [n.rsplit("/", 1)[1].split(".")[0] for n in archive.namelist() if "images/" in n]
    images = {int(stem) if stem.isdigit() else STEMS[stem] for stem in stems}  # id, or own name
    assert images == set(labelled) - set(left_out)
    lines = archive.read("skipped.txt").decode().splitlines()
    assert len(lines) == len(left_out)
    for line, (frame_id, path) in zip(lines, sorted(left_out.items()), strict=True):
        assert line.startswith(f"frame {frame_id}: Frame {frame_id}'s ") and path in line


def test_every_export_leaves_out_and_lists_a_frame_whose_file_is_lost(
    client: TestClient, settings, session_factory, make_user
) -> None:
    labelled, no_image, no_mask, image, mask = _lose_files(settings, session_factory)
    _, token = make_user("exporter", Role.reviewer)
    for fmt in ("masks", "coco", "yolo", "cvat"):
        # Every format reads the mask stored with the label (RLE, outlines), not its file: only
        # the image is missing (test_export_masks: a label saved before its RLE was stored).
        left_out = {no_image: image}
        answer = client.get("/api/v1/export", params={"format": fmt}, headers=auth(token))
        assert answer.status_code == 200, (fmt, answer.text)
        archive = zipfile.ZipFile(io.BytesIO(answer.content))
        _check(archive, labelled, left_out)
        if fmt == "masks":
            manifest = json.loads(archive.read("manifest.json"))
            assert [m["frame_id"] for m in manifest["frames"]] == [
                f for f in labelled if f not in left_out
            ]
            assert [s["frame_id"] for s in manifest["skipped"]] == sorted(left_out)
        if fmt == "coco":
            coco = json.loads(archive.read("annotations.json"))
            assert len(coco["images"]) == len(coco["annotations"]) == len(labelled) - 1
        assert no_mask not in left_out and mask not in archive.read("skipped.txt").decode()
        if fmt == "cvat":
            xml = archive.read("annotations.xml").decode()
            assert f"<size>{len(labelled) - 1}</size>" in xml

    started = client.post("/api/v1/exports", json={"format": "masks"}, headers=auth(token))
    job = wait_for_job(client, started.json()["job_id"], token)
    assert job["status"] == "succeeded", job["error"]
    assert job["result"]["skipped"] == 1
    assert [s["frame_id"] for s in job["result"]["skipped_frames"]] == [no_image]
    assert "1 frame left out" in job["message"]
    download = client.get(f"/api/v1/exports/{job['id']}", headers=auth(token))
    _check(zipfile.ZipFile(io.BytesIO(download.content)), labelled, {no_image: image})
