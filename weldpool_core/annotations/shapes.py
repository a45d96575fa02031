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

import base64
import binascii
import dataclasses
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from weldpool_core.annotations.source import Refusal, Source
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import decode_mask_png
from weldpool_core.outline import (
    MAX_POLYGONS,
    MAX_VERTICES,
    BoxedMask,
    Polygon,
    fill_polygons,
    rle_boxed,
    rle_mask,
)

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

MAX_KEYPOINTS = 64
"""Most keypoints one imported label may carry (as many as a reviewer may place)."""
MAX_POLYGON_VERTICES = 100_000
"""Most vertices one imported polygon may have: a pool traced pixel by pixel round the largest
frame (25 MP) has under 40,000; counted before the points are parsed."""
MAX_MASK_PIXELS = 25_000_000
"""Largest mask box a file may declare (the largest frame ingest takes)."""
DAMAGED = (ValueError, TypeError, OverflowError, KeyError, IndexError, AttributeError)
"""What Python raises on a value of the wrong type or size in a file: readers refuse the item."""
EDGE_TOLERANCE = 1.0
"""How far (px) a vertex or keypoint may lie outside the frame before the item is refused
(tools round or clip at the border; farther out means the annotation is for another image)."""


class Shape(Protocol):
    def mask(self, height: int, width: int) -> NDArray[np.bool_]: ...


def check_vertices(count: int) -> None:
    """Refuse a polygon of more than ``MAX_POLYGON_VERTICES`` vertices (before reading them)."""
    if count > MAX_POLYGON_VERTICES:
        raise InvalidInputError(
            f"A polygon has at most {MAX_POLYGON_VERTICES:,} vertices; simplify it."
        )


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
        if self.polygons:
            every = [np.asarray(p.points, np.float64).reshape(-1, 2) for p in self.polygons]
            _check_inside(np.concatenate(every), height, width, "polygon's")
        if not self.has_holes:  # union, not even–odd, of separate regions
            return _union(self.polygons, height, width)
        return fill_polygons(self.polygons, height, width)

    @property
    def has_holes(self) -> bool:
        return any(p.hole for p in self.polygons)


if TYPE_CHECKING:
    _Box = tuple[NDArray[np.float64], int, int, int, int]  # points, left, top, right, bottom
GROUPED = 64
"""Outer polygons in a label from which those whose boxes overlap no other's are filled
together (a fill's fixed cost, ~0.2 ms, times thousands of tiny polygons)."""


def _union(polygons: list[Polygon], height: int, width: int) -> NDArray[np.bool_]:
    """The union of outer polygons, each filled over its own box: thousands of tiny polygons
    cost their pixels, not a frame each. From ``GROUPED`` polygons, those whose boxes overlap
    no other's are filled together, ``MAX_POLYGONS`` at a time (even–odd cannot join two
    polygons whose boxes are apart: each crosses a row an even number of times)."""
    union = np.zeros((height, width), bool)
    boxes = [b for p in polygons if (b := _box(p, height, width)) is not None]
    alone = _alone(boxes, height, width) if len(boxes) >= GROUPED else [False] * len(boxes)
    for box, apart in zip(boxes, alone, strict=True):
        if not apart:
            _fill(union, [box])
    together = [box for box, apart in zip(boxes, alone, strict=True) if apart]
    group: list[_Box] = []
    vertices = 0
    for box in together:
        if len(group) >= MAX_POLYGONS or vertices + len(box[0]) > MAX_VERTICES:
            _fill(union, group)
            group, vertices = [], 0
        group.append(box)
        vertices += len(box[0])
    if group:
        _fill(union, group)
    return union


def _box(polygon: Polygon, height: int, width: int) -> _Box | None:
    """A polygon's rounded vertices and their box on the frame (None when it is wholly on the
    frame's border margin). Rounded first, so filling it shifted into its box is exact."""
    pixels = np.rint(np.asarray(polygon.points, np.float64).reshape(-1, 2))
    if len(pixels) == 0:
        return pixels, 0, 0, 1, 1  # refused by the fill
    left, top = (int(v) for v in np.maximum(pixels.min(axis=0), 0))
    right, bottom = (int(v) for v in np.minimum(pixels.max(axis=0) + 1, (width, height)))
    return (pixels, left, top, right, bottom) if right > left and bottom > top else None


