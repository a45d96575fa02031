"""A mask as polygons and back: the outline a reviewer edits vertex by vertex, and the polygons
of formats that have no masks (Ultralytics YOLO segmentation).

``mask_polygons`` traces every region's outer boundary and every hole's boundary (OpenCV's
two-level contour hierarchy) and simplifies them with Douglas–Peucker (``tolerance`` in pixels;
0 keeps every boundary pixel). Vertices are pixel indices ``(x, y)`` of boundary pixels, so
``fill_polygons`` of an unsimplified outline gives the mask back pixel for pixel: outer polygons
are filled with their edges, holes are emptied inside their edges (the hole's boundary pixels
belong to the region around it). The fill is even–odd over pixel centres, row band by row band
(``_even_odd``): its work is one step per row an edge crosses plus one per pixel, whatever the
edges' order or crossings (OpenCV's ``fillPoly`` re-sorts crossing edges row by row: 35 s for
10,000 vertices laid out against it).

``coco_mask`` is a mask as COCO holds it: compressed RLE (holes survive, unlike outer
polygons), area and bounding box, from pycocotools (the reference implementation every COCO
reader uses); ``coco_mask_png`` reads a stored 0/1 or 0/255 mask PNG the short way, and
``rle_mask`` decodes the RLE back to a mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError
from weldpool_core.io import encode_mask_png, mask_gray, mask_level

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

MAX_VERTICES = 10_000
"""Most vertices an outline may have in all. The polygon tool sends tens (a pool traced at
tolerance 1 has ~50; at tolerance 0 ~2,400 on a 1280×800 frame); reading 10,000 from JSON takes
under 0.1 s."""
MAX_POLYGONS = MAX_VERTICES // 3
"""Most polygons an outline may have (each has 3 vertices or more)."""
MAX_CROSSINGS_PER_PIXEL = 4
"""How many times per frame pixel an outline's edges may cross the frame's rows: the fill takes
a step per crossing, and a traced mask crosses them at most twice per pixel."""
MIN_CROSSINGS = 1 << 22
"""The crossings allowed on any frame, however small (about 0.15 s of filling)."""


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
    """``CocoMask`` of a mask PNG (the mask ``io.decode_mask_png`` reads from it), decoded,
    transposed and thresholded by OpenCV straight into the column-major 0/1 array pycocotools
    encodes (a third faster than decoding to a boolean mask and copying it to column order)."""
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise InvalidInputError("The mask is not a readable PNG image.")
    gray = mask_gray(decoded)  # the readers' one rule (io.mask_level)
    _, columns = cv2.threshold(cv2.transpose(gray), mask_level(gray), 1, cv2.THRESH_BINARY)
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


def rle_counts(counts: str | bytes) -> NDArray[np.int64]:
    """The run lengths of COCO's compressed RLE string (background first, then pool, …), as
    pycocotools' ``rleFrString`` reads it, in numpy: 5-bit groups, least significant first,
    ``0x20`` for more to come and ``0x10`` for a negative last group; from the fourth run on,
    each is stored as the difference to the run two before it.

    Raises:
        ValueError: a character outside the code, a number cut off or too long, a negative run.
    """
    raw = counts.encode("ascii") if isinstance(counts, str) else bytes(counts)
    code = np.frombuffer(raw, np.uint8).astype(np.int64) - 48
    if code.size == 0:
        return np.zeros(0, np.int64)
    if int(code.min()) < 0 or int(code.max()) > 63:
        raise ValueError("a character outside the RLE code")
    ends = np.flatnonzero((code & 0x20) == 0)  # the last character of each number
    if ends.size == 0 or ends[-1] != code.size - 1:
        raise ValueError("the counts end inside a number")
    starts = np.concatenate(([0], ends[:-1] + 1))
    place = np.arange(code.size) - np.repeat(starts, ends - starts + 1)
    if int(place.max()) > 7:
        raise ValueError("a run longer than an image can be")
    values = np.add.reduceat((code & 0x1F) << (5 * place), starts)
    negative = (code[ends] & 0x10) != 0
    values[negative] -= np.left_shift(1, 5 * (place[ends][negative] + 1))
    values[3::2] = np.cumsum(values[1::2])[1:]
    values[4::2] = np.cumsum(values[2::2])[1:]
    if values.size and int(values.min()) < 0:
        raise ValueError("a negative run")
    return values


@dataclass(frozen=True)
class BoxedMask:
    """A frame's mask held as the pixels of its regions' bounding box: ``pixels`` at ``origin``
    ``(left, top)`` of a frame of ``size`` ``(height, width)``, background elsewhere. What a
    label's work (outline, Algorithm 1, the mask PNG) needs, without a frame-sized array."""

    pixels: NDArray[np.bool_]
    origin: tuple[int, int]
    size: tuple[int, int]

    @classmethod
    def of(cls, mask: NDArray[np.bool_]) -> BoxedMask:
        x, y, w, h = cv2.boundingRect(np.ascontiguousarray(mask).view(np.uint8))
        height, width = mask.shape
        return cls(mask[y : y + h, x : x + w], (x, y), (height, width))

    @property
    def empty(self) -> bool:
        return not self.pixels.any()

    def frame_mask(self) -> NDArray[np.bool_]:
        """The whole frame's mask."""
        full = np.zeros(self.size, bool)
        (left, top), (height, width) = self.origin, self.pixels.shape
        full[top : top + height, left : left + width] = self.pixels
        return full


