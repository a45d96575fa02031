"""Pool geometry on shapes with known area, length and width, and on the real labelled frames."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tests.helpers import real_label_masks
from weldpool_core.geometry import pool_geometry, pool_shape
from weldpool_core.io import read_mask


def test_a_rectangle_along_x_is_as_long_and_wide_as_drawn() -> None:
    mask = np.zeros((100, 200), bool)
    mask[40:50, 20:80] = True  # 60 long in x, 10 high
    along_x = pool_geometry(mask, travel_deg=0)
    assert (along_x.area_px, along_x.length_px, along_x.width_px) == (600, 60.0, 10.0)
    assert along_x.centroid == pytest.approx((49.5, 44.5))
    # Travel downwards (90°): length and width swap — a swapped axis shows here.
    down = pool_geometry(mask, travel_deg=90)
    assert (down.length_px, down.width_px) == pytest.approx((10.0, 60.0))
    # Without a travel direction: the mask's major axis (x), so the long side is the length.
    free = pool_geometry(mask)
    assert free.travel_deg == pytest.approx(0.0) and free.length_px == pytest.approx(60.0)


@pytest.mark.parametrize("angle", [0.0, 30.0, 75.0, 120.0])
def test_a_rotated_ellipse_has_its_axes_as_length_and_width(angle: float) -> None:
    mask = np.zeros((400, 400), np.uint8)
    cv2.ellipse(mask, (200, 200), (120, 40), angle, 0, 360, 1, -1)
    mask = mask.astype(bool)
    geometry = pool_geometry(mask)
    assert (geometry.travel_deg - angle + 90) % 180 - 90 == pytest.approx(0, abs=1.0)
    assert geometry.length_px == pytest.approx(241, abs=2.5)
    assert geometry.width_px == pytest.approx(81, abs=2.5)
    assert geometry.area_px == pytest.approx(math.pi * 120 * 40, rel=0.02)
    assert geometry.centroid == pytest.approx((200, 200), abs=0.5)
    # Measured across the pool instead, the numbers swap.
    across = pool_geometry(mask, travel_deg=angle + 90)
    assert across.length_px == pytest.approx(81, abs=2.5)


@pytest.mark.parametrize("angle", [20.0, 110.0])
def test_a_small_mask_placed_in_frame_pixels_measures_like_the_full_one(angle: float) -> None:
    """A model's 4× smaller (and, with a resized input, non-square) mask, measured in frame
    pixels, gives the full-resolution geometry: scale, offset and axes each matter."""
    full = np.zeros((400, 640), np.uint8)
    cv2.ellipse(full, (330, 190), (150, 50), angle, 0, 360, 1, -1)
    truth = pool_geometry(full.astype(bool))
    for sx, sy in [(0.25, 0.25), (0.25, 0.4)]:
        small = cv2.resize(full, None, fx=sx, fy=sy, interpolation=cv2.INTER_NEAREST).astype(bool)
        # pixel centre (j, i) of the small mask is frame point ((j + 0.5) / sx − 0.5, …)
        origin = (0.5 / sx - 0.5, 0.5 / sy - 0.5)
        placed = pool_shape(small, origin=origin, pixel=(1 / sx, 1 / sy)).measure()
        assert placed.area_px == pytest.approx(truth.area_px, rel=0.03)
        assert placed.centroid == pytest.approx(truth.centroid, abs=2.0)
        assert (placed.travel_deg - truth.travel_deg + 90) % 180 - 90 == pytest.approx(0, abs=2)
        assert placed.length_px == pytest.approx(truth.length_px, abs=4.0)
        assert placed.width_px == pytest.approx(truth.width_px, abs=4.0)
    unplaced = pool_shape(small).measure()
    assert unplaced.length_px < 0.5 * truth.length_px  # without the placement: model pixels


def test_millimetres_follow_the_scale_and_an_empty_mask_has_no_pool() -> None:
    mask = np.zeros((50, 50), bool)
    mask[10:20, 10:30] = True
    geometry = pool_geometry(mask, travel_deg=0)
    assert geometry.in_mm(0.05) == pytest.approx(
        {"area_mm2": 200 * 0.0025, "length_mm": 1.0, "width_mm": 0.5}
    )
    assert geometry.in_mm(None) == {"area_mm2": None, "length_mm": None, "width_mm": None}
    empty = pool_geometry(np.zeros((5, 5), bool))
    assert (empty.area_px, empty.length_px, empty.centroid) == (0, None, None)


def test_real_pools_are_longer_than_wide_and_match_their_pixels() -> None:
    for path in real_label_masks():
        mask = read_mask(path)
        geometry = pool_geometry(mask)
        assert geometry.area_px == int(mask.sum())
        assert geometry.length_px >= geometry.width_px > 0
        ys, xs = np.nonzero(mask)
        assert geometry.centroid == pytest.approx((xs.mean(), ys.mean()))


def test_the_scale_from_two_points_is_their_distance_over_their_separation() -> None:
    """A 3-4-5 triangle: points 50 px apart, 10 mm apart → 0.2 mm/px, whichever way round and
    whichever axis; points that are (almost) one point or a distance ≤ 0 are refused."""
    from weldpool_core.errors import InvalidInputError
    from weldpool_core.geometry import scale_from_points

    assert scale_from_points((10, 20), (40, 60), 10.0) == pytest.approx(0.2)
    assert scale_from_points((40, 60), (10, 20), 10.0) == pytest.approx(0.2)
    assert scale_from_points((0, 0), (0, 200), 5.0) == pytest.approx(0.025)  # y counts too
    assert scale_from_points((0, 0), (200, 0), 5.0) == pytest.approx(0.025)
    with pytest.raises(InvalidInputError, match=r"0\.5 px apart"):
        scale_from_points((3, 3), (3.5, 3), 1.0)
    with pytest.raises(InvalidInputError, match="positive"):
        scale_from_points((0, 0), (100, 0), 0.0)
