"""Exports carry the label configuration's classes and the images' own names: COCO, YOLO and
CVAT exported by one instance and imported into a fresh one keep each frame's pool and its
objects; names stay unique within an export, deterministically."""

from __future__ import annotations

import io
import zipfile
from types import SimpleNamespace

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.db import create_db_engine, create_session_factory
from app.core.models import Role
from app.core.schema import migrate
from app.main import create_app
from app.review.export_classes import file_names
from tests.helpers import auth, corrected_label, image_bytes, make_settings, mask_b64
from tests.imports.common import H, W, label_mask, start_import, stored_labels, token_for
from weldpool_core.outline import rle_mask

CONFIG = {
    "version": 0,
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#00aaff"},
        {
            "name": "spatter",
            "kind": "instances",
            "attributes": [{"name": "size", "type": "choice", "options": ["small", "large"]}],
        },
    ],
}


def _box(top: int, bottom: int, left: int, right: int) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[top:bottom, left:right] = True
    return mask


POOL = _box(10, 40, 10, 50)
WIRE = _box(0, 8, 60, 90)
SPATTER = [_box(50, 56, 5, 12), _box(50, 60, 70, 80)]


def _frame(name: str, frame_id: int, path: str = "frames/ab.png") -> SimpleNamespace:
    return SimpleNamespace(id=frame_id, original_name=name, path=path)


def test_file_names_are_the_frames_own_and_unique_by_stem() -> None:
    frames = [
        _frame("run-a/weld_1.png", 7),
        _frame("weld_1.png", 3),  # the lower id keeps the name
        _frame("WELD_1.png", 9),  # ignoring case
        _frame("weld_1.jpg", 12, "frames/cd.jpg"),  # same stem: a YOLO label file each
        _frame("", 5),
        _frame("clip.mp4", 6),  # a video's frame: the stored file's extension is added
        _frame("weld_1-7.png", 2),  # the name a later duplicate would take
    ]
    assert file_names(frames) == {  # type: ignore[arg-type]
        2: "weld_1-7.png",
        3: "weld_1.png",
        5: "0000005.png",
        6: "clip.mp4.png",
        7: "weld_1-7-2.png",
        9: "WELD_1-9.png",
        12: "weld_1-12.jpg",
    }


def _exported(tmp_path, fmt: str) -> tuple[bytes, dict[str, int]]:
    """A SQLite instance with the configuration and two labelled frames (one with a wire and
    two spatters), exported in ``fmt``; and the frames' names."""
    home = tmp_path / "source"
    settings = make_settings(home, database_url=f"sqlite:///{home / 'source.sqlite3'}")
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    _, token = token_for(create_session_factory(engine), "ada", Role.admin)
    with TestClient(create_app(settings, embedded_worker=True)) as client:
        assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(token)).is_success
        names = ["run7 0001.png", "run7 0002.png"]
        files = [
            ("files", (n, image_bytes(W, H, seed=80 + i), "image/png")) for i, n in enumerate(names)
        ]
        stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
        ids = {f["original_name"]: f["id"] for f in stored}
        objects = [{"class": "wire", "mask_png": mask_b64(WIRE)}] + [
            {"class": "spatter", "mask_png": mask_b64(m), "attributes": {"size": size}}
            for m, size in zip(SPATTER, ["small", "large"], strict=True)
        ]
        body = corrected_label(POOL) | {"objects": objects}
        saved = client.put(f"/api/v1/frames/{ids[names[0]]}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
        plain = client.put(
            f"/api/v1/frames/{ids[names[1]]}/label", json=corrected_label(POOL), headers=auth(token)
        )
        assert plain.status_code == 200
        response = client.get("/api/v1/export", params={"format": fmt}, headers=auth(token))
        assert response.status_code == 200, response.text
    engine.dispose()
    return response.content, ids


@pytest.mark.parametrize("fmt", ["coco", "yolo", "cvat"])
def test_a_round_trip_keeps_the_pool_and_the_objects(
    client, session_factory, tmp_path, fmt
) -> None:
    archive, _ = _exported(tmp_path, fmt)
    names = zipfile.ZipFile(io.BytesIO(archive)).namelist()
    if fmt == "yolo":
        assert "images/train/run7 0001.png" in names and "labels/train/run7 0001.txt" in names
        data = zipfile.ZipFile(io.BytesIO(archive)).read("data.yaml").decode()
        assert "names:\n  0: weld_pool\n  1: wire\n  2: spatter\n" in data
    if fmt == "cvat":
        assert "images/run7 0001.png" in names  # the task's frames are matched by name
    _, token = token_for(session_factory, "bea", Role.admin)
    assert client.put("/api/v1/label-config", json=CONFIG, headers=auth(token)).is_success
    result = start_import(client, token, archive, fmt)["result"]
    assert result["refused"] == [] and result["labels"] == 2
    assert result["classes"]["kept"] == {"spatter": 2, "wire": 1}
    labels = {frame["original_name"]: label for frame, label in stored_labels(client, token)}
    assert set(labels) == {"run7 0001.png", "run7 0002.png"}
    first = labels["run7 0001.png"]
    assert np.array_equal(label_mask(first), POOL)
    assert [o["class"] for o in first["objects"]] == ["wire", "spatter", "spatter"]
    kept = [rle_mask(o["rle"]) for o in first["objects"]]
    for got, sent in zip(kept, [WIRE, *SPATTER], strict=True):
        assert np.array_equal(got, sent), fmt  # boxes: exact in every format
    assert labels["run7 0002.png"]["objects"] == []
    sizes = [o.get("attributes", {}).get("size") for o in first["objects"]]
    assert sizes == ([None] * 3 if fmt == "yolo" else [None, "small", "large"])  # not YOLO
