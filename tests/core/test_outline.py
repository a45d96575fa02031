"""The outline a reviewer edits: masks as polygons and back, holes, simplification, YOLO."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.core.shapes import pool_blob
from tests.helpers import real_label_masks
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import read_mask
from weldpool_core.outline import (
    Polygon,
    coco_mask,
    fill_polygons,
    mask_polygons,
    normalised,
    rle_mask,
)


def ring_and_square() -> np.ndarray:
    """An ellipse with a round hole, and a separate rectangle, on a 200×300 frame."""
    mask = np.zeros((200, 300), np.uint8)
    cv2.ellipse(mask, (150, 100), (80, 50), 20, 0, 360, 1, -1)
    cv2.circle(mask, (150, 100), 15, 0, -1)
    cv2.rectangle(mask, (10, 10), (40, 30), 1, -1)
    return mask.astype(bool)


@pytest.mark.parametrize("seed", range(6))
def test_an_unsimplified_outline_fills_back_to_the_same_mask(seed: int) -> None:
    mask = pool_blob(seed)
    assert np.array_equal(fill_polygons(mask_polygons(mask, 0), *mask.shape), mask)


def test_holes_and_separate_regions_survive() -> None:
    mask = ring_and_square()
    polygons = mask_polygons(mask, 0)
    assert [p.hole for p in polygons] == [False, True, False] or [p.hole for p in polygons] == [
        False,
        False,
        True,
    ]
    back = fill_polygons(polygons, *mask.shape)
    assert np.array_equal(back, mask)
    assert not back[100, 150]  # the hole's centre stays empty
    assert back[20, 25]  # the rectangle is kept


def test_simplification_keeps_the_shape_with_far_fewer_vertices() -> None:
    mask = ring_and_square()
    exact = mask_polygons(mask, 0)
    simple = mask_polygons(mask, 1.0)
    assert sum(len(p.points) for p in simple) * 5 < sum(len(p.points) for p in exact)
    back = fill_polygons(simple, *mask.shape)
    assert (back & mask).sum() / (back | mask).sum() > 0.98
    assert not back[100, 150]


def test_moving_a_vertex_changes_the_area_by_the_triangle_it_sweeps() -> None:
    mask = np.zeros((100, 160), bool)
    mask[20:61, 30:91] = True  # a 61×41 rectangle
    (square,) = mask_polygons(mask, 1.0)
    assert sorted(square.points) == [(30.0, 20.0), (30.0, 60.0), (90.0, 20.0), (90.0, 60.0)]
    # Pull the bottom-right corner 20 px to the right: a triangle of base 40 and height 20 is added.
    points = [(110.0, 60.0) if p == (90.0, 60.0) else p for p in square.points]
    grown = fill_polygons([Polygon(points)], 100, 160)
    assert grown.sum() - mask.sum() == pytest.approx(400, abs=25)
    assert grown[58, 105] and not grown[22, 105]  # the new part is at the bottom right, not the top


def test_small_specks_are_dropped_when_asked() -> None:
    mask = ring_and_square()
    mask[190, 290] = True
    mask[150:153, 250:253] = True  # 3×3: its outline encloses 4 px²
    assert len(mask_polygons(mask, 1.0)) == 4  # the lone pixel has no polygon
    assert len(mask_polygons(mask, 1.0, min_area=5)) == 3


def test_yolo_coordinates_are_x_over_width_and_y_over_height() -> None:
    polygon = Polygon([(0.0, 0.0), (299.0, 0.0), (299.0, 49.0)])
    expected = [0.5 / 300, 0.5 / 200, 299.5 / 300, 0.5 / 200, 299.5 / 300, 49.5 / 200]
    assert normalised(polygon, 200, 300) == pytest.approx(expected, abs=1e-6)
    assert normalised(Polygon([(-5.0, 0.0), (400.0, 0.0), (0.0, 250.0)]), 200, 300)[2:] == [
        1.0,
        pytest.approx(0.0025),
        pytest.approx(0.5 / 300, abs=1e-6),
        1.0,
    ]


def test_a_stored_rle_decodes_to_its_mask_row_major() -> None:
    mask = np.zeros((100, 160), bool)  # wider than high, and not symmetric: a transpose shows
    mask[20:80, 30:130] = True
    mask[40:60, 60:90] = False
    mask[5:9, 150:158] = True
    back = rle_mask(coco_mask(mask).rle)
    assert back.dtype == bool and back.flags.c_contiguous
    assert np.array_equal(back, mask)
    assert mask_polygons(back, 1.0) == mask_polygons(mask, 1.0)


def test_bad_outlines_are_refused_in_one_sentence() -> None:
    with pytest.raises(InvalidInputError, match="at least 3 vertices"):
        fill_polygons([Polygon([(0.0, 0.0), (5.0, 5.0)])], 10, 10)
    with pytest.raises(InvalidInputError, match="at most"):
        fill_polygons([Polygon([(0.0, 0.0), (5.0, 5.0), (0.0, 5.0)])] * 10_001, 10, 10)


@pytest.mark.parametrize(
    "vertex", [(-161.0, 0.0), (0.0, -101.0), (321.0, 50.0), (80.0, 201.0), (3e9, -3e9)]
)
def test_a_vertex_more_than_a_frame_size_outside_is_refused(vertex: tuple[float, float]) -> None:
    """The fill walks every row from the topmost vertex: a vertex at y = −3e9 cost minutes."""
    with pytest.raises(InvalidInputError, match="more than one frame width or height outside"):
        fill_polygons([Polygon([(0.0, 0.0), vertex, (0.0, 99.0)])], 100, 160)


def test_vertices_within_a_frame_size_outside_are_clipped_by_the_fill() -> None:
    far = [(-160.0, -100.0), (320.0, -100.0), (320.0, 200.0), (-160.0, 200.0)]
    assert fill_polygons([Polygon(far)], 100, 160).all()
    left = fill_polygons([Polygon([(-160.0, -100.0), (80.0, -100.0), (80.0, 200.0)])], 100, 160)
    assert left[:, 81:].sum() == 0 and left[0, :81].all()


def _crossing_number(polygons: list[Polygon], height: int, width: int) -> np.ndarray:
    """Pixel centres inside the rounded polygons by the even–odd rule's definition: an odd
    number of edges crosses the row left of the centre or on it (half-open in y, so a vertex
    counts once)."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    inside = np.zeros((height, width), bool)
    for polygon in polygons:
        xy = np.rint(np.asarray(polygon.points, dtype=np.float64))
        for (x0, y0), (x1, y1) in zip(xy, np.roll(xy, -1, axis=0), strict=True):
            if y0 != y1:
                spans = (np.minimum(y0, y1) <= y) & (y < np.maximum(y0, y1))
                inside ^= spans & (x0 + (y - y0) * (x1 - x0) / (y1 - y0) <= x)
    return inside


