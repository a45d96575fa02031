"""Uncertainty components, the combined score and the diverse queue order."""

from __future__ import annotations

import numpy as np
import pytest

from weldpool_core.active import (
    combined_score,
    disagreement,
    diverse_order,
    main_reason,
    teacher_components,
)


def test_teacher_components() -> None:
    assert teacher_components(0.9, 0.6) == pytest.approx({"teacher_iou": 0.1, "instability": 0.4})
    assert teacher_components(None, None) == {"teacher_iou": None, "instability": None}
    assert teacher_components(1.2, -0.1) == {"teacher_iou": 0.0, "instability": 1.0}


def test_an_unstable_proposal_ranks_above_a_stable_one() -> None:
    stable = combined_score(teacher_components(sam2_iou=0.9, stability=0.98))
    unstable = combined_score(teacher_components(sam2_iou=0.9, stability=0.40))
    assert unstable > stable
    assert main_reason(teacher_components(0.9, 0.40)) == "instability"


def test_combined_score_weights_and_missing_parts() -> None:
    parts = {
        "teacher_iou": 0.2,
        "instability": None,
        "disagreement": 0.8,
        "student_uncertainty": None,
    }
    assert combined_score(parts) == pytest.approx(0.5)
    weights = {"teacher_iou": 3.0, "disagreement": 1.0}
    assert combined_score(parts, weights) == pytest.approx((3 * 0.2 + 0.8) / 4)
    assert combined_score({"teacher_iou": None}) is None
    assert combined_score(parts, {"student_uncertainty": 1.0}) is None


def test_disagreement_between_student_and_teacher() -> None:
    mask = np.zeros((100, 200), bool)
    mask[20:80, 40:160] = True
    points = [[40, 20], [160, 20], [160, 80], [40, 80]]
    assert disagreement(mask, mask, points, points) == 0.0
    shifted = np.roll(mask, 5, axis=1)
    moved = [[x + 5, y] for x, y in points]
    # masks: IoU 115/125, so 0.08; keypoints: 5 px / diagonal × KEYPOINT_SCALE; their mean
    expected = (0.08 + 5 / np.hypot(100, 200) * 10) / 2
    assert disagreement(shifted, mask, moved, points) == pytest.approx(expected, abs=1e-9)
    assert disagreement(mask, mask, moved, points) == pytest.approx(expected - 0.04, abs=1e-9)
    far = [[x + 300, y] for x, y in points]  # the keypoint part saturates at 1
    assert disagreement(mask, mask, far, points) == pytest.approx(0.5)
    assert disagreement(~mask, mask, [], points) == 1.0  # nothing overlaps, no keypoints


def test_diverse_order_breaks_up_near_duplicates() -> None:
    # Five near-identical frames with the highest scores, and two different ones just below.
    rng = np.random.default_rng(0)
    base, other = rng.normal(size=8), rng.normal(size=8)
    descriptors = np.array([base + 0.01 * rng.normal(size=8) for _ in range(5)] + [other, -base])
    scores = np.array([0.95, 0.94, 0.93, 0.92, 0.91, 0.80, 0.79])
    order = diverse_order(scores, descriptors)
    assert order[0] == 0  # the most uncertain frame first
    assert set(order[1:3]) == {5, 6}  # then the different frames, before the duplicates
    assert sorted(order) == list(range(7))
    plain = diverse_order(scores, descriptors, trade_off=0.0)
    assert plain == list(range(7))  # no diversity: pure ranking