def rle_boxed(rle: dict[str, Any], box: Sequence[float] | None = None) -> BoxedMask:
    """The mask of a compressed RLE ``{"size": [h, w], "counts": str}`` as a ``BoxedMask`` over
    ``box`` ``[x, y, width, height]`` (as ``CocoMask.bbox`` holds it; pixels outside it are
    left out), or the runs' own box: only the box's columns are laid out from the runs and
    only the box is put in row order (never the frame's million pixels that ``rle_mask``
    decodes and transposes).

    Raises:
        ValueError: the counts are not an RLE of ``size`` (the runs do not cover it exactly).
    """
    height, width = (int(v) for v in rle["size"])
    runs = rle_counts(rle["counts"])
    ends = np.cumsum(runs)
    covered = int(ends[-1]) if ends.size else 0
    if covered != height * width:
        raise ValueError(f"the runs cover {covered} pixels, not {height}×{width}")
    if box is None:
        found = _runs_box(ends, runs.size, height)
        if found is None:
            return BoxedMask(np.zeros((0, 0), bool), (0, 0), (height, width))
        x0, y0, x1, y1 = found
    else:
        x0, y0 = int(box[0]), int(box[1])
        x1, y1 = x0 + int(box[2]), y0 + int(box[3])
    first, last = x0 * height, x1 * height
    inside = np.clip(ends, first, last) - np.clip(ends - runs, first, last)
    values = np.arange(runs.size, dtype=np.uint8) & 1  # runs alternate, 0s first
    columns = np.repeat(values, inside).reshape(x1 - x0, height)[:, y0:y1]
    rows: NDArray[np.bool_] = cv2.transpose(np.ascontiguousarray(columns)).view(bool)
    return BoxedMask(rows, (x0, y0), (height, width))


