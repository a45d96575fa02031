"""Labels made elsewhere, read into one shape: COCO, YOLO segmentation, mask folders, LabelMe
and CVAT for images 1.1 (``READERS``); each reader gives ``ImportedLabel``s and the items it
refused, and rasterises a label only against the frame it belongs to (``ImportedLabel.mask``).

Converters considered: Datumaro 1.13 (CVAT's own) reads all five, but requires 18 packages
(pandas, pyarrow, shapely, lxml…) and pins Pillow 12; supervision 0.31 reads COCO and YOLO
only. Each format here is a page of code over pycocotools (COCO's reference RLE and polygons),
OpenCV and the one polygon filler (``outline.fill_polygons``), with the refusals this service
needs.
"""

from __future__ import annotations

from collections.abc import Callable

from weldpool_core.annotations.coco import read_coco
from weldpool_core.annotations.cvat import read_cvat
from weldpool_core.annotations.labelme import read_labelme
from weldpool_core.annotations.masks import read_masks
from weldpool_core.annotations.shapes import ImportedLabel, Parsed
from weldpool_core.annotations.source import Refusal, Source, open_source, open_upload
from weldpool_core.annotations.yolo import read_yolo

Reader = Callable[[Source, str | None], Parsed]
READERS: dict[str, Reader] = {
    "coco": read_coco,
    "yolo": read_yolo,
    "masks": read_masks,
    "labelme": read_labelme,
    "cvat": read_cvat,
}
ARCHIVE_ONLY = ("yolo", "masks")
"""Formats whose labels are files of a folder: a single uploaded file cannot hold them."""

__all__ = [
    "ARCHIVE_ONLY",
    "READERS",
    "ImportedLabel",
    "Parsed",
    "Refusal",
    "Source",
    "open_source",
    "open_upload",
]
