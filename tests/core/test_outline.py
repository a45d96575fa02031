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


def test_real_pool_masks_round_trip() -> None:
    for path in real_label_masks():
        mask = read_mask(path)
        assert np.array_equal(fill_polygons(mask_polygons(mask, 0), *mask.shape), mask), path.name
        simple = mask_polygons(mask, 1.0)
        back = fill_polygons(simple, *mask.shape)
        assert (back & mask).sum() / (back | mask).sum() > 0.98, path.name
        assert sum(len(p.points) for p in simple) < 400, path.name