def _runs_box(ends: NDArray[np.int64], count: int, height: int) -> tuple[int, int, int, int] | None:
    """The box ``(x0, y0, x1, y1)`` (ends exclusive) of the pool runs ending at ``ends``
    (column-major), or None when there is no pool."""
    starts, stops = ends[0::2][: count // 2], ends[1::2]
    kept = stops > starts
    starts, stops = starts[kept], stops[kept]
    if starts.size == 0:
        return None
    x0, x1 = int(starts[0]) // height, (int(stops[-1]) - 1) // height + 1
    crossing = bool(((stops - 1) // height > starts // height).any())  # a run over a column's end
    y0 = 0 if crossing else int((starts % height).min())
    y1 = height if crossing else int(((stops - 1) % height).max()) + 1
    return x0, y0, x1, y1


def coco_rle(rle: dict[str, Any]) -> CocoMask:
    """``CocoMask`` of a compressed RLE as it is (area and box read from the runs)."""
    from pycocotools import mask as coco

    encoded = {"size": list(rle["size"]), "counts": rle["counts"].encode("ascii")}
    box = [round(v) for v in coco.toBbox(encoded).tolist()]
    return CocoMask(dict(rle), int(coco.area(encoded)), box)


def _coco_encoded(fortran: NDArray[Any]) -> CocoMask:
    from pycocotools import mask as coco

    rle = coco.encode(fortran)
    box = [round(v) for v in coco.toBbox(rle).tolist()]
    counts = {"size": [int(v) for v in rle["size"]], "counts": rle["counts"].decode("ascii")}
    return CocoMask(counts, int(coco.area(rle)), box)


def mask_polygons(
    mask: NDArray[np.bool_],
    tolerance: float = 1.0,
    min_area: float = 0.0,
    origin: tuple[int, int] = (0, 0),
) -> list[Polygon]:
    """The outline of ``mask``: outer boundaries first, each followed by its holes.

    Args:
        mask: H×W boolean mask.
        tolerance: Douglas–Peucker distance in pixels (0 keeps every boundary pixel).
        min_area: outer boundaries enclosing less than this many pixels² are dropped, with
            their holes (specks); holes smaller than it are dropped too. Regions whose boundary
            has fewer than 3 vertices (a lone pixel, a line one pixel wide) are always dropped.
        origin: ``(left, top)`` of ``mask`` in its frame when it is only the part around the
            regions (the rest background): the same polygons as the whole frame's, in its pixels.
    """
    binary = np.ascontiguousarray(mask, dtype=np.uint8)
    contours, hierarchy = cv2.findContours(
        binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE, offset=origin
    )
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


def region_outlines(
    mask: NDArray[np.bool_], origin: tuple[int, int] = (0, 0)
) -> list[list[list[float]]]:
    """Each region's outer boundary ``[[x, y], …]`` (frame pixels), simplified by
    ``OUTLINE_TOLERANCE`` and without specks: what a format without masks or holes (Ultralytics
    YOLO segmentation) gets of a mask, and what a label stores when it is saved. ``origin``: as
    ``mask_polygons``'."""
    return [
        [[x, y] for x, y in polygon.points]
        for polygon in mask_polygons(mask, OUTLINE_TOLERANCE, OUTLINE_MIN_AREA, origin)
        if not polygon.hole
    ]


def _simplified(contour: NDArray[Any], tolerance: float, *, hole: bool = False) -> Polygon:
    if tolerance > 0 and len(contour) > 3:
        contour = cv2.approxPolyDP(contour, tolerance, closed=True)
    return Polygon([(float(x), float(y)) for x, y in contour.reshape(-1, 2)], hole=hole)


def check_editable(polygons: list[Polygon], traced: float | None = None) -> None:
    """Refuse an outline with more polygons or vertices than an edited one may have (what
    ``fill_polygons`` takes back); ``traced``: the tolerance a mask was traced at, which the
    refusal then advises raising.

    Raises:
        InvalidInputError: more than ``MAX_POLYGONS`` polygons or ``MAX_VERTICES`` vertices.
    """
    vertices = sum(len(p.points) for p in polygons)
    if len(polygons) <= MAX_POLYGONS and vertices <= MAX_VERTICES:
        return
    if traced is not None:
        raise InvalidInputError(
            f"The mask traces to {vertices:,} vertices in {len(polygons):,} polygons at tolerance "
            f"{traced:g}, more than an outline may have ({MAX_VERTICES:,} vertices, "
            f"{MAX_POLYGONS:,} polygons); raise the tolerance or edit the mask with the brush."
        )
    if len(polygons) > MAX_POLYGONS:
        raise InvalidInputError(f"An outline has at most {MAX_POLYGONS:,} polygons.")
    raise InvalidInputError(f"An outline has at most {MAX_VERTICES:,} vertices in all.")


def fill_polygons(polygons: list[Polygon], height: int, width: int) -> NDArray[np.bool_]:
    """Rasterise an outline: every outer polygon filled with its edges, then every hole emptied
    inside its edges (even–odd: where outer polygons overlap, the overlap is outside). Vertices
    are rounded to pixels; those outside the frame are clipped by the fill, and those more than
    one frame width or height outside it are refused, so the work follows the frame's size.

    Raises:
        InvalidInputError: too many polygons or vertices, a polygon with fewer than 3, a vertex
            more than one frame size outside the frame, or edges crossing the frame's rows more
            than ``MAX_CROSSINGS_PER_PIXEL`` times per pixel (and ``MIN_CROSSINGS`` times).
    """
    check_editable(polygons)
    if any(len(p.points) < 3 for p in polygons):
        raise InvalidInputError("Every polygon of an outline needs at least 3 vertices.")
    _check_near_frame(polygons, height, width)
    outers = [_pixels(p) for p in polygons if not p.hole]
    holes = [_pixels(p) for p in polygons if p.hole]
    outer_edges, hole_edges = _Edges.of(outers, height), _Edges.of(holes, height)
    limit = max(MAX_CROSSINGS_PER_PIXEL * height * width, MIN_CROSSINGS)
    if outer_edges.crossings + hole_edges.crossings > limit:
        raise InvalidInputError(
            f"The outline's edges cross the frame's rows more than {limit:,} times; "
            "simplify the outline."
        )
    canvas = np.zeros((height, width), dtype=np.uint8)
    if outers:
        canvas[_even_odd(outer_edges, height, width)] = 1
        cv2.polylines(canvas, outers, True, 1, thickness=1, lineType=cv2.LINE_8)
    if holes:
        canvas[_even_odd(hole_edges, height, width)] = 0
        cv2.polylines(canvas, holes, True, 1, thickness=1, lineType=cv2.LINE_8)
    return canvas.astype(bool)


_BAND_STEPS = 1 << 20
"""About how many pixels and edge crossings one row band of the fill holds (memory, not work)."""


@dataclass(frozen=True)
class _Edges:
    """The non-horizontal edges of closed integer polygons, each over the frame rows
    ``first ≤ y < stop`` it crosses (half-open, so a vertex on a row counts once)."""

    x0: NDArray[np.float64]
    y0: NDArray[np.float64]
    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    first: NDArray[np.int64]
    stop: NDArray[np.int64]

    @classmethod
    def of(cls, polygons: list[NDArray[np.int32]], height: int) -> _Edges:
        if not polygons:
            empty = np.zeros(0)
            return cls(empty, empty, empty, empty, empty.astype(np.int64), empty.astype(np.int64))
        start = np.concatenate([p.reshape(-1, 2) for p in polygons]).astype(np.float64)
        end = np.concatenate([np.roll(p.reshape(-1, 2), -1, axis=0) for p in polygons])
        x0, y0 = start[:, 0], start[:, 1]
        x1, y1 = end[:, 0].astype(np.float64), end[:, 1].astype(np.float64)
        first = np.clip(np.minimum(y0, y1), 0, height).astype(np.int64)
        stop = np.clip(np.maximum(y0, y1), 0, height).astype(np.int64)
        kept = stop > first
        x0, y0, x1, y1 = x0[kept], y0[kept], x1[kept], y1[kept]
        return cls(x0, y0, x1 - x0, y1 - y0, first[kept], stop[kept])

    @property
    def crossings(self) -> int:
        return int((self.stop - self.first).sum())


def _even_odd(edges: _Edges, height: int, width: int) -> NDArray[np.bool_]:
    """The pixels with an odd number of edge crossings left of their centre on their row, one
    row band at a time: each crossing toggles the pixels from it rightwards, and a running sum
    along the row gives their parity (pixels exactly on an edge are left to the edges drawn
    afterwards)."""
    inside = np.zeros((height, width), dtype=bool)
    rows = max(1, min(_BAND_STEPS // (width + 1), _BAND_STEPS // max(1, len(edges.first))))
    for top in range(0, height, rows):
        bottom = min(height, top + rows)
        live = (edges.first < bottom) & (edges.stop > top)
        if not live.any():
            continue
        first = np.maximum(edges.first[live], top)
        counts = np.minimum(edges.stop[live], bottom) - first
        edge = np.repeat(np.flatnonzero(live), counts)
        row = (
            np.repeat(first, counts)
            + np.arange(len(edge))
            - np.repeat(np.cumsum(counts) - counts, counts)
        )
        # Product before quotient: a crossing on a pixel centre comes out exact.
        x = edges.x0[edge] + (row - edges.y0[edge]) * edges.dx[edge] / edges.dy[edge]
        column = np.clip(np.ceil(x), 0, width).astype(np.int64)
        toggles = np.bincount(
            (row - top) * (width + 1) + column, minlength=(bottom - top) * (width + 1)
        ).reshape(bottom - top, width + 1)[:, :width]
        inside[top:bottom] = np.cumsum(toggles, axis=1) % 2 == 1
    return inside


def _check_near_frame(polygons: list[Polygon], height: int, width: int) -> None:
    if not polygons:
        return
    xy = np.concatenate([np.asarray(p.points, dtype=np.float64).reshape(-1, 2) for p in polygons])
    low, high = np.array([-width, -height]), np.array([2 * width, 2 * height])
    outside = ~np.all((xy >= low) & (xy <= high), axis=1)  # NaN is outside too
    if outside.any():
        x, y = xy[int(np.argmax(outside))]
        raise InvalidInputError(
            f"The vertex ({x:g}, {y:g}) lies more than one frame width or height outside the "
            f"{width}×{height} frame; keep the outline on the frame."
        )


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


def mask_record(
    mask: NDArray[np.bool_] | BoxedMask, rle: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What a label stores of its mask besides the file: COCO RLE, area and box (from ``rle``
    when the caller has the mask's compressed RLE already), and its region outlines."""
    pixels, origin = (mask.pixels, mask.origin) if isinstance(mask, BoxedMask) else (mask, (0, 0))
    if rle is not None:
        coco = coco_rle(rle)
    else:
        coco = coco_mask(mask.frame_mask() if isinstance(mask, BoxedMask) else mask)
    outlines = region_outlines(pixels, origin)
    return {
        "mask_rle": coco.rle,
        "mask_area": coco.area,
        "mask_bbox": coco.bbox,
        "mask_outlines": outlines,
    }


def rle_mask_pngs(rles: list[dict[str, Any]]) -> list[bytes | None]:
    """The mask PNG of each stored COCO RLE (``encode_mask_png`` of ``rle_boxed``: the file
    saving wrote), None for a damaged one; a batch for the service's processes (a masks
    export from a cold cache)."""
    pngs: list[bytes | None] = []
    for rle in rles:
        try:
            boxed = rle_boxed(rle)
        except (ValueError, KeyError, TypeError):  # the label's file says what it is
            pngs.append(None)
        else:
            pngs.append(encode_mask_png(boxed.pixels, boxed.size, boxed.origin))
    return pngs
