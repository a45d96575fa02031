"""Active learning: how unsure the models are about a frame, and a diverse review queue.

Uncertainty components, each in [0, 1] (1 = most unsure), None when it cannot be measured:

- ``teacher_iou``: 1 − SAM2's predicted IoU of the teacher's mask.
- ``instability``: 1 − the teacher's prompt stability (mean IoU of the mask with the masks of
  slightly jittered prompts).
- ``disagreement``: how far the promoted student is from the teacher: the mean of
  1 − IoU(student mask, teacher mask) and the mean distance between matched keypoints divided
  by the frame diagonal × ``KEYPOINT_SCALE`` (capped at 1).
- ``propagation_doubt``: 1 − the confidence of the frame's propagated mask (SAM2's video
  model: object probability × predicted IoU), where the frame has one: a mask carried from a
  reviewed frame that SAM2 itself doubts is a frame to look at.
- ``student_uncertainty``: the promoted student's uncertainty (``StudentPrediction.uncertainty``):
  how much of its predicted pool it is unsure of (the mask probability in doubt over the pool's
  area), combined with how far beyond its training frames the frame lies to its encoder
  (``student.predict``).

The combined score is the weighted mean of the components that are present (weights from the
settings); a frame with none has no score and goes to the end of the queue.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from weldpool_core.defaults import DEFAULT_WEIGHTS
from weldpool_core.metrics import iou, match_keypoints

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

COMPONENTS = (
    "teacher_iou",
    "instability",
    "disagreement",
    "student_uncertainty",
    "propagation_doubt",
)
KEYPOINT_SCALE = 10.0  # a mean error of a tenth of the diagonal counts as full disagreement


def _clip(value: float) -> float:
    return float(min(1.0, max(0.0, value)))


def teacher_components(sam2_iou: float | None, stability: float | None) -> dict[str, float | None]:
    """The teacher's own uncertainty components."""
    return {
        "teacher_iou": None if sam2_iou is None else _clip(1.0 - sam2_iou),
        "instability": None if stability is None else _clip(1.0 - stability),
    }


def propagation_components(confidence: float | None) -> dict[str, float | None]:
    """A propagated mask's uncertainty component."""
    return {"propagation_doubt": None if confidence is None else _clip(1.0 - confidence)}


def disagreement(
    student_mask: NDArray[np.bool_],
    teacher_mask: NDArray[np.bool_],
    student_keypoints: Any,
    teacher_keypoints: Any,
) -> float:
    """Student–teacher disagreement in [0, 1] (see the module doc)."""
    mask_part = 1.0 - iou(student_mask, teacher_mask)
    height, width = teacher_mask.shape
    diagonal = float(np.hypot(height, width))
    distances = match_keypoints(student_keypoints, teacher_keypoints)
    matched = distances[~np.isnan(distances)]
    if len(distances) == 0:  # the teacher has no keypoints: the masks alone
        return _clip(mask_part)
    key_part = _clip(float(matched.mean()) / diagonal * KEYPOINT_SCALE) if len(matched) else 1.0
    return _clip((mask_part + key_part) / 2)


def combined_score(
    components: Mapping[str, float | None], weights: Mapping[str, float] | None = None
) -> float | None:
    """The weighted mean of the present components; None when none is present."""
    weights = weights or DEFAULT_WEIGHTS
    present = [
        (weights.get(name, 0.0), value)
        for name, value in components.items()
        if value is not None and weights.get(name, 0.0) > 0
    ]
    total = sum(weight for weight, _ in present)
    if not present or total <= 0:
        return None
    return float(sum(weight * value for weight, value in present) / total)


def main_reason(
    components: Mapping[str, float | None], weights: Mapping[str, float] | None = None
) -> str | None:
    """The component that adds most to the combined score (shown to the reviewer)."""
    weights = weights or DEFAULT_WEIGHTS
    scored = [(weights.get(n, 0.0) * v, n) for n, v in components.items() if v is not None]
    return max(scored)[1] if scored else None


def diverse_order(
    scores: NDArray[np.float64], descriptors: NDArray[np.float64], trade_off: float = 0.5
) -> list[int]:
    """Reorder candidates (already the top of the ranking) so that near-identical frames do
    not follow each other: a greedy k-center pick that takes, at each step, the candidate
    maximising ``(1 − trade_off) · score + trade_off · distance to the frames already picked``
    (both scaled to [0, 1]; cosine distance between DINO CLS descriptors). The most uncertain
    frame always comes first.
    """
    count = len(scores)
    if count <= 2:
        return list(np.argsort(-scores, kind="stable"))
    vectors = descriptors / np.maximum(np.linalg.norm(descriptors, axis=1, keepdims=True), 1e-12)
    distances = 1.0 - vectors @ vectors.T  # every pair at once: one product, not one per pick
    span = float(scores.max() - scores.min()) or 1.0
    weighted = (1 - trade_off) * (scores - scores.min()) / span
    order = [int(np.argmax(scores))]
    nearest = distances[order[0]].copy()  # distance to the closest picked frame (0 if picked)
    picked = np.zeros(count)  # -inf once picked
    picked[order[0]] = -np.inf
    for _ in range(count - 1):
        value = weighted + nearest * (trade_off / max(float(nearest.max()), 1e-12)) + picked
        pick = int(np.argmax(value))
        order.append(pick)
        picked[pick] = -np.inf
        np.minimum(nearest, distances[pick], out=nearest)
    return order
