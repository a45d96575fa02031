"""Algorithm 1: properties on random pool-like masks, known corners, degenerate masks."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from tests.core.shapes import (
    SIZE,
    SQUARE,
    TEARDROP_TIP,
    TRIANGLE,
    arc_positions,
    centroid,
    ellipse_mask,
    polygon_mask,
    pool_blob,
    teardrop_mask,
)
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, HeatmapResult, heatmap_from_mask
from weldpool_core.keypoints import angles_around
from weldpool_core.synth import nudge_outline

PROPERTY = settings(max_examples=25, deadline=None, derandomize=True)
SEEDS = st.integers(0, 2**32 - 1)


def _set_distance(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Largest distance between two keypoint sets after pairing them up optimally."""
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].max())


def _keeps_order_rule(result: HeatmapResult) -> bool:
    return bool(np.all(np.diff(angles_around(result.keypoints, centroid(result))) > 0))


@PROPERTY
@given(SEEDS, st.integers(1, 6))
def test_keypoints_lie_on_the_contour_and_keep_their_separation(seed: int, k: int) -> None:
    params = HeatmapParams(k=k)
    result = heatmap_from_mask(pool_blob(seed), params)
    assert result.keypoints.shape == (k, 2) and len(result.rules) == k
    to_contour = np.linalg.norm(result.contour[None] - result.keypoints[:, None], axis=2).min(1)
    assert to_contour.max() <= 2.0
    arcs, perimeter = arc_positions(result)
    if k > 1:
        gaps = np.abs(arcs[:, None] - arcs[None, :])
        gaps = np.minimum(gaps, perimeter - gaps) + np.eye(k) * perimeter
        assert gaps.min() >= params.separation * perimeter - 1.5


@PROPERTY
@given(SEEDS, st.integers(-12, 12), st.integers(-12, 12))
def test_translation_moves_keypoints_and_keeps_their_order(seed: int, dx: int, dy: int) -> None:
    mask = pool_blob(seed)
    moved = np.roll(np.roll(mask, dy, axis=0), dx, axis=1)  # the blob stays clear of the border
    before, after = heatmap_from_mask(mask), heatmap_from_mask(moved)
    shift = np.array([dx, dy], np.float64)
    assert np.abs(after.keypoints - (before.keypoints + shift)).max() <= 1.5
    assert after.rules == before.rules


@PROPERTY
@given(SEEDS, st.sampled_from(["left-right", "up-down", "transpose"]))
def test_mirroring_mirrors_the_keypoints_and_keeps_the_order_rule(seed: int, how: str) -> None:
    mask = pool_blob(seed)
    original = heatmap_from_mask(mask)
    expected = original.keypoints.copy()
    if how == "left-right":
        mirrored = heatmap_from_mask(mask[:, ::-1])
        expected[:, 0] = SIZE - 1 - expected[:, 0]
    elif how == "up-down":
        mirrored = heatmap_from_mask(mask[::-1])
        expected[:, 1] = SIZE - 1 - expected[:, 1]
    else:
        mirrored = heatmap_from_mask(mask.T)
        expected = expected[:, ::-1]
    assert _set_distance(mirrored.keypoints, expected) <= 1.5
    assert sorted(mirrored.rules) == sorted(original.rules)
    assert _keeps_order_rule(mirrored) and _keeps_order_rule(original)


@PROPERTY
@given(SEEDS)
def test_mask_channel_is_the_mask_and_the_heatmap_peaks_at_the_keypoints(seed: int) -> None:
    mask = pool_blob(seed)
    result = heatmap_from_mask(mask)
    heat, channel = result.heatmap[:, :, 0], result.heatmap[:, :, 1]
    assert result.heatmap.shape == (SIZE, SIZE, 2) and result.heatmap.dtype == np.float32
    assert np.array_equal(channel, mask.astype(np.float32))
    assert heat.min() >= 0 and heat.max() > 0.5
    for x, y in result.keypoints:
        x0, y0 = round(x) - 8, round(y) - 8
        window = heat[y0 : y0 + 17, x0 : x0 + 17]
        py, px = np.unravel_index(int(np.argmax(window)), window.shape)
        assert np.hypot(x0 + px - x, y0 + py - y) <= 1.0


def test_a_smooth_ellipse_still_gives_k_distinct_keypoints() -> None:
    for k in (2, 4, 6):
        result = heatmap_from_mask(ellipse_mask(), HeatmapParams(k=k))
        assert len(result.keypoints) == k
        assert len({tuple(p) for p in result.keypoints.round(1)}) == k
    four = heatmap_from_mask(ellipse_mask()).keypoints
    # One per quadrant (back-top, front-top, front-bottom, back-bottom), mirror-symmetric.
    signs = np.sign(four - 128).tolist()
    assert signs == [[-1, -1], [1, -1], [1, 1], [-1, 1]]
    assert np.allclose(np.abs(four - 128), np.abs(four[0] - 128), atol=1.0)


