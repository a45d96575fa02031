"""The masks layout's mask PNGs, where this machine lacks a label's file, are made from the RLE
stored with the label: the same pixels as the stored file (its bytes too, where the service
encoded it), without reading the store."""

from __future__ import annotations

import io
import zipfile

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.core import processes as core_processes
from app.core.config import Settings
from app.core.models import Label, Role
from app.review import export
from tests.helpers import auth, corrected_label, image_bytes

SIZES = [(100, 160), (77, 131), (64, 64), (120, 90)]


def random_mask(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A few blobs with holes cut out of them (oxide islands), some touching the border."""
    mask = np.zeros((height, width), np.uint8)
    for _ in range(int(rng.integers(1, 4))):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        axes = (int(rng.integers(5, width // 2)), int(rng.integers(5, height // 2)))
        cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    for _ in range(int(rng.integers(1, 6))):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        cv2.circle(mask, centre, int(rng.integers(1, 8)), 0, -1)
    mask[rng.random((height, width)) < 0.01] ^= 1  # lone pixels and pinholes
    mask[height // 2, width // 2] = 1  # never empty
    return mask.astype(bool)


def _labelled(client: TestClient, token: str, count: int) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(57)
    masks = {}
    for index in range(count):
        height, width = SIZES[index % len(SIZES)]
        upload = [("files", (f"m{index}.png", image_bytes(width, height, seed=index), "image/png"))]
        answer = client.post("/api/v1/frames", files=upload, headers=auth(token))
        frame_id = answer.json()["stored"][0]["id"]
        mask = random_mask(rng, height, width)
        saved = client.put(
            f"/api/v1/frames/{frame_id}/label", json=corrected_label(mask), headers=auth(token)
        )
        assert saved.status_code == 200, saved.text
        masks[frame_id] = mask
    return masks


def _exported(client: TestClient, token: str) -> zipfile.ZipFile:
    answer = client.get("/api/v1/export", params={"format": "masks"}, headers=auth(token))
    assert answer.status_code == 200, answer.text
    return zipfile.ZipFile(io.BytesIO(answer.content))


def test_masks_are_made_from_the_stored_rle_pixel_for_pixel_without_reading_the_files(
    client: TestClient, settings: Settings, session_factory, make_user
) -> None:
    _, token = make_user("masker", Role.reviewer)
    masks = _labelled(client, token, 12)
    with session_factory() as session:
        paths = {
            r.frame_id: r.mask_path
            for r in session.execute(sa.select(Label.frame_id, Label.mask_path))
        }
    stored = {f: (settings.home / paths[f]).read_bytes() for f in masks}
    copied = _exported(client, token)  # the files are here: copied
    for path in paths.values():  # not on this machine (a cold cache): made from the RLE
        (settings.home / path).unlink()
    archive = _exported(client, token)
    assert "skipped.txt" not in archive.namelist()
    for frame_id, mask in masks.items():
        exported = archive.read(f"masks/{frame_id:07d}.png")
        pixels = cv2.imdecode(np.frombuffer(exported, np.uint8), cv2.IMREAD_UNCHANGED)
        original = cv2.imdecode(np.frombuffer(stored[frame_id], np.uint8), cv2.IMREAD_UNCHANGED)
        assert pixels.dtype == np.uint8 and pixels.shape == mask.shape
        assert np.array_equal(pixels, original)  # pixel for pixel, holes and all
        assert np.array_equal(pixels == 255, mask) and set(np.unique(pixels)) <= {0, 255}
        assert exported == stored[frame_id]  # the service encoded both: the same bytes
        assert copied.read(f"masks/{frame_id:07d}.png") == stored[frame_id]


def test_a_label_saved_before_its_rle_has_its_file_copied_or_is_left_out_when_lost(
    client: TestClient, settings: Settings, session_factory, make_user
) -> None:
    _, token = make_user("older", Role.reviewer)
    masks = _labelled(client, token, 3)
    first, second, third = masks
    with session_factory() as session:
        session.execute(
            sa.update(Label).where(Label.frame_id.in_([first, second])).values(mask_rle=None)
        )
        session.execute(  # a damaged RLE: the file says what the mask is
            sa.update(Label)
            .where(Label.frame_id == third)
            .values(mask_rle={"size": [1, 1], "counts": "0"})
        )
        session.commit()
        lost = session.scalars(sa.select(Label.mask_path).where(Label.frame_id == second)).one()
    (settings.home / lost).unlink()
    archive = _exported(client, token)
    for frame_id in (first, third):
        exported = archive.read(f"masks/{frame_id:07d}.png")
        pixels = cv2.imdecode(np.frombuffer(exported, np.uint8), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(pixels == 255, masks[frame_id])
    assert f"masks/{second:07d}.png" not in archive.namelist()
    skipped = archive.read("skipped.txt").decode()
    assert skipped.startswith(f"frame {second}: ") and lost in skipped


@pytest.mark.parametrize("processes", ["running", "not started"])
def test_the_pngs_made_in_the_processes_are_the_stored_files_in_order(
    client: TestClient,
    settings: Settings,
    session_factory,
    make_user,
    monkeypatch: pytest.MonkeyPatch,
    processes: str,
) -> None:
    """A cold masks export makes its PNGs in the service's processes a few tasks ahead of the
    writer (or in its thread for a small export): each frame gets its own mask's file, byte for
    byte, even where a frame between them is left out; a damaged RLE whose file is lost too
    leaves its frame out."""
    _, token = make_user(f"cold-{processes.replace(' ', '-')}", Role.reviewer)
    masks = _labelled(client, token, 11)
    ids = sorted(masks)
    with session_factory() as session:
        paths = {
            r.frame_id: r.mask_path
            for r in session.execute(sa.select(Label.frame_id, Label.mask_path))
        }
        session.execute(  # frame 4: a damaged RLE, and (below) its file lost
            sa.update(Label)
            .where(Label.frame_id == ids[4])
            .values(mask_rle={"size": [1, 1], "counts": "0"})
        )
        session.commit()
    stored = {f: (settings.home / paths[f]).read_bytes() for f in ids}
    for path in paths.values():
        (settings.home / path).unlink()
    monkeypatch.setattr(export, "POOL_CHUNK", 3)
    monkeypatch.setattr(export, "POOL_PROCESS_MIN", 1 if processes == "running" else 10**6)
    archive = _exported(client, token)
    assert core_processes.started() or processes == "not started"
    for frame_id in ids:
        name = f"masks/{frame_id:07d}.png"
        if frame_id == ids[4]:
            assert name not in archive.namelist()
        else:
            assert archive.read(name) == stored[frame_id]
    assert archive.read("skipped.txt").decode().startswith(f"frame {ids[4]}: ")
