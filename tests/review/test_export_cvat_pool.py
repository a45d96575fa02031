"""The CVAT export builds every mask it writes — the pool's in the service's processes, the
other classes' objects' in the readers' pool — from the RLE stored over each box, never in the
thread writing the zip; the masks it writes are those of the whole frame, and its XML is byte
for byte the one made label by label in one thread (the writer before the processes)."""

from __future__ import annotations

import io
import threading
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from app.core import processes as core_processes
from app.core.models import Frame, Label, LabelStatus, Split
from app.review import export
from app.review.export_classes import Rows, cvat_objects
from app.storage import LocalStorage, Storage
from tests.helpers import image_bytes
from weldpool_core.annotations import cvat
from weldpool_core.annotations.shapes import cvat_rle
from weldpool_core.io import encode_png
from weldpool_core.outline import coco_mask


def _rows(storage: Storage, count: int) -> tuple[Rows, list[tuple[np.ndarray, np.ndarray]]]:
    """``count`` labelled 64×48 frames, each with a pool and one ``spatter`` object; every
    third label saved before its RLE was stored (its mask read from its PNG)."""
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
        if index % 3 == 2:
            label.mask_path = storage.put(encode_png(pool * 255), f"{index:064x}", ".png").path
            label.mask_rle = label.mask_area = label.mask_bbox = None
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

    monkeypatch.setattr(cvat, "cvat_rle_mask", recorded)  # this process's: the objects'
    monkeypatch.setattr(export, "POOL_CHUNK", 5)  # the pools: 16 stored, four tasks
    monkeypatch.setattr(export, "POOL_PROCESS_MIN", 16)
    data = b"".join(export.stream_export(storage, "cvat", rows))  # written in this thread
    assert built_in and threading.get_ident() not in built_in
    assert core_processes.started()
    document = ET.fromstring(zipfile.ZipFile(io.BytesIO(data)).read("annotations.xml"))
    images = document.findall("image")
    assert len(images) == len(masks)
    for image, (pool, spatter) in zip(images, masks, strict=True):
        found = {m.get("label"): _mask(m) for m in image.findall("mask")}
        assert np.array_equal(found["weld_pool"], pool)
        assert np.array_equal(found["spatter"], spatter)


def _reference_xml(storage: Storage, rows: Rows) -> bytes:
    """The CVAT document as the export made it before its pools' masks went to processes:
    label by label, in one thread."""
    names = export.file_names([row[0] for row in rows])
    elements = []
    for frame, label, _, _ in rows:
        if label.mask_rle is not None:
            mask = cvat.cvat_rle_mask(label.mask_rle, label.mask_bbox)
        else:
            mask = cvat.cvat_mask(export.load_mask(storage, label.mask_path))
        image = cvat.CvatImage(
            id=len(elements),
            name=names[frame.id],
            width=frame.width,
            height=frame.height,
            mask=mask,
            keypoints=label.keypoints,
            validation_keypoints=None,
            objects=cvat_objects(label, rows),
            tags=export.frame_fields(label)["tags"],
        )
        elements.append(cvat.cvat_image(image))
    return cvat.cvat_document(elements, len(elements), export.cvat_labels(rows))


class _Broken:
    """A process pool whose processes died: every task's future raises."""

    def submit(self, function, task):  # type: ignore[no-untyped-def]
        from concurrent.futures import Future
        from concurrent.futures.process import BrokenProcessPool

        future: Future[list[object]] = Future()
        future.set_exception(BrokenProcessPool("a process died"))
        return future


def _never() -> None:
    pytest.fail("the processes were started for a few masks")


def _refused() -> None:
    raise OSError("cannot start a process")


@pytest.mark.parametrize("processes", ["running", "broken", "not startable", "few"])
def test_the_cvat_xml_is_the_one_made_label_by_label(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, processes: str
) -> None:
    """Processes, or this thread where they cannot work: the same bytes, in the rows' order
    (pools of labels with and without a stored RLE interleaved)."""
    storage = LocalStorage(tmp_path)
    rows, _ = _rows(storage, 23)
    monkeypatch.setattr(export, "POOL_CHUNK", 3)  # more tasks than are sent ahead
    monkeypatch.setattr(export, "POOL_PROCESS_MIN", 100 if processes == "few" else 1)
    if processes == "few":  # fewer than start the processes: made here, none started
        monkeypatch.setattr(core_processes, "started", lambda: False)
        monkeypatch.setattr(core_processes, "process_pool", _never)
    if processes == "broken":
        monkeypatch.setattr(core_processes, "process_pool", _Broken)
    if processes == "not startable":
        monkeypatch.setattr(core_processes, "process_pool", _refused)
    data = b"".join(export.stream_export(storage, "cvat", rows))
    written = zipfile.ZipFile(io.BytesIO(data)).read("annotations.xml")
    assert written == _reference_xml(storage, rows)
