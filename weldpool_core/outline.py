"""A mask as polygons and back: the outline a reviewer edits vertex by vertex, and the polygons
of formats that have no masks (Ultralytics YOLO segmentation).

``mask_polygons`` traces every region's outer boundary and every hole's boundary (OpenCV's
two-level contour hierarchy) and simplifies them with Douglas–Peucker (``tolerance`` in pixels;
0 keeps every boundary pixel). Vertices are pixel indices ``(x, y)`` of boundary pixels, so
``fill_polygons`` of an unsimplified outline gives the mask back pixel for pixel: outer polygons
are filled with their edges, holes are emptied inside their edges (the hole's boundary pixels
belong to the region around it).

``coco_mask`` is a mask as COCO holds it: compressed RLE (holes survive, unlike outer
polygons), area and bounding box, from pycocotools (the reference implementation every COCO
reader uses); ``coco_mask_png`` reads a stored 0/1 or 0/255 mask PNG the short way, and
``rle_mask`` decodes the RLE back to a mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError

MAX_POLYGONS = 10_000
MAX_VERTICES = 200_000


@dataclass(frozen=True)
class Polygon:
    """One closed boundary: ``points`` in frame pixels, ``hole`` when it bounds a hole."""

    points: list[tuple[float, float]]
    hole: bool = False

    def area(self) -> float:
        """The shoelace area in pixels² (positive)."""
        xy = np.asarray(self.points, dtype=np.float64)
        x, y = xy[:, 0], xy[:, 1]
        return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2)


@dataclass(frozen=True)
class CocoMask:
    """A mask in COCO's terms: ``rle`` ``{"size": [h, w], "counts": str}`` (compressed,
    column-major), ``area`` in pixels and ``bbox`` ``[x, y, width, height]``."""

    rle: dict[str, Any]
    area: int
    bbox: list[int]


def coco_mask(mask: NDArray[Any]) -> CocoMask:
    """``CocoMask`` of a boolean (or 0/1) mask."""
    return _coco_encoded(np.asfortranarray(mask.astype(np.uint8)))


def coco_mask_png(data: bytes) -> CocoMask:
    """``CocoMask`` of a mask PNG (0/1 or 0/255 gray), decoded to gray, transposed and
    thresholded by OpenCV straight into the column-major 0/1 array pycocotools encodes (a third
    faster than decoding to a boolean mask and copying it to column order)."""
    gray = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        raise InvalidInputError("The mask is not a readable PNG image.")
    level = 0 if int(gray.max()) <= 1 else 127
    _, columns = cv2.threshold(cv2.transpose(gray), level, 1, cv2.THRESH_BINARY)
    return _coco_encoded(columns.T)


def rle_mask(rle: dict[str, Any]) -> NDArray[np.bool_]:
    """The boolean H×W mask of a compressed RLE ``{"size": [h, w], "counts": str}`` (as
    ``CocoMask.rle`` holds it), row-major: pycocotools decodes column-major."""
    from pycocotools import mask as coco

    counts = rle["counts"]
    encoded = {
        "size": list(rle["size"]),
        "counts": counts.encode("ascii") if isinstance(counts, str) else counts,
    }
    columns = coco.decode(encoded)  # H×W 0/1 uint8, column-major: its .T is a row-major W×H
    rows: NDArray[np.bool_] = cv2.transpose(columns.T).view(bool)  # OpenCV's transpose: 10× numpy's
    return rows


def _coco_encoded(fortran: NDArray[Any]) -> CocoMask:
    from pycocotools import mask as coco

    rle = coco.encode(fortran)
    box = [round(v) for v in coco.toBbox(rle).tolist()]
    counts = {"size": [int(v) for v in rle["size"]], "counts": rle["counts"].decode("ascii")}
    return CocoMask(counts, int(coco.area(rle)), box)


def mask_polygons(
    mask: NDArray[np.bool_], tolerance: float = 1.0, min_area: float = 0.0
) -> list[Polygon]:
    """The outline of ``mask``: outer boundaries first, each followed by its holes.

    Args:
        mask: H×W boolean mask.
        tolerance: Douglas–Peucker distance in pixels (0 keeps every boundary pixel).
        min_area: outer boundaries enclosing less than this many pixels² are dropped, with
            their holes (specks); holes smaller than it are dropped too. Regions whose boundary
            has fewer than 3 vertices (a lone pixel, a line one pixel wide) are always dropped.
    """
    binary = np.ascontiguousarray(mask, dtype=np.uint8)
    contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if hierarchy is None:
        return []
    links = hierarchy[0]  # next, previous, first child, parent
    polygons: list[Polygon] = []
    for index, link in enumerate(links):
        if link[3] != -1:
            continue  # a hole: written after its region
        outer = _simplified(contours[index], tolerance)
        if len(outer.points) < 3 or outer.area() < min_area:
            continue  # a speck, or a line one pixel wide: no area to edit or export
        polygons.append(outer)
        child = int(link[2])
        while child != -1:
            hole = _simplified(contours[child], tolerance, hole=True)
            if len(hole.points) >= 3 and hole.area() >= min_area:
                polygons.append(hole)
            child = int(links[child][0])
    return polygons


OUTLINE_TOLERANCE = 1.0
"""Douglas–Peucker tolerance (px) of the outlines formats without masks get (YOLO)."""
OUTLINE_MIN_AREA = 4.0
"""Regions enclosing fewer pixels² than this are specks those outlines leave out. Labels store
their outlines when saved (``Label.mask_outlines``): changing either constant leaves the stored
ones as they were (null the column to have the export trace them again)."""


def region_outlines(mask: NDArray[np.bool_]) -> list[list[list[float]]]:
    """Each region's outer boundary ``[[x, y], …]`` (frame pixels), simplified by
    ``OUTLINE_TOLERANCE`` and without specks: what a format without masks or holes (Ultralytics
    YOLO segmentation) gets of a mask, and what a label stores when it is saved."""
    return [
        [[x, y] for x, y in polygon.points]
        for polygon in mask_polygons(mask, OUTLINE_TOLERANCE, OUTLINE_MIN_AREA)
        if not polygon.hole
    ]


def _simplified(contour: NDArray[Any], tolerance: float, *, hole: bool = False) -> Polygon:
    if tolerance > 0 and len(contour) > 3:
        contour = cv2.approxPolyDP(contour, tolerance, closed=True)
    return Polygon([(float(x), float(y)) for x, y in contour.reshape(-1, 2)], hole=hole)


def fill_polygons(polygons: list[Polygon], height: int, width: int) -> NDArray[np.bool_]:
    """Rasterise an outline: every outer polygon filled with its edges, then every hole emptied
    inside its edges. Vertices outside the frame are clipped by the fill.

    Raises:
        InvalidInputError: too many polygons or vertices, or a polygon with fewer than 3.
    """
    if len(polygons) > MAX_POLYGONS:
        raise InvalidInputError(f"An outline has at most {MAX_POLYGONS} polygons.")
    if sum(len(p.points) for p in polygons) > MAX_VERTICES:
        raise InvalidInputError(f"An outline has at most {MAX_VERTICES} vertices in all.")
    if any(len(p.points) < 3 for p in polygons):
        raise InvalidInputError("Every polygon of an outline needs at least 3 vertices.")
    canvas = np.zeros((height, width), dtype=np.uint8)
    outers = [_pixels(p) for p in polygons if not p.hole]
    holes = [_pixels(p) for p in polygons if p.hole]
    if outers:
        cv2.fillPoly(canvas, outers, 1, lineType=cv2.LINE_8)
        cv2.polylines(canvas, outers, True, 1, thickness=1, lineType=cv2.LINE_8)
    if holes:
        cv2.fillPoly(canvas, holes, 0, lineType=cv2.LINE_8)
        cv2.polylines(canvas, holes, True, 1, thickness=1, lineType=cv2.LINE_8)
    return canvas.astype(bool)


def _pixels(polygon: Polygon) -> NDArray[np.int32]:
    return np.rint(np.asarray(polygon.points, dtype=np.float64)).astype(np.int32).reshape(-1, 1, 2)


def normalised(
    polygon: Polygon | Sequence[Sequence[float]], height: int, width: int
) -> list[float]:
    """A polygon (or its ``[[x, y], …]``) as ``x1 y1 x2 y2 …`` in 0–1 of the frame (YOLO), pixel
    centres, clipped."""
    points = polygon.points if isinstance(polygon, Polygon) else polygon
    xy = (np.asarray(points, dtype=np.float64) + 0.5) / np.array([width, height])
    return [round(float(v), 6) for v in np.clip(xy, 0.0, 1.0).reshape(-1)]