@pytest.mark.parametrize("seed", range(40))
def test_an_outline_partly_outside_is_filled_as_its_geometry_says(seed: int) -> None:
    """Pixels off the drawn edges are inside exactly when the even–odd rule says so, also where
    vertices lie outside the frame (OpenCV's fill painted stripes along the frame's edge there,
    up to 8 px from any edge of the outline)."""
    rng = np.random.default_rng(seed)
    height, width = int(rng.integers(8, 40)), int(rng.integers(8, 40))

    def polygon(hole: bool) -> Polygon:
        corners = rng.uniform([-width, -height], [2 * width, 2 * height], (rng.integers(3, 8), 2))
        return Polygon([(float(x), float(y)) for x, y in corners], hole)

    outers, holes = [polygon(False), polygon(False)], [polygon(True)]
    filled = fill_polygons(outers + holes, height, width)

    def drawn(polygons: list[Polygon]) -> np.ndarray:
        edges = np.zeros((height, width), np.uint8)
        points = [
            np.rint(np.asarray(p.points)).astype(np.int32).reshape(-1, 1, 2) for p in polygons
        ]
        return cv2.polylines(edges, points, True, 1).astype(bool)

    expected = _crossing_number(outers, height, width) & ~_crossing_number(holes, height, width)
    off_edges = ~drawn(outers + holes)
    assert np.array_equal(filled[off_edges], expected[off_edges])
    assert filled[drawn(holes)].all()  # a hole's edge belongs to the region around it


def test_edges_crossing_too_many_rows_are_refused() -> None:
    """The fill's work is a step per row an edge crosses: 3,333 triangles the height of a tall
    frame would be 133 million steps for its 2 million pixels."""
    slivers = [
        Polygon([(x, -20_000.0), (x + 1, 40_000.0), (x - 1, 40_000.0)]) for x in range(1, 100, 3)
    ]
    assert fill_polygons(slivers, 20_000, 100).sum() > 0  # 33 slivers: 1.3 million crossings
    with pytest.raises(InvalidInputError, match="cross the frame's rows more than 8,000,000 times"):
        fill_polygons(slivers * 101, 20_000, 100)


def test_an_outline_has_at_most_10_000_vertices_in_all() -> None:
    """The documented cap (``outline.MAX_VERTICES``): it bounds the fill's work."""
    squares = []  # 2 500 squares of 2×2 px side by side, 4 vertices each: the cap exactly
    for index in range(2_500):
        x, y = 2.0 * (index % 75), 2.0 * (index // 75)
        squares.append(Polygon([(x, y), (x + 1, y), (x + 1, y + 1), (x, y + 1)]))
    assert fill_polygons(squares, 100, 160).sum() == 150 * 66 + 50 * 2
    with pytest.raises(InvalidInputError, match="at most 10,000 vertices in all"):
        fill_polygons([*squares, Polygon([(0.0, 0.0)] * 3)], 100, 160)


def test_real_pool_masks_round_trip() -> None:
    for path in real_label_masks():
        mask = read_mask(path)
        assert np.array_equal(fill_polygons(mask_polygons(mask, 0), *mask.shape), mask), path.name
        simple = mask_polygons(mask, 1.0)
        back = fill_polygons(simple, *mask.shape)
        assert (back & mask).sum() / (back | mask).sum() > 0.98, path.name
        assert sum(len(p.points) for p in simple) < 400, path.name