def _alone(boxes: list[_Box], height: int, width: int) -> list[bool]:
    """Whether each box overlaps no other (how many boxes cover each pixel, by one 2-D prefix
    sum of the boxes' corners)."""
    corners = np.zeros((height + 1, width + 1), np.int32)
    left, top, right, bottom = (np.array([b[i] for b in boxes]) for i in range(1, 5))
    for rows, columns, sign in ((top, left, 1), (top, right, -1), (bottom, left, -1)):
        np.add.at(corners, (rows, columns), sign)
    np.add.at(corners, (bottom, right), 1)
    cover = corners.cumsum(axis=0, dtype=np.int32).cumsum(axis=1, dtype=np.int32)
    return [bool(cover[y0:y1, x0:x1].max() == 1) for _, x0, y0, x1, y1 in boxes]


def _fill(union: NDArray[np.bool_], boxes: list[_Box]) -> None:
    """Add polygons to ``union``, filled together over their boxes' box."""
    left, top = min(b[1] for b in boxes), min(b[2] for b in boxes)
    right, bottom = max(b[3] for b in boxes), max(b[4] for b in boxes)
    shifted = [Polygon([(x - left, y - top) for x, y in b[0].tolist()]) for b in boxes]
    union[top:bottom, left:right] |= fill_polygons(shifted, bottom - top, right - left)


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
        while len(rles) > 1:  # pairwise: merging a list adds each to a growing union (n²)
            rles = [coco.merge(rles[i : i + 2]) for i in range(0, len(rles), 2)]
        return {"size": [height, width], "counts": rles[0]["counts"].decode("ascii")}

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
class MaskFile:
    """A whole-frame mask PNG of the import, not read yet (``path`` in its source): read with
    its batch (``ImportedLabel.loaded``), so an import holds one batch's files, not all."""

    path: str

    def mask(self, height: int, width: int) -> NDArray[np.bool_]:
        raise InvalidInputError(f"The mask {self.path} was not read with its batch.")


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
    flat = np.ascontiguousarray(pixels, dtype=bool).reshape(-1)
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    edges = np.concatenate([[0], changes, [flat.size]])
    runs = np.diff(edges).tolist()
    return [0, *runs] if flat.size and flat[0] else runs


@dataclass
class OtherShape:
    """A region of a class other than the pool, or a points class's named points, under the
    name the file gives its class (``shape`` and ``points`` None: the file's element could not
    be read as either). The service keeps it as an object where its label configuration has
    the class (``kind`` set), else counts it."""

    name: str
    shape: Shape | None = None
    kind: str | None = None  # "mask", "instances" or "points", once the service knows the class
    attributes: dict[str, Any] = field(default_factory=dict)  # as the file gives them
    points: dict[str, list[float]] | None = None  # a points object's {name: [x, y]}


def other_objects(
    others: list[OtherShape], height: int, width: int
) -> tuple[list[dict[str, Any]], list[str]]:
    """The stored objects of a label's other classes whose ``kind`` is set, on a
    ``height``×``width`` frame, in the file's order: each ``instances`` region one object
    (``{"class", "rle", "area", "bbox"}``), all regions of a ``mask`` class one (their union),
    each points object its named points; empty regions left out. And why each one that does
    not fit the frame was left out (the pool's label stays)."""
    from weldpool_core.outline import coco_mask

    entries: list[OtherShape | tuple[str, list[Shape], dict[str, Any]]] = []
    masks: dict[str, list[Shape]] = {}
    for other in others:
        if other.kind == "points" and other.points:
            entries.append(other)
        elif other.shape is None or other.kind not in ("mask", "instances"):
            continue
        elif other.kind == "instances":
            entries.append((other.name, [other.shape], other.attributes))
        elif other.name in masks:
            masks[other.name].append(other.shape)
        else:
            masks[other.name] = [other.shape]
            entries.append((other.name, masks[other.name], other.attributes))
    objects, problems = [], []
    for entry in entries:
        name = entry.name if isinstance(entry, OtherShape) else entry[0]
        try:
            if isinstance(entry, OtherShape):
                objects.append(_points_object(entry, height, width))
                continue
            union = np.zeros((height, width), bool)
            for shape in merged(entry[1]):
                union |= shape.mask(height, width)
        except InvalidInputError as exc:
            problems.append(f"A {name!r} object is left out: {exc.message}")
            continue
        if union.any():
            coco = coco_mask(union)
            made = {"class": name, "rle": coco.rle, "area": coco.area, "bbox": coco.bbox}
            objects.append(made | ({"attributes": entry[2]} if entry[2] else {}))
    return objects, problems


