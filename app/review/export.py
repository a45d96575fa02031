"""Exports of the reviewed labels (accepted and corrected), as one zip file.

``masks``: the DATASET layout that ``weldpool train`` reads — ``images/<stem>.<ext>`` (the
original files), ``masks/<stem>.png`` (0 / 255), ``keypoints/<stem>.json``; manual validation
keypoints go to ``validation_keypoints/<stem>.json``; ``manifest.json`` lists every frame with
its id, sequence, split and label. ``coco``: ``annotations.json`` in COCO format (masks as
compressed RLE with ``iscrowd`` 0, so holes survive; bounding boxes, areas, keypoints; each image
record carries its weld run's process parameters) with the images beside it. ``yolo``: the
Ultralytics YOLO segmentation layout — ``data.yaml``, ``images/<split>/`` and ``labels/<split>/``
(``train``, ``val``, ``test``), one line ``0 x1 y1 x2 y2 …`` per region of the mask (polygons
from ``weldpool_core.outline.region_outlines``, coordinates 0–1 of the frame). YOLO polygons
cannot hold holes: a region's holes are left out there (COCO keeps them). ``masks`` and
``coco`` name the images by frame id, zero-padded; ``yolo`` and ``cvat`` by their original file
names, unique within the export (``export_classes.file_names``: CVAT matches a task's frames by
name); ``labelme`` too, a JSON beside each image (``export_labelme``). Every format carries the
label configuration's mask and instances classes beside the pool; all but YOLO their points
classes, attributes and the frames' tags (``export_classes``; YOLO counts them in
``notes.txt``).

``GET /export`` streams the zip as it is written (the first bytes leave after the first frame;
no temporary file, memory bounded by one entry); large sets can also run as an ``export`` job
(``POST /exports``) with progress and a download. COCO masks are decoded and RLE-encoded in a
thread pool a few frames ahead of the writer (OpenCV and pycocotools release the GIL) — only
for labels saved before their RLE, area and box were stored with them at save time. YOLO's
polygons are stored with labels too (``Label.mask_outlines``); those of labels saved before
are traced in the same pool, on masks decoded from the stored RLE (else the PNG). CVAT's
pool masks, and the masks layout's PNGs where this machine lacks a label's mask file (a cold
export from an object store GETs no mask), are made from the stored RLE in the service's
processes (``mapped_ahead``): in threads, their numpy work held the GIL against the writer.

A frame whose image, or a mask file the export must read, the store lost is left out of the zip:
``skipped.txt`` lists each such frame with what restores its file (the masks layout's
``manifest.json`` under ``skipped`` too), and an export job's result counts them.
"""

from __future__ import annotations

import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.budgets import shared_pool
from app.core.errors import InvalidInputError, MissingFile
from app.core.models import Frame, Label, LabelStatus, Sequence, Split, ValidationKeypoints
from app.core.processes import mapped_ahead
from app.frames.schemas import stored_scale
from app.frames.sequences import get_sequence
from app.review.export_classes import (
    ClassFiles,
    Rows,
    class_files,
    coco_categories,
    coco_objects,
    configured_rows,
    cvat_labels,
    cvat_objects,
    cvat_text,
    file_names,
    frame_fields,
    manifest_classes,
    written_classes,
    written_config,
    yaml_name,
    yolo_lines,
    yolo_notes,
)
from app.storage import EXPORTS_DIR, Storage
from app.storage.pixels import load_mask
from app.system.doctor import frame_file, frame_file_missing
from weldpool_core.outline import coco_mask, coco_mask_png, rle_mask, rle_mask_pngs

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

ExportFormat = Literal["coco", "masks", "yolo", "cvat", "labelme"]
YOLO_SPLITS = {"train": "train", "validation": "val", "test": "test"}
Progress = Callable[[float, str], None]
PROCESS_FIELDS = (
    "wire_feed_m_min",
    "voltage_v",
    "current_a",
    "arc_length_correction_pct",
    "robot_speed_cm_min",
    "synergic_law",
    "joint_type",
    "mm_per_px",
    "notes",
)


def process_parameters(sequence: Sequence) -> dict[str, Any]:
    """A run's process parameters as an export writes them: a number that is not finite, or a
    scale outside the physical range (a row written before the checks), as null."""
    values = {f: getattr(sequence, f) for f in PROCESS_FIELDS}
    for name, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            values[name] = None
    values["mm_per_px"] = stored_scale(values["mm_per_px"])
    return values


def export_name(job_id: int) -> str:
    """Where an export job's zip is stored (relative to the store)."""
    return f"{EXPORTS_DIR}/{job_id}.zip"


