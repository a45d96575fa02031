"""IoU / mIoU and keypoint distances against cases worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from weldpool_core.errors import InvalidInputError
from weldpool_core.metrics import iou, keypoint_scores, match_keypoints, segmentation_scores


def test_iou_by_hand() -> None:
    truth = np.zeros((10, 10), bool)
    truth[0:4, 0:4] = True  # 16 pixels
    predicted = np.zeros((10, 10), np.uint8)
    predicted[0:4, 2:6] = 255  # 16 pixels, 8 shared
    assert iou(predicted, truth) == pytest.approx(8 / 24)
    assert iou(truth, truth) == 1.0


def test_iou_of_empty_masks() -> None:
    empty, full = np.zeros((5, 5), bool), np.ones((5, 5), bool)
    assert iou(empty, empty) == 1.0  # both agree there is no pool
    assert iou(empty, full) == 0.0 and iou(full, empty) == 0.0


def test_iou_needs_masks_of_one_size() -> None:
    with pytest.raises(InvalidInputError, match="differ in size"):
        iou(np.zeros((4, 5)), np.zeros((5, 4)))


def test_miou_and_quartiles_by_hand() -> None:
    scores = segmentation_scores({"a": 0.2, "b": 0.4, "c": 0.6, "d": 0.8})
    assert scores.miou == pytest.approx(0.5)
    assert (scores.q1, scores.median, scores.q3) == pytest.approx((0.35, 0.5, 0.65))
    report = scores.as_dict()
    assert report["mIoU"] == pytest.approx(0.5) and report["count"] == 4
    assert report["quartiles"] == pytest.approx({"q1": 0.35, "median": 0.5, "q3": 0.65})
    assert report["per_image"] == {"a": 0.2, "b": 0.4, "c": 0.6, "d": 0.8}
    with pytest.raises(InvalidInputError):
        segmentation_scores({})


def test_hungarian_and_in_order_matching_by_hand() -> None:
    truth = [[0, 0], [10, 0]]
    predicted = [[10, 1], [0, 2]]  # right places, swapped order
    assert match_keypoints(predicted, truth).tolist() == pytest.approx([2.0, 1.0])
    in_order = match_keypoints(predicted, truth, "order")
    assert in_order.tolist() == pytest.approx([math.sqrt(101), math.sqrt(104)])


def test_unmatched_keypoints_are_nan() -> None:
    assert np.isnan(match_keypoints([], [[1, 1], [2, 2]])).all()
    assert match_keypoints([[1, 1], [5, 5], [9, 9]], []).shape == (0,)
    one = match_keypoints([[9, 9]], [[0, 0], [10, 10]])
    assert np.isnan(one[0]) and one[1] == pytest.approx(math.sqrt(2))
    short = match_keypoints([[0, 1]], [[0, 0], [10, 10]], "order")
    assert short[0] == pytest.approx(1.0) and np.isnan(short[1])


def test_med_med_k_and_std_by_hand() -> None:
    truth = [[0, 0], [10, 0]]
    pairs = {
        "a": ([[3, 4], [10, 0]], truth),  # distances 5 and 0
        "b": ([[0, 1]], truth),  # 1, and keypoint 2 missed
        "c": ([[1, 1]], []),  # no ground truth: one extra prediction
    }
    scores = keypoint_scores(pairs)
    assert scores.med == pytest.approx(2.0)  # (5 + 0 + 1) / 3
    assert scores.med_k == pytest.approx([3.0, 0.0])
    assert scores.std == pytest.approx(math.sqrt(14 / 3))  # population std of 5, 0, 1
    assert (scores.matched, scores.missed, scores.extra) == (3, 1, 1)
    report = scores.as_dict()
    assert report["per_image"] == {"a": [5.0, 0.0], "b": [1.0, None], "c": []}
    assert report["mED"] == pytest.approx(2.0) and report["matching"] == "hungarian"


def test_no_match_at_all_gives_no_distances() -> None:
    scores = keypoint_scores({"a": ([], [[1, 2]])})
    assert scores.med is None and scores.std is None and scores.med_k == [None]
    assert scores.missed == 1


def test_bad_keypoint_input_is_a_clear_error() -> None:
    with pytest.raises(InvalidInputError, match="matching"):
        match_keypoints([[0, 0]], [[0, 0]], "nearest")  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match=r"\[x, y\]"):
        match_keypoints([[0, 0, 0]], [[0, 0]])
    with pytest.raises(InvalidInputError, match=r"\[x, y\]"):
        match_keypoints([[float("nan"), 0]], [[0, 0]])
    with pytest.raises(InvalidInputError):
        keypoint_scores({})