def _points_object(other: OtherShape, height: int, width: int) -> dict[str, Any]:
    """A points object as stored: its named points (within ``EDGE_TOLERANCE`` of the frame,
    moved onto it) and attributes."""
    names = list(other.points or {})
    xy = np.asarray([other.points[n] for n in names] if other.points else [], np.float64)
    _check_inside(xy.reshape(-1, 2), height, width, f"{other.name!r}")
    placed = inside_frame(xy.reshape(-1, 2).tolist(), height, width)
    made: dict[str, Any] = {"class": other.name, "points": dict(zip(names, placed, strict=True))}
    return made | ({"attributes": other.attributes} if other.attributes else {})


@dataclass
class ImportedLabel:
    """One image's pool label as an annotation file states it, with the file's regions of
    other classes on the same image (``others``)."""

    item: str  # how a refusal names it: "<annotation file>: <image name>"
    image: str  # the image's name as the annotation gives it
    shapes: list[Shape] = field(default_factory=list)
    size: tuple[int, int] | None = None  # (height, width) the annotation states
    image_data: bytes | None = None  # embedded in the annotation (LabelMe's imageData)
    embedded: str | None = None  # the file whose imageData holds the image, not read yet
    keypoints: list[list[float]] | None = None  # the label's own (our exports)
    validation_keypoints: list[list[float]] | None = None  # placed by hand
    sequence: str | None = None
    process: dict[str, Any] | None = None
    original_name: str | None = None
    beside: str = ""  # the annotation file, to find images relative to it
    others: list[OtherShape] = field(default_factory=list)
    tags: list[str] = field(default_factory=list)  # the frame's tags, as the file names them
    frame_attributes: dict[str, Any] = field(default_factory=dict)  # as the file gives them

    def mask(self, height: int, width: int) -> NDArray[np.bool_] | None:
        """The pool mask on a ``height``×``width`` frame (None when the label has only
        keypoints); refused (InvalidInputError) when a shape does not fit the frame."""
        self._check_size(height, width)
        if not self.shapes:
            return None
        union = np.zeros((height, width), bool)
        for shape in merged(self.shapes):
            union |= shape.mask(height, width)
        if not union.any():
            raise InvalidInputError("The mask is empty.")
        return union

    def _check_size(self, height: int, width: int) -> None:
        if self.size is not None and tuple(self.size) != (height, width):
            raise InvalidInputError(
                f"The annotation is for a {self.size[1]}×{self.size[0]} image; the frame is "
                f"{width}×{height}."
            )

    def add_keypoints(self, points: list[list[float]], own: bool) -> None:
        """Add a region's keypoints to the label's own (``own``) or its validation keypoints,
        in place (a file may give thousands of regions of one point each).

        Raises:
            InvalidInputError: the label would hold more than ``MAX_KEYPOINTS``.
        """
        kept = (self.keypoints if own else self.validation_keypoints) or []
        if len(kept) + len(points) > MAX_KEYPOINTS:
            raise InvalidInputError(f"A label has at most {MAX_KEYPOINTS} keypoints.")
        kept.extend(points)
        if own:
            self.keypoints = kept
        else:
            self.validation_keypoints = kept

    def loaded(self, source: Source) -> ImportedLabel:
        """The label with the files it names read from ``source``: its mask files (its other
        classes' too), and its image embedded in the annotation file (LabelMe's base64
        ``imageData``).

        Raises:
            InvalidInputError: a file cannot be read, or the embedded image is not base64.
        """
        shapes = [
            MaskImage(source.read(s.path)) if isinstance(s, MaskFile) else s for s in self.shapes
        ]
        others = [
            dataclasses.replace(o, shape=MaskImage(source.read(o.shape.path)))
            if isinstance(o.shape, MaskFile)
            else o
            for o in self.others
        ]
        image = self.image_data
        if self.embedded is not None:
            document = source.read_json(self.embedded)
            data = document.get("imageData") if isinstance(document, dict) else None
            try:
                image = base64.b64decode(data if isinstance(data, str) else "", validate=True)
            except (binascii.Error, ValueError):
                raise InvalidInputError("Its imageData is not base64.") from None
        return dataclasses.replace(
            self, shapes=shapes, others=others, image_data=image, embedded=None
        )

    def checked_points(self, height: int, width: int) -> None:
        for points in (self.keypoints, self.validation_keypoints):
            if points and len(points) > MAX_KEYPOINTS:
                raise InvalidInputError(f"A label has at most {MAX_KEYPOINTS} keypoints.")
            if points:
                _check_inside(np.asarray(points, np.float64).reshape(-1, 2), height, width, "key")

    def rasterised(self, height: int, width: int) -> tuple[BoxedMask | None, dict[str, Any] | None]:
        """The mask (by its box: ``BoxedMask``), and its compressed RLE when the label is one
        COCO shape (RLE already: stored as it is instead of encoded again, and only its box
        decoded)."""
        shapes = merged(self.shapes)
        shape = shapes[0] if len(shapes) == 1 else None
        if not isinstance(shape, CocoRle | CocoPolygons):
            mask = self.mask(height, width)
            return (BoxedMask.of(mask) if mask is not None else None), None
        self._check_size(height, width)
        rle = shape.rle(height, width)
        try:
            boxed = rle_boxed(rle)
        except (ValueError, TypeError) as exc:
            raise InvalidInputError(f"The RLE mask cannot be decoded ({exc}).") from None
        if boxed.empty:
            raise InvalidInputError("The mask is empty.")
        return boxed, rle