def _stem(frame: Frame) -> str:
    return f"{frame.id:07d}"


def _extension(frame: Frame) -> str:
    return Path(frame.path).suffix


def _stored_rle(storage: Storage, label: Label) -> tuple[dict[str, Any], int, list[int]]:
    """A label's mask as COCO RLE, area and box: stored with the label when it was saved, else
    (labels saved before they were stored) encoded from its mask PNG now."""
    if label.mask_rle is not None and label.mask_area is not None and label.mask_bbox:
        return label.mask_rle, label.mask_area, label.mask_bbox
    assert label.mask_path is not None  # accepted and corrected labels have a mask
    try:
        coco = coco_mask_png(storage.existing(label.mask_path).read_bytes())
    except InvalidInputError:
        coco = coco_mask(load_mask(storage, label.mask_path))  # says what is wrong with the file
    return coco.rle, coco.area, coco.bbox


def _stored_mask(storage: Storage, label: Label) -> NDArray[np.bool_]:
    """A label's mask: from the RLE stored with it when it was saved (a fifth of a PNG's
    decoding time), else from its mask PNG."""
    if label.mask_rle is not None:
        return rle_mask(label.mask_rle)
    assert label.mask_path is not None  # accepted and corrected labels have a mask
    return load_mask(storage, label.mask_path)


def _from_rle(storage: Storage, label: Label) -> bool:
    """Whether the masks layout makes a label's PNG from its stored RLE (the same pixels): where
    this machine lacks its file (a cold cache, a lost file); a file here is copied (cheaper)."""
    assert label.mask_path is not None  # accepted and corrected labels have a mask
    return label.mask_rle is not None and not storage.local(label.mask_path).is_file()


def _query(
    sequence_id: int | None, split: Split | None
) -> sa.Select[Frame, Label, Sequence, ValidationKeypoints]:
    query = (
        sa.select(Frame, Label, Sequence, ValidationKeypoints)
        .join(Label, Label.frame_id == Frame.id)
        .outerjoin(Sequence, Sequence.id == Frame.sequence_id)
        .outerjoin(ValidationKeypoints, ValidationKeypoints.frame_id == Frame.id)
        .where(Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]))
        .order_by(Frame.id)
    )
    if sequence_id is not None:
        query = query.where(Frame.sequence_id == sequence_id)
    if split is not None:
        query = query.where(Frame.split == split)
    return query


def export_size(session: Session, sequence_id: int | None, split: Split | None) -> int:
    """How many labels an export of this sequence and split holds (404 for no such run)."""
    if sequence_id is not None:
        get_sequence(session, sequence_id)
    subquery = _query(sequence_id, split).subquery()
    return session.scalar(sa.select(sa.func.count()).select_from(subquery)) or 0


def _rows(
    session: Session, sequence_id: int | None, split: Split | None
) -> list[tuple[Frame, Label, Sequence | None, ValidationKeypoints | None]]:
    return [
        (frame, label, sequence, manual)
        for frame, label, sequence, manual in session.execute(_query(sequence_id, split))
    ]


def export_rows(
    session: Session, sequence_id: int | None = None, split: Split | None = None
) -> Rows:
    """The rows of an export (frame, label, sequence, validation keypoints) and the configured
    classes it writes, loaded now so that writing the zip needs no database session; 400
    when there is no label to export, 404 for no such run."""
    if sequence_id is not None:
        get_sequence(session, sequence_id)
    rows = _rows(session, sequence_id, split)
    if not rows:
        raise InvalidInputError("There are no accepted or corrected labels to export.")
    return configured_rows(session, rows)


def build_export(
    session: Session,
    storage: Storage,
    fmt: ExportFormat,
    *,
    sequence_id: int | None = None,
    split: Split | None = None,
    progress: Progress | None = None,
    skipped: Skipped | None = None,
) -> Path:
    """Write the export to a temporary zip file and return its path (the caller removes it).
    ``progress(fraction, message)`` is called after every frame; raise from it to stop.
    Frames whose files the store lost are left out, listed in ``skipped`` and the zip."""
    rows = export_rows(session, sequence_id, split)
    descriptor, name = tempfile.mkstemp(suffix=".zip", dir=storage.scratch())
    os.close(descriptor)
    target = Path(name)
    report = progress or (lambda fraction, message: None)
    try:
        with zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as archive:
            for done in _written(archive, storage, fmt, rows, [] if skipped is None else skipped):
                report(done / len(rows), f"{done} of {len(rows)} labels")
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    return target


