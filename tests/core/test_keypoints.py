"""The order rule and the modes of a heatmap (what the student's output is read with)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from tests.core.shapes import SQUARE, polygon_mask, pool_blob
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import heatmap_from_mask
from weldpool_core.keypoints import (
    ModeParams,
    angles_around,
    keypoints_from_heatmap,
    order_by_angle,
)


def _gaussians(
    centres: list[tuple[float, float]], sigma: float = 3.0, peaks: list[float] | None = None
) -> np.ndarray:
    ys, xs = np.mgrid[0:120, 0:160].astype(np.float64)
    heat = np.zeros((120, 160))
    for (cx, cy), peak in zip(centres, peaks or [1.0] * len(centres), strict=True):
        heat += peak * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * sigma**2))
    return heat.astype(np.float32)


def test_order_rule_runs_clockwise_on_screen_from_the_left() -> None:
    points = np.array([[1, 0], [0, 1], [0, -1], [-1, -1], [-1, 0.1], [-1, -0.1]], np.float64)
    ordered = points[order_by_angle(points, (0.0, 0.0))]
    assert ordered.tolist() == [[-1, -0.1], [-1, -1], [0, -1], [1, 0], [0, 1], [-1, 0.1]]
    angles = angles_around(points, (0.0, 0.0))
    assert angles.min() >= 0 and angles.max() < 2 * np.pi
    assert order_by_angle(points, (0.0, 0.0), start_deg=0.0)[0] == 0  # from the right instead


def test_modes_are_found_sub_pixel_and_in_order() -> None:
    # In the order rule around (80, 60): up-left, up-right, down-right, down-left.
    centres = [(40.3, 30.7), (120.6, 35.2), (100.25, 90.8), (30.9, 85.4)]
    modes = keypoints_from_heatmap(_gaussians(centres[::-1]), k=4, centre=(80.0, 60.0))
    assert np.abs(modes - np.array(centres)).max() < 0.05


def test_strongest_modes_win_and_close_ones_are_suppressed() -> None:
    heat = _gaussians([(40, 40), (45, 41), (120, 80), (80, 100)], 1.5, [1.0, 0.9, 0.8, 0.3])
    modes = keypoints_from_heatmap(heat, k=2, params=ModeParams(min_distance=8))
    assert sorted(modes.round().tolist()) == [[40, 40], [120, 80]]


def test_a_flat_topped_mode_is_taken_at_its_first_pixel_in_raster_order() -> None:
    # An int8 student's heatmap has 256 levels, so its modes are plateaus: the strongest
    # pixel is the plateau's first in raster order, the same on every run.
    heat = _gaussians([(120, 90)], 3.0, [0.5])
    heat[40:60, 60:80] = 0.8
    modes = keypoints_from_heatmap(heat, k=1, params=ModeParams(min_distance=5))
    # Refined over the plateau's part of the 7×7 window at (60, 40): pixels 60–63, 40–43.
    assert modes.tolist() == [[61.5, 41.5]]
    two = keypoints_from_heatmap(heat, k=2, params=ModeParams(min_distance=5), centre=(0, 0))
    assert sorted(two.tolist()) == [[61.5, 41.5], [65.0, 41.5]]  # next: (65, 40), 5 px on


def test_missing_values_in_a_heatmap_count_as_zero() -> None:
    centres = [(40.3, 30.7), (120.6, 35.2)]
    heat = _gaussians(centres)
    heat[100:, :] = np.nan  # a band no model scored
    modes = keypoints_from_heatmap(heat, k=2, centre=(80.0, 60.0))
    assert np.abs(modes - np.array(centres)).max() < 0.05
    assert keypoints_from_heatmap(np.full((30, 40), np.nan, np.float32), k=2).shape == (0, 2)


def test_fewer_modes_than_k_and_an_empty_heatmap() -> None:
    assert len(keypoints_from_heatmap(_gaussians([(50, 50), (100, 60)]), k=4)) == 2
    empty = keypoints_from_heatmap(np.zeros((30, 40), np.float32), k=4)
    assert empty.shape == (0, 2)
    faint = _gaussians([(50, 50), (100, 60)], peaks=[1.0, 0.05])
    assert len(keypoints_from_heatmap(faint, k=4)) == 1  # below 10 % of the strongest mode


def test_two_channel_heatmap_orders_around_the_mask_centroid() -> None:
    mask = np.zeros((120, 160), np.float32)
    mask[20:100, 10:150] = 1
    heat = _gaussians([(10, 20), (150, 20), (150, 100), (10, 100), (80, 20)])
    stacked = np.dstack([heat, mask])
    modes = keypoints_from_heatmap(stacked, k=5)
    explicit = keypoints_from_heatmap(heat, k=5, centre=(79.5, 59.5))
    assert np.array_equal(modes, explicit)
    assert modes[0].round().tolist() == [10, 20]  # first clockwise from the left
    assert modes[1].round().tolist() == [80, 20]
    assert modes[-1].round().tolist() == [10, 100]


def test_round_trip_through_algorithm_1() -> None:
    """The modes of Algorithm 1's heatmap are its keypoints, within a pixel."""
    for mask in (polygon_mask(SQUARE), pool_blob(1), pool_blob(2), pool_blob(5)):
        result = heatmap_from_mask(mask)
        modes = keypoints_from_heatmap(result.heatmap, k=4)
        cost = np.linalg.norm(modes[:, None] - result.keypoints[None], axis=2)
        rows, cols = linear_sum_assignment(cost)
        assert len(modes) == 4 and cost[rows, cols].max() <= 1.0


@pytest.mark.parametrize("heat", [np.zeros((4, 4, 3)), np.zeros((0, 3)), np.zeros(5)])
def test_bad_heatmaps_are_clear_errors(heat: np.ndarray) -> None:
    with pytest.raises(InvalidInputError, match="heatmap"):
        keypoints_from_heatmap(heat)


def test_bad_parameters_are_clear_errors() -> None:
    with pytest.raises(InvalidInputError):
        ModeParams(min_distance=0)
    with pytest.raises(InvalidInputError):
        ModeParams(refine_level=1.5)
    with pytest.raises(InvalidInputError, match="k must"):
        keypoints_from_heatmap(np.zeros((4, 4)), k=0)
