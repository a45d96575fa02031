"""One imported label's content, computed away from any database: rasterised on its frame,
checked, encoded as the mask PNG the store keeps, with its stored columns (``outline``) and
Algorithm 1's keypoints unless it has its own. Pure and picklable, so an import can compute
many in worker processes (the Python parts of Algorithm 1 and the RLE decode hold the GIL)."""

from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import hashlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from weldpool_core.annotations.shapes import DAMAGED, ImportedLabel, other_objects
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import mask_keypoints
from weldpool_core.io import encode_mask_png
from weldpool_core.outline import mask_record

if TYPE_CHECKING:
    import cv2
else:
    from weldpool_core.lazy import cv2

HEAP_BYTES = 64 << 20
"""Blocks up to this size a label process takes from its heap instead of fresh pages."""


def start_process() -> None:
    """Tune a process that computes label contents (a process pool's initializer).

    A label's work makes a few full-frame arrays (1 MB each at 1280×800). A fresh glibc process
    maps each one anew and page-faults its every page (a quarter of a label's time, measured);
    a heap threshold above a frame lets freed blocks be reused instead. OpenCV gets one thread:
    the pool already keeps each core busy, and its threads only add waiting. Elsewhere than
    glibc the allocator is left as it is."""
    cv2.setNumThreads(1)
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        mallopt = libc.mallopt if libc is not None else None
    except (OSError, AttributeError):
        return
    if mallopt is not None:
        mallopt(-3, HEAP_BYTES)  # M_MMAP_THRESHOLD
        mallopt(-1, 2 * HEAP_BYTES)  # M_TRIM_THRESHOLD: keep freed heap for the next label


@dataclass
class LabelContent:
    """A label's mask PNG (to store) and its sha256, stored columns and keypoints, the file's
    validation keypoints, or why it is refused."""

    mask_png: bytes | None = None
    sha256: str = ""
    columns: dict[str, Any] = field(default_factory=dict)
    keypoints: list[list[float]] | None = None
    manual: list[list[float]] | None = None
    objects: list[dict[str, Any]] = field(default_factory=list)  # the other classes' (``kind``)
    left_out: list[str] = field(default_factory=list)  # why some of their regions are not kept
    problem: str | None = None


def label_content(item: ImportedLabel, size: tuple[int, int], wants_label: bool) -> LabelContent:
    """Rasterise, check, encode and measure one label on a frame of ``size`` (height, width)."""
    height, width = size
    content = LabelContent(manual=item.validation_keypoints)
    try:
        item.checked_points(height, width)
        if not wants_label:
            return content
        boxed, rle = item.rasterised(height, width)
        if boxed is None:
            return content
        content.keypoints = item.keypoints or mask_keypoints(boxed.pixels, boxed.origin)
        content.columns = mask_record(boxed, rle=rle)
        content.mask_png = encode_mask_png(boxed.pixels, boxed.size, boxed.origin)
        content.sha256 = hashlib.sha256(content.mask_png).hexdigest()
        content.objects, content.left_out = other_objects(item.others, height, width)
    except InvalidInputError as exc:
        content.problem = exc.message
    except DAMAGED:
        content.problem = "The annotation holds values of the wrong type or size."
    return content


def shipped(item: ImportedLabel) -> ImportedLabel:
    """The label as another process needs it: without its image's bytes."""
    return dataclasses.replace(item, image_data=None) if item.image_data is not None else item


def many_contents(
    jobs: list[tuple[ImportedLabel, tuple[int, int], bool]],
) -> list[LabelContent]:
    """``label_content`` of several labels (one task of a process pool: fewer round trips)."""
    return [label_content(item, size, wants) for item, size, wants in jobs]
