"""How every claim is judged: IoU / mIoU for the teacher, keypoint distances (mED) for the student.

Segmentation: IoU per frame; mIoU is their mean and the quartiles are numpy's linear-interpolated
25th, 50th and 75th percentiles, all as fractions in [0, 1] (the paper prints percentages). A
frame where both masks are empty scores 1 (they agree there is no pool); where exactly one is
empty it scores 0.

Keypoints (the paper's Table II): each ground-truth keypoint is matched to one predicted keypoint,
either by the Hungarian algorithm on Euclidean distance (``"hungarian"``, the default: immune to
a different order rule) or by position in the list (``"order"``: keypoint i against keypoint i).
mED_k is the mean distance of ground-truth keypoint k over the frames, mED the mean of all
matched distances and std their population standard deviation, in pixels. A ground-truth keypoint
without a partner (an empty or shorter prediction) is counted in ``missed`` and has no distance;
a predicted keypoint without one (an empty ground truth) in ``extra``. With no match at all the
distances are None.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

Matching = Literal["hungarian", "order"]
MATCHINGS: tuple[Matching, ...] = ("hungarian", "order")


def iou(predicted: NDArray[Any], truth: NDArray[Any]) -> float:
    """Intersection over union of two masks (nonzero is foreground); 1 when both are empty."""
    pred, true = np.asarray(predicted) != 0, np.asarray(truth) != 0
    if pred.shape != true.shape:
        raise InvalidInputError(
            f"The masks differ in size: prediction {pred.shape[::-1]}, ground truth "
            f"{true.shape[::-1]} (width, height)."
        )
    union = int(np.count_nonzero(pred | true))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(pred & true)) / union


@dataclass(frozen=True)
class SegmentationScores:
    """mIoU, quartiles and per-frame IoU of a set of frames (fractions in [0, 1])."""

    miou: float
    q1: float
    median: float
    q3: float
    per_image: dict[str, float]

    def as_dict(self) -> dict[str, Any]:
        """The JSON shape of ``weldpool eval segmentation``."""
        return {
            "mIoU": self.miou,
            "quartiles": {"q1": self.q1, "median": self.median, "q3": self.q3},
            "count": len(self.per_image),
            "per_image": self.per_image,
        }


def segmentation_scores(per_image: Mapping[str, float]) -> SegmentationScores:
    """Summarise per-frame IoU values (frame name → IoU) as mIoU and quartiles."""
    if not per_image:
        raise InvalidInputError("There are no frames to score.")
    values = np.array(list(per_image.values()), np.float64)
    q1, median, q3 = (float(q) for q in np.percentile(values, [25, 50, 75]))
    return SegmentationScores(float(values.mean()), q1, median, q3, dict(per_image))


def _points(points: NDArray[Any] | list[Any], what: str) -> NDArray[np.float64]:
    array = np.asarray(points, np.float64)
    if array.size == 0:
        return np.zeros((0, 2), np.float64)
    if array.ndim != 2 or array.shape[1] != 2 or not np.isfinite(array).all():
        raise InvalidInputError(f"The {what} keypoints must be a list of finite [x, y] pairs.")
    return array


def match_keypoints(
    predicted: NDArray[Any] | list[Any],
    truth: NDArray[Any] | list[Any],
    matching: Matching = "hungarian",
) -> NDArray[np.float64]:
    """Distance from each ground-truth keypoint to its matched prediction; NaN where unmatched."""
    if matching not in MATCHINGS:
        raise InvalidInputError(
            f"Unknown matching {matching!r}; use one of {', '.join(MATCHINGS)}."
        )
    pred, true = _points(predicted, "predicted"), _points(truth, "ground-truth")
    distances = np.full(len(true), np.nan)
    if len(pred) == 0 or len(true) == 0:
        return distances
    cost = np.linalg.norm(true[:, None, :] - pred[None, :, :], axis=2)
    if matching == "hungarian":
        from scipy.optimize import linear_sum_assignment  # scipy loads only where it is used

        rows, cols = linear_sum_assignment(cost)
    else:
        rows = cols = np.arange(min(len(true), len(pred)))
    distances[rows] = cost[rows, cols]
    return distances


@dataclass(frozen=True)
class KeypointScores:
    """mED, mED_k and std over a set of frames (pixels), and what could not be matched."""

    med: float | None
    med_k: list[float | None]
    std: float | None
    per_image: dict[str, list[float | None]]
    matched: int
    missed: int
    extra: int
    matching: Matching

    def as_dict(self) -> dict[str, Any]:
        """The JSON shape of ``weldpool eval keypoints``."""
        return {
            "mED": self.med,
            "mED_k": self.med_k,
            "std": self.std,
            "matching": self.matching,
            "count": len(self.per_image),
            "matched": self.matched,
            "missed": self.missed,
            "extra": self.extra,
            "per_image": self.per_image,
        }


def keypoint_scores(
    pairs: Mapping[str, tuple[NDArray[Any] | list[Any], NDArray[Any] | list[Any]]],
    matching: Matching = "hungarian",
) -> KeypointScores:
    """Score frames given as name → (predicted keypoints, ground-truth keypoints)."""
    if not pairs:
        raise InvalidInputError("There are no frames to score.")
    per_image: dict[str, list[float | None]] = {}
    by_index: dict[int, list[float]] = {}
    missed = extra = 0
    for name, (predicted, truth) in pairs.items():
        distances = match_keypoints(predicted, truth, matching)
        found = ~np.isnan(distances)
        missed += int((~found).sum())
        extra += len(_points(predicted, "predicted")) - int(found.sum())
        per_image[name] = [float(d) if ok else None for d, ok in zip(distances, found, strict=True)]
        for index in np.flatnonzero(found):
            by_index.setdefault(int(index), []).append(float(distances[index]))
    every = [d for values in by_index.values() for d in values]
    size = max((len(v) for v in per_image.values()), default=0)
    med_k = [float(np.mean(by_index[i])) if i in by_index else None for i in range(size)]
    return KeypointScores(
        med=float(np.mean(every)) if every else None,
        med_k=med_k,
        std=float(np.std(every)) if every else None,
        per_image=per_image,
        matched=len(every),
        missed=missed,
        extra=extra,
        matching=matching,
    )


IOU_FLOOR = 0.5
"""Below this IoU a frame's keypoints do not count as found: a model that draws the wrong pool is
not rescued by a lucky keypoint (``proposal_quality``)."""


def proposal_quality(
    frames: Mapping[str, tuple[NDArray[Any], Any, NDArray[Any], Any]],
    iou_floor: float = IOU_FLOOR,
) -> dict[str, Any]:
    """How good a source's masks and keypoints are on reviewed frames: the one rule that
    training's epoch choice and the promotion gate both use.

    ``frames`` maps a name to ``(predicted mask, predicted keypoints, true mask, true
    keypoints)``. Returns ``mIoU``, ``mED`` / ``mED_k`` / ``std`` / ``missed`` (matched
    keypoints only, as ``keypoint_scores``), ``mED_penalised`` (every true keypoint counts; one
    without a partner, or on a frame whose IoU is below ``iou_floor``, counts as the frame's
    diagonal; None when no frame has true keypoints), ``per_image`` IoU and ``frames``.
    """
    if not frames:
        raise InvalidInputError("There are no frames to score.")
    per_image: dict[str, float] = {}
    pairs: dict[str, tuple[Any, Any]] = {}
    penalised: list[float] = []
    for name, (predicted, points, truth, true_points) in frames.items():
        per_image[name] = iou(predicted, truth)
        pairs[name] = (points, true_points)
        diagonal = float(np.hypot(*np.asarray(truth).shape))
        distances = match_keypoints(points, true_points)
        if per_image[name] < iou_floor:
            distances = np.full(len(distances), np.nan)
        penalised.extend(np.where(np.isnan(distances), diagonal, distances).tolist())
    keypoints = keypoint_scores(pairs)
    return {
        "mIoU": float(np.mean(list(per_image.values()))),
        "mED": keypoints.med,
        "mED_k": keypoints.med_k,
        "std": keypoints.std,
        "missed": keypoints.missed,
        "mED_penalised": float(np.mean(penalised)) if penalised else None,
        "per_image": per_image,
        "frames": len(frames),
    }
