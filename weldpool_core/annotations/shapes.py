"""What one imported label holds, and how its shapes become one mask.

Each format's reader turns its regions into ``Shape``s without knowing the frame: a shape is
rasterised only once the frame it belongs to is known, so a wrong size or a region outside the
frame is refused against the frame's own size. The pool's mask is the union of its shapes.

Polygons are filled by ``outline.fill_polygons`` (vertices are pixel centres, edges included:
the convention our YOLO export writes), except COCO's, which pycocotools rasterises as every
COCO reader does. RLE masks (COCO compressed or uncompressed, CVAT's) and mask images are taken
pixel for pixel, holes and all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from weldpool_core.annotations.source import Refusal
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import Polygon, fill_polygons, rle_mask

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

MAX_KEYPOINTS = 64
"""Most keypoints one imported label may carry (as many as a reviewer may place)."""
MAX_MASK_PIXELS = 25_000_000
"""Largest mask box a file may declare (the largest frame ingest takes)."""
DAMAGED = (ValueError, TypeError, OverflowError, KeyError, IndexError, AttributeError)
"""What Python raises on a value of the wrong type or size in a file: readers refuse the item."""
EDGE_TOLERANCE = 1.0
"""How far (px) a vertex or keypoint may lie outside the frame before the item is refused
(tools round or clip at the border; farther out means the annotation is for another image)."""


class Shape(Protocol):
    def mask(self, height: int, width: int) -> NDArray[np.bool_]: ...


def _check_inside(xy: NDArray[np.float64], height: int, width: int, what: str) -> None:
    low, high = -EDGE_TOLERANCE, np.array([width, height]) + EDGE_TOLERANCE
    outside = ~np.all((xy >= low) & (xy <= high), axis=1)
    if outside.any():
        x, y = xy[int(np.argmax(outside))]
        raise InvalidInputError(
            f"The {what} point ({x:g}, {y:g}) lies outside the {width}×{height} frame."
        )


@dataclass(frozen=True)
class Polygons:
    """Closed polygons in frame pixels (x, y of pixel centres); holes flagged."""

    polygons: list[Polygon]

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        for polygon in self.polygons:
            _check_inside(np.asarray(polygon.points, np.float64), height, width, "polygon's")
        outers = [p for p in self.polygons if not p.hole]
        if len(outers) == len(self.polygons):  # union, not even–odd, of separate regions
            union = np.zeros((height, width), bool)
            for polygon in outers:
                union |= fill_polygons([polygon], height, width)
            return union
        return fill_polygons(self.polygons, height, width)


@dataclass(frozen=True)
class CocoPolygons:
    """COCO's polygons ``[[x1, y1, x2, y2, …], …]``: pycocotools rasterises them (COCO's own
    convention: coordinates are continuous, a pixel is in when its area mostly is)."""

    polygons: list[list[float]]

    def rle(self, height: int, width: int) -> dict[str, Any]:
        """The polygons' union as compressed RLE on a ``height``×``width`` frame."""
        from pycocotools import mask as coco

        for flat in self.polygons:
            _check_inside(np.asarray(flat, np.float64).reshape(-1, 2), height, width, "polygon's")
        rles = coco.frPyObjects([list(map(float, p)) for p in self.polygons], height, width)
        merged = coco.merge(rles)
        return {"size": [height, width], "counts": merged["counts"].decode("ascii")}

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        return rle_mask(self.rle(height, width))


@dataclass(frozen=True)
class CocoRle:
    """A COCO RLE, compressed ``{"size", "counts": str}`` or uncompressed (``counts`` a list)."""

    encoded: dict[str, Any]

    def compressed(self) -> dict[str, Any]:
        from pycocotools import mask as coco

        size = [int(v) for v in self.encoded["size"]]
        counts = self.encoded["counts"]
        if isinstance(counts, list):
            if any(c < 0 for c in counts) or sum(counts) != size[0] * size[1]:
                raise InvalidInputError(
                    f"The RLE counts cover {sum(counts)} pixels, not the {size[1]}×{size[0]} "
                    "it states."
                )
            encoded = coco.frPyObjects({"size": size, "counts": counts}, *size)
            counts = encoded["counts"].decode("ascii")
        return {"size": size, "counts": counts}

    def rle(self, height: int, width: int) -> dict[str, Any]:
        """The compressed RLE, checked against a ``height``×``width`` frame."""
        size = [int(v) for v in self.encoded["size"]]
        if size != [height, width]:
            raise InvalidInputError(
                f"The mask is {size[1]}×{size[0]}; the frame is {width}×{height}."
            )
        return self.compressed()

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        rle = self.rle(height, width)
        try:
            return rle_mask(rle)
        except (ValueError, TypeError) as exc:
            raise InvalidInputError(f"The RLE mask cannot be decoded ({exc}).") from None


@dataclass(frozen=True)
class PartialMask:
    """A mask over part of the frame, placed at (``left``, ``top``): CVAT's RLE masks and
    LabelMe's mask shapes. ``pixels`` is the part's boolean mask."""

    pixels: NDArray[np.bool_]
    left: int = 0
    top: int = 0

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        h, w = self.pixels.shape
        if self.left < 0 or self.top < 0 or self.left + w > width or self.top + h > height:
            raise InvalidInputError(
                f"The {w}×{h} mask at ({self.left}, {self.top}) does not fit the "
                f"{width}×{height} frame."
            )
        full = np.zeros((height, width), bool)
        full[self.top : self.top + h, self.left : self.left + w] = self.pixels
        return full