def merged(shapes: list[Shape]) -> list[Shape]:
    """The shapes with those of one kind as one: every outer polygon (LabelMe's, YOLO's) filled
    into one mask, every COCO polygon (CVAT's) rasterised in one RLE: thousands of shapes do
    not each cost a frame."""
    outers = [p for s in shapes if isinstance(s, Polygons) and not s.has_holes for p in s.polygons]
    coco = [p for s in shapes if isinstance(s, CocoPolygons) for p in s.polygons]
    rest = [
        s
        for s in shapes
        if not isinstance(s, CocoPolygons) and not (isinstance(s, Polygons) and not s.has_holes)
    ]
    together: list[Shape] = [Polygons(outers)] if outers else []
    together += [CocoPolygons(coco)] if coco else []
    return together + rest


def text_or_none(value: Any) -> str | None:
    """A name a file gives (a run, an original file name), when it is a non-empty string."""
    return value[:255] if isinstance(value, str) and value.strip() else None


@dataclass
class Parsed:
    """What a reader found: the labels, what it refused before any frame was looked at, and
    the regions of other classes on images without a pool (counted by class: not imported)."""

    labels: list[ImportedLabel] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)
    without_pool: Counter[str] = field(default_factory=Counter)

    def refuse(self, item: str, reason: str) -> None:
        self.refused.append(Refusal(item, reason))

    def attach(self, label: ImportedLabel | None, others: list[OtherShape]) -> None:
        """Give an image's other regions to its pool label, or count them without one."""
        if label is not None:
            label.others.extend(others)
        else:
            self.without_pool.update(o.name for o in others)