def test_square_corners() -> None:
    result = heatmap_from_mask(polygon_mask(SQUARE))
    assert result.rules == ("curvature",) * 4
    # Blurring rounds a corner, so the outline passes about 2 px inside it.
    assert _set_distance(result.keypoints, SQUARE) <= 4.0
    assert np.allclose(result.keypoints[0], SQUARE[0], atol=4)  # order: from the top-left


def test_triangle_base_corners_and_an_apex_shared_by_two_keypoints() -> None:
    """The base corners lie on anchors' diagonals; the apex, straight up, lies between the
    back-top and front-top anchors and pulls both towards it alike (mirror symmetry); kept
    apart by the separation, neither sits on a bend, so both count as completed."""
    result = heatmap_from_mask(polygon_mask(TRIANGLE))
    assert result.rules == ("completion", "completion", "curvature", "curvature")
    assert _set_distance(result.keypoints[[3, 2]], TRIANGLE[[2, 1]]) <= 10.0  # a 60° corner rounds
    back, front = result.keypoints[0], result.keypoints[1]
    assert abs(back[0] + front[0] - 2 * TRIANGLE[0, 0]) <= 1.0 and abs(back[1] - front[1]) <= 1.0
    assert back[1] < 100  # pulled up the sides, well above the anchors (y ≈ 120)


def test_teardrop_tip_is_straddled_by_the_two_front_keypoints() -> None:
    result = heatmap_from_mask(teardrop_mask())
    top, bottom = result.keypoints[1], result.keypoints[2]
    assert result.rules[1] == result.rules[2] == "curvature"
    assert result.rules[0] == result.rules[3] == "completion"  # the round end has no corner
    assert abs(top[1] + bottom[1] - 2 * TEARDROP_TIP[1]) <= 1.0  # symmetric about the tip
    tip = np.linalg.norm(result.keypoints[1:3] - TEARDROP_TIP, axis=1)
    assert tip.max() <= 30.0  # the separation (0.1 of the outline) apart, around the tip


def test_crowded_bends_pull_the_front_keypoints_into_the_notch() -> None:
    """A narrow notch (the filler wire) has four sharp corners within a few pixels; it lies
    straight ahead, between the front-top and front-bottom anchors, and pulls both in."""
    canvas = ellipse_mask((100, 60)).copy()
    canvas[122:134, 200:240] = False
    plain = heatmap_from_mask(ellipse_mask((100, 60)))
    result = heatmap_from_mask(canvas)
    assert result.rules == ("completion", "curvature", "curvature", "completion")
    for notch in result.keypoints[1:3]:
        assert 195 <= notch[0] <= 240 and 110 <= notch[1] <= 146
    assert np.abs(plain.keypoints[1:3] - result.keypoints[1:3]).max() > 15  # they moved there
    assert np.abs(plain.keypoints[[0, 3]] - result.keypoints[[0, 3]]).max() <= 8.0  # centroid


@PROPERTY
@given(SEEDS)
def test_a_small_change_of_the_outline_moves_keypoints_a_little_and_keeps_their_numbers(
    seed: int,
) -> None:
    """Keypoints are a continuous function of the outline: nudging it by ~2 px moves each
    keypoint (matched by its number, not re-paired) by a few pixels, never to another part."""
    mask = pool_blob(seed)
    before = heatmap_from_mask(mask).keypoints
    after = heatmap_from_mask(nudge_outline(mask, seed, 2.0)).keypoints
    assert np.linalg.norm(after - before, axis=1).max() <= 12.0


def test_deterministic_and_indifferent_to_the_mask_dtype() -> None:
    mask = pool_blob(7)
    first = heatmap_from_mask(mask)
    for same in (mask, mask.astype(np.uint8) * 255, mask.astype(np.float32)):
        again = heatmap_from_mask(same)
        assert np.array_equal(again.keypoints, first.keypoints)
        assert np.array_equal(again.heatmap, first.heatmap)
        assert again.rules == first.rules


def test_several_blobs_mark_the_largest() -> None:
    mask = np.zeros((SIZE, SIZE), bool)
    mask[20:60, 20:60] = True
    mask[100:220, 80:230] = True
    result = heatmap_from_mask(mask)
    assert np.all((result.keypoints >= [78, 98]) & (result.keypoints <= [231, 221]))
    assert np.array_equal(result.heatmap[:, :, 1], mask.astype(np.float32))