@dataclass(frozen=True)
class MaskImage:
    """A whole-frame mask PNG (0/255 or 0/1), decoded by the one mask reader."""

    data: bytes

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        decoded = decode_mask_png(self.data)
        if decoded.shape != (height, width):
            raise InvalidInputError(
                f"The mask is {decoded.shape[1]}×{decoded.shape[0]}; the frame is {width}×{height}."
            )
        return decoded


def inside_frame(points: list[list[float]], height: int, width: int) -> list[list[float]]:
    """Keypoints within ``EDGE_TOLERANCE`` of the frame (checked on reading) moved onto it."""
    return [[min(max(float(x), 0.0), width), min(max(float(y), 0.0), height)] for x, y in points]


def cvat_rle(counts: list[int], width: int, height: int) -> NDArray[np.bool_]:
    """CVAT's mask RLE: run lengths over the box, row by row, starting with a run of 0s."""
    if width <= 0 or height <= 0:
        raise InvalidInputError("The mask's box is empty.")
    if width * height > MAX_MASK_PIXELS:
        raise InvalidInputError(f"The mask's {width}×{height} box is larger than any frame.")
    if any(c < 0 for c in counts) or sum(counts) != width * height:
        raise InvalidInputError(
            f"The mask's runs cover {sum(counts)} pixels, not its {width}×{height} box."
        )
    values = np.zeros(len(counts), bool)
    values[1::2] = True
    return np.repeat(values, counts).reshape(height, width)


def to_cvat_rle(pixels: NDArray[np.bool_]) -> list[int]:
    """The inverse of ``cvat_rle`` (the box's pixels, row-major, runs starting with 0s)."""
    flat = np.ascontiguousarray(pixels, dtype=np.uint8).reshape(-1)
    changes = np.flatnonzero(np.diff(flat)) + 1
    edges = np.concatenate([[0], changes, [flat.size]])
    runs = np.diff(edges).tolist()
    return [0, *runs] if flat.size and flat[0] else runs


@dataclass
class ImportedLabel:
    """One image's pool label as an annotation file states it."""

    item: str  # how a refusal names it: "<annotation file>: <image name>"
    image: str  # the image's name as the annotation gives it
    shapes: list[Shape] = field(default_factory=list)
    size: tuple[int, int] | None = None  # (height, width) the annotation states
    image_data: bytes | None = None  # embedded in the annotation (LabelMe's imageData)
    keypoints: list[list[float]] | None = None  # the label's own (our exports)
    validation_keypoints: list[list[float]] | None = None  # placed by hand
    sequence: str | None = None
    process: dict[str, Any] | None = None
    original_name: str | None = None
    beside: str = ""  # the annotation file, to find images relative to it

    def mask(self, height: int, width: int) -> NDArray[np.bool_] | None:
        """The pool mask on a ``height``×``width`` frame (None when the label has only
        keypoints); refused (InvalidInputError) when a shape does not fit the frame."""
        self._check_size(height, width)
        if not self.shapes:
            return None
        union = self.shapes[0].mask(height, width)
        for shape in self.shapes[1:]:
            union = union | shape.mask(height, width)
        if not union.any():
            raise InvalidInputError("The mask is empty.")
        return union

    def _check_size(self, height: int, width: int) -> None:
        if self.size is not None and tuple(self.size) != (height, width):
            raise InvalidInputError(
                f"The annotation is for a {self.size[1]}×{self.size[0]} image; the frame is "
                f"{width}×{height}."
            )

    def checked_points(self, height: int, width: int) -> None:
        for points in (self.keypoints, self.validation_keypoints):
            if points and len(points) > MAX_KEYPOINTS:
                raise InvalidInputError(f"A label has at most {MAX_KEYPOINTS} keypoints.")
            if points:
                _check_inside(np.asarray(points, np.float64).reshape(-1, 2), height, width, "key")

    def rasterised(
        self, height: int, width: int
    ) -> tuple[NDArray[np.bool_] | None, dict[str, Any] | None]:
        """``mask``, and its compressed RLE when the label is one COCO shape (RLE already:
        stored as it is instead of encoded again)."""
        shape = self.shapes[0] if len(self.shapes) == 1 else None
        if not isinstance(shape, CocoRle | CocoPolygons):
            return self.mask(height, width), None
        self._check_size(height, width)
        rle = shape.rle(height, width)
        try:
            mask = rle_mask(rle)
        except (ValueError, TypeError) as exc:
            raise InvalidInputError(f"The RLE mask cannot be decoded ({exc}).") from None
        if not mask.any():
            raise InvalidInputError("The mask is empty.")
        return mask, rle


def text_or_none(value: Any) -> str | None:
    """A name a file gives (a run, an original file name), when it is a non-empty string."""
    return value[:255] if isinstance(value, str) and value.strip() else None


@dataclass
class Parsed:
    """What a reader found: the labels, and what it refused before any frame was looked at."""

    labels: list[ImportedLabel] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)

    def refuse(self, item: str, reason: str) -> None:
        self.refused.append(Refusal(item, reason))
