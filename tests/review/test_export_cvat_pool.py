"""The CVAT export builds every mask it writes — the pool's and the other classes' objects' —
in the readers' pool, from the RLE stored over each box, never in the thread writing the zip;
and the masks it writes are those of the whole frame."""

from __future__ import annotations

import io
import threading
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from app.core.models import Frame, Label, LabelStatus, Split
from app.review import export
from app.review.export_classes import Rows
from app.storage import LocalStorage, Storage
from tests.helpers import image_bytes
from weldpool_core.annotations import cvat
from weldpool_core.annotations.shapes import cvat_rle
from weldpool_core.outline import coco_mask


def _rows(storage: Storage, count: int) -> tuple[Rows, list[np.ndarray]]:
    """``count`` labelled 64×48 frames, each with a pool and one ``spatter`` object."""
    frame_file = storage.put(image_bytes(seed=1), "a" * 64, ".png").path
    rows, masks = [], []
    for index in range(count):
        pool, spatter = np.zeros((48, 64), bool), np.zeros((48, 64), bool)
        pool[10 + index % 10 : 30, 5:40] = True
        pool[15:20, 10:20] = False  # a hole
        spatter[40:47, 50 + index % 10 : 63] = True  # near the frame's corner
        region, obj = coco_mask(pool), coco_mask(spatter)
        frame = Frame(
            id=index + 1,
            path=frame_file,
            original_name=f"f{index}.png",
            width=64,
            height=48,
            split=Split.train,
        )
        label = Label(
            frame_id=index + 1,
            status=LabelStatus.accepted,
            keypoints=[[12.0, 20.0]],
            mask_rle=region.rle,
            mask_area=region.area,
            mask_bbox=region.bbox,
            objects=[
                {"class": "spatter", "rle": obj.rle, "area": obj.area, "bbox": obj.bbox},
            ],
        )
        rows.append((frame, label, None, None))
        masks.append((pool, spatter))
    return Rows(rows, ["spatter"]), masks


def _mask(element: ET.Element) -> np.ndarray:
    """The frame's mask an XML ``<mask>`` holds."""
    runs = [int(v) for v in (element.get("rle") or "").split(", ")]
    left, top = int(element.get("left") or 0), int(element.get("top") or 0)
    width, height = int(element.get("width") or 0), int(element.get("height") or 0)
    whole = np.zeros((48, 64), bool)
    whole[top : top + height, left : left + width] = cvat_rle(runs, width, height)
    return whole


def test_the_cvat_masks_are_built_in_the_pool_and_are_the_whole_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    storage = LocalStorage(tmp_path)
    rows, masks = _rows(storage, 24)
    built_in: set[int] = set()
    real = cvat.cvat_rle_mask

    def recorded(*args, **kwargs):  # type: ignore[no-untyped-def]
        built_in.add(threading.get_ident())
        return real(*args, **kwargs)

    monkeypatch.setattr(cvat, "cvat_rle_mask", recorded)
    data = b"".join(export.stream_export(storage, "cvat", rows))  # written in this thread
    assert built_in and threading.get_ident() not in built_in
    document = ET.fromstring(zipfile.ZipFile(io.BytesIO(data)).read("annotations.xml"))
    images = document.findall("image")
    assert len(images) == len(masks)
    for image, (pool, spatter) in zip(images, masks, strict=True):
        found = {m.get("label"): _mask(m) for m in image.findall("mask")}
        assert np.array_equal(found["weld_pool"], pool)
        assert np.array_equal(found["spatter"], spatter)