def test_holes_are_ignored() -> None:
    filled = polygon_mask(SQUARE)
    holed = filled.copy()
    holed[110:130, 110:150] = False
    assert np.array_equal(heatmap_from_mask(holed).keypoints, heatmap_from_mask(filled).keypoints)


def test_a_pool_cut_by_the_image_border() -> None:
    mask = np.zeros((120, 160), bool)
    mask[:, :70] = True  # the frame cuts the pool on the left, top and bottom
    result = heatmap_from_mask(mask)
    assert len(result.keypoints) == 4
    assert np.all((result.keypoints >= 0) & (result.keypoints <= [159, 119]))
    full = heatmap_from_mask(np.ones((50, 60), bool))
    assert (
        _set_distance(
            full.keypoints, np.array([[1.5, 1.5], [57.5, 1.5], [57.5, 47.5], [1.5, 47.5]])
        )
        <= 1.0
    )


@pytest.mark.parametrize(
    ("mask", "message"),
    [
        (np.zeros((64, 64), bool), "empty"),
        (np.pad(np.ones((3, 3), bool), 20), "too small or too thin"),
        (np.pad(np.ones((40, 1), bool), 20), "too small or too thin"),
        (np.zeros((8, 8, 3), np.uint8), "2-D"),
        (np.zeros((0, 5), bool), "2-D"),
        (np.array([["a"]]), "booleans or numbers"),
    ],
)
def test_degenerate_masks_are_clear_errors(mask: NDArray[np.generic], message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        heatmap_from_mask(mask)


def test_small_but_real_regions_still_get_keypoints() -> None:
    result = heatmap_from_mask(np.pad(np.ones((12, 12), bool), 20))
    assert len(result.keypoints) == 4


@pytest.mark.parametrize(
    "bad",
    [
        {"k": 0},
        {"blur_size": 4},
        {"min_separation": 0.3},
        {"k": 8, "min_separation": 0.1},
        {"covariance_floor": 0},
        {"turn_step": 0.5},
        {"window_sigmas": -1},
    ],
)
def test_bad_parameters_are_clear_errors(bad: dict[str, float]) -> None:
    with pytest.raises(InvalidInputError, match="Bad heatmap parameters"):
        HeatmapParams(**bad)  # type: ignore[arg-type]


def test_default_separation_scales_with_k() -> None:
    assert HeatmapParams().separation == pytest.approx(0.1)
    assert len(heatmap_from_mask(pool_blob(3), HeatmapParams(k=8)).keypoints) == 8


REAL_LABELS = (
    Path(
        os.environ.get("WELDPOOL_SHARED_DATA")
        or Path(__file__).resolve().parents[2].parent / "shared" / "data"
    )
    / "waam"
    / "labels"
)


def test_on_real_pools_keypoints_mark_the_same_corners_in_every_frame_of_a_clip() -> None:
    """The 9 hand-drawn WAAM pool masks (three frames of three clips; the pool barely moves
    within a clip): keypoint j is the same corner in each frame of a clip, and a 4 px nudge
    of the outline moves no keypoint far (the paper's K-means moved them 130 px on average)."""
    if not REAL_LABELS.is_dir():
        pytest.skip(f"no real labels at {REAL_LABELS} (set WELDPOOL_SHARED_DATA)")
    clips: dict[str, list[NDArray[np.float64]]] = {}
    nudges = []
    for path in sorted(REAL_LABELS.glob("*.png")):
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
        keypoints = heatmap_from_mask(mask).keypoints
        clips.setdefault(path.stem.rsplit("_", 1)[0], []).append(keypoints)
        nudged = heatmap_from_mask(nudge_outline(mask, 0, 4.0)).keypoints
        nudges.append(np.linalg.norm(nudged - keypoints, axis=1))
    assert len(clips) == 3
    moves = [
        np.linalg.norm(a - b, axis=1) for frames in clips.values() for a in frames for b in frames
    ]
    print(
        f"within a clip: mean {np.mean(moves):.1f} px, largest {np.max(moves):.1f} px; "
        f"nudged: mean {np.mean(nudges):.1f}, largest {np.max(nudges):.1f}"
    )
    assert np.mean(moves) <= 15.0 and np.mean(nudges) <= 10.0 and np.max(nudges) <= 30.0


def test_keypoints_from_mask_are_the_heatmaps_keypoints() -> None:
    """The keypoint-only path (what a saved label stores) and the full Algorithm 1 agree."""
    from weldpool_core.heatmap import heatmap_from_mask, keypoints_from_mask
    from weldpool_core.synth import SynthParams, synth_frame

    for seed in range(6):
        mask = synth_frame(seed=seed, params=SynthParams(320, 200)).mask
        assert np.array_equal(keypoints_from_mask(mask), heatmap_from_mask(mask).keypoints)