class _Sink(io.RawIOBase):
    """A write-only, unseekable byte sink that ``stream_export`` empties after every entry
    (zipfile then writes data descriptors instead of seeking back)."""

    def __init__(self) -> None:
        self._chunks: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        self._chunks.append(bytes(data))
        return len(data)

    def drain(self) -> bytes:
        out = b"".join(self._chunks)
        self._chunks.clear()
        return out


def stream_export(storage: Storage, fmt: ExportFormat, rows: list[Any]) -> Iterator[bytes]:
    """The zip of ``rows`` (from ``export_rows``) as a stream of byte chunks, one or more per
    frame: nothing is written to disk and nothing is held beyond the entry being written. A
    frame whose files the store lost is left out and listed in the zip's ``skipped.txt``."""
    sink = _Sink()
    with zipfile.ZipFile(sink, "w", zipfile.ZIP_STORED) as archive:
        for _ in _written(archive, storage, fmt, rows, []):
            if chunk := sink.drain():
                yield chunk
    if chunk := sink.drain():
        yield chunk


Skipped = list[tuple[int, str]]
"""Frames an export left out: (frame id, the sentence saying which file is lost and what
restores it)."""
SKIPPED_LIST = "skipped.txt"


def _written(
    archive: zipfile.ZipFile, storage: Storage, fmt: str, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    """The format's writer, then ``skipped.txt`` (one frame a line) when frames were left out."""
    yield from WRITERS[fmt](archive, storage, rows, skipped)
    if skipped:
        lines = [f"frame {frame_id}: {reason}\n" for frame_id, reason in skipped]
        archive.writestr(SKIPPED_LIST, "".join(lines))


Writer = Callable[[zipfile.ZipFile, Storage, list[Any], Skipped], Iterator[int]]
_READERS = shared_pool(8, "export")  # the route's and the job's
"""Where an export reads its rows' files ahead of the writer: from an object store a frame's
image and mask are GETs that wait on the network (8 at once), and their decoding (OpenCV,
pycocotools) lets go of the GIL."""
_AHEAD = 16


def _ahead(function: Callable[[Any], Any], items: list[Any]) -> Iterator[Any]:
    """``map(function, items)`` computed in the readers' pool at most ``_AHEAD`` items ahead
    of the consumer (so a big export holds a few results, not all)."""
    pending = [_READERS.submit(function, item) for item in items[:_AHEAD]]
    for index in range(len(items)):
        result = pending.pop(0).result()
        if index + _AHEAD < len(items):
            pending.append(_READERS.submit(function, items[index + _AHEAD]))
        yield result


def _trying(read: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """``read``, returning the MissingFile it raises (the pool's result) instead of raising."""

    def attempt(row: Any) -> Any:
        try:
            return read(row)
        except MissingFile as missing:
            return missing

    return attempt


def _readable(
    storage: Storage, rows: list[Any], skipped: Skipped, read: Callable[[Any], Any] | None = None
) -> Iterator[tuple[int, Any, Path | None, Any]]:
    """(done, row, image file, ``read(row)``) for every row in order, the image fetched and
    ``read`` (of the label's mask) run in the readers' pool a few rows ahead (an object store's
    GETs overlap). A row whose image or mask the store lost comes with no image: the writer
    leaves it out, and it is listed in ``skipped``."""
    attempt = _trying(read) if read else None

    def fetched(row: Any) -> tuple[Path | MissingFile, Any]:
        result = attempt(row) if attempt else None
        try:
            return frame_file(storage, row[0].path, row[0].id), result
        except MissingFile as missing:
            return missing, result

    for done, (row, (image, result)) in enumerate(zip(rows, _ahead(fetched, rows), strict=True), 1):
        frame = row[0]
        if isinstance(result, MissingFile):
            image = frame_file_missing(result, frame.id, "label mask")
        if isinstance(image, MissingFile):
            skipped.append((frame.id, image.message))
            yield done, row, None, None
            continue
        yield done, row, image, result


def _write_masks(
    archive: zipfile.ZipFile, storage: Storage, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    manifest = []
    config = written_config(rows)
    made = {row[0].id for row in rows if _from_rle(storage, row[1])}
    stored = [row[1].mask_rle for row in rows if row[0].id in made]  # their PNGs: in processes
    pngs = mapped_ahead(rle_mask_pngs, stored, POOL_CHUNK, POOL_PROCESS_MIN)

    def read(row: Any) -> tuple[Path | None, ClassFiles]:  # in the readers' pool
        file = None if row[0].id in made else storage.existing(row[1].mask_path)
        return file, class_files(row[1], config, _stem(row[0]))

    for done, (frame, label, sequence, manual), image, files in _readable(
        storage, rows, skipped, read
    ):
        png = next(pngs) if frame.id in made else None
        if image is None:
            yield done
            continue
        stem, (mask, classes) = _stem(frame), files
        if png is not None:
            mask = png
        elif mask is None:  # made from a damaged RLE: its file instead, where it is here
            try:
                mask = frame_file(storage, label.mask_path, frame.id, "label mask")
            except MissingFile as missing:
                skipped.append((frame.id, missing.message))
                yield done
                continue
        archive.write(image, f"images/{stem}{_extension(frame)}")
        if isinstance(mask, bytes):
            archive.writestr(f"masks/{stem}.png", mask)
        else:
            archive.write(mask, f"masks/{stem}.png")
        for path, data in classes.files:
            archive.writestr(path, data)
        archive.writestr(f"keypoints/{stem}.json", json.dumps({"keypoints": label.keypoints}))
        if manual is not None:
            archive.writestr(
                f"validation_keypoints/{stem}.json", json.dumps({"keypoints": manual.keypoints})
            )
        manifest.append(
            {
                "stem": stem,
                "frame_id": frame.id,
                "original_name": frame.original_name,
                "sequence": sequence.name if sequence else None,
                "split": frame.split.value,
                "label": label.status.value,
                "revision": label.revision,
                "frame_index": frame.frame_index,
                "timestamp_s": frame.timestamp_s,
                "process": process_parameters(sequence) if sequence else None,
                "objects": classes.objects,
            }
            | frame_fields(label)
        )
        yield done
    left_out = [{"frame_id": frame_id, "reason": reason} for frame_id, reason in skipped]
    archive.writestr(
        "manifest.json",
        json.dumps(
            {"classes": manifest_classes(config), "frames": manifest, "skipped": left_out},
            indent=1,
        ),
    )


def _write_coco(
    archive: zipfile.ZipFile, storage: Storage, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    images, annotations, objects = [], [], []
    config = written_config(rows)
    k = max((len(label.keypoints or []) for _, label, _, _ in rows), default=0)
    masks = _readable(storage, rows, skipped, lambda row: _stored_rle(storage, row[1]))
    for done, (frame, label, sequence, manual), image, encoded in masks:
        if image is None:
            yield done
            continue
        file_name = f"images/{_stem(frame)}{_extension(frame)}"
        archive.write(image, file_name)
        process = process_parameters(sequence) if sequence else {}
        images.append(
            {
                "id": frame.id,
                "file_name": file_name,
                "width": frame.width,
                "height": frame.height,
                "original_name": frame.original_name,
                "sequence": sequence.name if sequence else None,
                "process": process,
                "frame_index": frame.frame_index,
                "timestamp_s": frame.timestamp_s,
                "split": frame.split.value,
                "bit_depth": frame.bit_depth,
            }
            | frame_fields(label)
        )
        segmentation, area, box = encoded
        keypoints = label.keypoints or []
        flat: list[float] = []
        for x, y in keypoints:
            flat += [float(x), float(y), 2]
        flat += [0.0, 0.0, 0] * (k - len(keypoints))
        annotation = {
            "id": frame.id,
            "image_id": frame.id,
            "category_id": 1,
            "iscrowd": 0,
            "segmentation": segmentation,
            "area": area,
            "bbox": box,
            "keypoints": flat,
            "num_keypoints": len(keypoints),
            "label": label.status.value,
        }
        if manual is not None:
            annotation["validation_keypoints"] = manual.keypoints
        annotations.append(annotation)
        objects += coco_objects(label, config, frame.id)
        yield done
    first = max((a["id"] for a in annotations), default=0) + 1  # after every pool's id
    annotations += [o | {"id": first + i} for i, o in enumerate(objects)]
    coco = {
        "info": {"description": "weldpool reviewed labels", "version": "1.0"},
        "images": images,
        "annotations": annotations,
        "categories": [
            {
                "id": 1,
                "name": "weld_pool",
                "supercategory": "weld",
                "keypoints": [f"keypoint_{i + 1}" for i in range(k)],
                "skeleton": [],
            },
            *coco_categories(config),
        ],
    }
    archive.writestr("annotations.json", json.dumps(coco))


def _write_yolo(
    archive: zipfile.ZipFile, storage: Storage, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    """Ultralytics YOLO segmentation: one polygon line per region (holes cannot be written),
    from the outlines stored with each label (traced from its mask for labels saved before)."""
    from weldpool_core.outline import normalised, region_outlines

    classes, used = written_classes(rows), set()

    def label_file(row: Any) -> str:
        frame, label = row[0], row[1]
        outlines = label.mask_outlines
        if outlines is None:  # saved before outlines were stored with labels
            outlines = region_outlines(_stored_mask(storage, label))
        lines = [
            "0 " + " ".join(f"{v:.6f}" for v in normalised(points, frame.height, frame.width))
            for points in outlines
        ]
        lines += yolo_lines(label, classes, frame.height, frame.width)
        return "\n".join(lines) + ("\n" if lines else "")

    names = file_names([row[0] for row in rows])
    for done, (frame, _, _, _), image, text in _readable(storage, rows, skipped, label_file):
        if image is not None:
            split = YOLO_SPLITS[frame.split.value]
            used.add(split)
            name = names[frame.id]
            archive.write(image, f"images/{split}/{name}")
            archive.writestr(f"labels/{split}/{Path(name).stem}.txt", text)
        yield done
    splits = "".join(
        f"{name}: images/{name}\n" for name in ("train", "val", "test") if name in used
    )
    ids = "".join(f"  {i}: {yaml_name(n)}\n" for i, n in enumerate(["weld_pool", *classes]))
    archive.writestr("data.yaml", f"path: .\n{splits}names:\n{ids}")
    if notes := yolo_notes(written_config(rows)):
        archive.writestr("notes.txt", notes)


def _write_cvat(
    archive: zipfile.ZipFile, storage: Storage, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    """CVAT for images 1.1: ``annotations.xml`` (each label one RLE ``<mask>``, holes kept;
    its keypoints and validation keypoints as ``<points>``) with the images beside it. The
    pools' masks are made from their stored RLE in the service's processes (``mapped_ahead``),
    those of labels saved before it was stored from their PNG in the readers' pool."""
    from weldpool_core.annotations.cvat import CvatImage, cvat_document, cvat_image, cvat_rle_masks

    elements: list[Any] = []
    config, names = written_config(rows), file_names([row[0] for row in rows])
    stored = [(row[1].mask_rle, row[1].mask_bbox) for row in rows if row[1].mask_rle is not None]
    pools = mapped_ahead(cvat_rle_masks, stored, POOL_CHUNK, POOL_PROCESS_MIN)

    def shapes(row: Any) -> tuple[Any, list[Any]]:  # in the readers' pool
        label = row[1]
        unstored = _cvat_mask(storage, label) if label.mask_rle is None else None
        return unstored, cvat_objects(label, config)

    for done, (frame, label, _, manual), path, made in _readable(storage, rows, skipped, shapes):
        pool = next(pools) if label.mask_rle is not None else None
        if path is None:
            yield done
            continue
        name = names[frame.id]  # as the task's own frames are named: CVAT matches by name
        archive.write(path, f"images/{name}")
        image = CvatImage(
            id=len(elements),
            name=name,
            width=frame.width,
            height=frame.height,
            mask=pool if label.mask_rle is not None else made[0],
            keypoints=label.keypoints or None,
            validation_keypoints=manual.keypoints if manual is not None else None,
            objects=made[1],
            tags=frame_fields(label)["tags"],
            frame_attributes={
                k: cvat_text(v) for k, v in frame_fields(label)["attributes"].items()
            },
        )
        elements.append(cvat_image(image))
        yield done
    archive.writestr("annotations.xml", cvat_document(elements, len(elements), cvat_labels(config)))


def _cvat_mask(storage: Storage, label: Label) -> Any:
    """The ``CvatMask`` of a label saved before its RLE was stored, from its mask PNG."""
    from weldpool_core.annotations.cvat import cvat_mask

    return cvat_mask(_stored_mask(storage, label))


def _write_labelme(
    archive: zipfile.ZipFile, storage: Storage, rows: list[Any], skipped: Skipped
) -> Iterator[int]:
    """LabelMe: a JSON file beside each image (``export_labelme``)."""
    from app.review.export_labelme import write_labelme

    def readable(read: Callable[[Any], Any]) -> Iterator[tuple[int, Any, Path | None, Any]]:
        return _readable(storage, rows, skipped, read)

    yield from write_labelme(archive, rows, readable, lambda label: _stored_mask(storage, label))


POOL_CHUNK = 16
"""Labels per task a CVAT or masks export sends to the service's processes."""
POOL_PROCESS_MIN = 128
"""Masks to make from the stored RLE from which an export starts the processes (their start
takes seconds and ~150 MB each); fewer are made in the writer's thread unless they run."""


WRITERS: dict[str, Writer] = {
    "masks": _write_masks,
    "coco": _write_coco,
    "yolo": _write_yolo,
    "cvat": _write_cvat,
    "labelme": _write_labelme,
}
