"""Held-out evaluation of the student: train on some labelled frames, score the others.

The scores are the ones the paper and the service use: IoU of the predicted mask against the
true mask, and the distance from each of Algorithm 1's keypoints on the true mask
(``heatmap.keypoints_from_mask``) to its Hungarian-matched predicted keypoint (mED, pixels).
Each held-out frame also gets the predictor's ``uncertainty``, so that a benchmark can check
whether it ranks the student's errors (Spearman ρ against 1 − IoU).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, keypoints_from_mask
from weldpool_core.io import load_rgb8, read_mask
from weldpool_core.metrics import iou, match_keypoints
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import StudentPrediction, StudentPredictor
from weldpool_core.student.train import TrainConfig, TrainResult, train_student


def labelled_frames(frames_dir: str | Path, labels_dir: str | Path) -> list[TrainingFrame]:
    """Every ``labels_dir/<stem>.png`` mask with its ``frames_dir/<stem>.png`` frame, by stem."""
    labels = sorted(Path(labels_dir).glob("*.png"))
    if not labels:
        raise InvalidInputError(f"{labels_dir} holds no mask files.")
    frames = []
    for path in labels:
        image = load_rgb8(Path(frames_dir) / path.name)
        frames.append(TrainingFrame(image, read_mask(path), None, path.stem))
    return frames


@dataclass(frozen=True)
class HeldOutScores:
    """Scores of a student on held-out frames.

    Attributes:
        names: the frames' names.
        ious: IoU per frame.
        distances: per frame, each true keypoint's distance to its match (NaN: missed).
        uncertainties: the predictor's uncertainty per frame (None without samples).
        parts: its parts per frame (``StudentPrediction.uncertainty_parts``).
        mask_distances: like ``distances``, for Algorithm 1's keypoints on the *predicted*
            mask instead of the heatmap's (all NaN where that mask has none): which of the
            student's two outputs places the corners better.
    """

    names: list[str]
    ious: list[float]
    distances: list[list[float]]
    uncertainties: list[float | None]
    parts: list[dict[str, float | None] | None] = field(default_factory=list)
    mask_distances: list[list[float]] = field(default_factory=list)

    @property
    def miou(self) -> float:
        """Mean IoU over the frames."""
        return float(np.mean(self.ious))

    @property
    def med(self) -> float | None:
        """Mean distance over all matched keypoints (None when none matched)."""
        found = [d for frame in self.distances for d in frame if not np.isnan(d)]
        return float(np.mean(found)) if found else None

    @property
    def mask_med(self) -> float | None:
        """``med`` of ``mask_distances``."""
        found = [d for frame in self.mask_distances for d in frame if not np.isnan(d)]
        return float(np.mean(found)) if found else None

    @property
    def missed(self) -> int:
        """True keypoints without a predicted partner."""
        return sum(int(np.isnan(d)) for frame in self.distances for d in frame)


def score_predictions(
    predictions: Sequence[StudentPrediction], frames: Sequence[TrainingFrame], k: int = 4
) -> HeldOutScores:
    """IoU and keypoint distances of predictions against frames' true masks (Algorithm 1's
    keypoints, or the frames' own keypoints when given)."""
    ious, distances, mask_distances = [], [], []
    for prediction, frame in zip(predictions, frames, strict=True):
        ious.append(iou(prediction.mask, frame.mask))
        truth = frame.keypoints
        if truth is None:
            truth = keypoints_from_mask(frame.mask, HeatmapParams(k=k))
        distances.append([float(d) for d in match_keypoints(prediction.keypoints, truth)])
        try:
            own = keypoints_from_mask(prediction.mask, HeatmapParams(k=k))
        except InvalidInputError:  # an empty or tiny predicted mask
            own = np.zeros((0, 2))
        mask_distances.append([float(d) for d in match_keypoints(own, truth)])
    return HeldOutScores(
        [f.name for f in frames],
        ious,
        distances,
        [p.uncertainty for p in predictions],
        [p.uncertainty_parts for p in predictions],
        mask_distances,
    )


@dataclass(frozen=True)
class FoldResult:
    """One train-then-test split: what trained, how long, and the held-out scores."""

    train: list[str]
    scores: HeldOutScores
    seconds: float
    result: TrainResult
    predictions: list[StudentPrediction] = field(default_factory=list, repr=False)
    """The held-out frames' predictions, in the order of ``scores.names``."""


def train_and_score(
    train: Sequence[TrainingFrame],
    test: Sequence[TrainingFrame],
    folder: str | Path,
    student: StudentConfig | None = None,
    config: TrainConfig | None = None,
    samples: int = 8,
) -> FoldResult:
    """Train a student on all of ``train`` into ``folder`` (the best round chosen on the
    training frames themselves, unaugmented: no frame of a small fold is given up for
    validation); score ``test``."""
    started = time.perf_counter()
    result = train_student(list(train), folder, student, config, validation=list(train))
    seconds = time.perf_counter() - started
    predictor = StudentPredictor.load(folder, "cpu")
    predictions = predictor.predict([f.image for f in test], samples=samples)
    k = predictor.config.k
    scores = score_predictions(predictions, test, k)
    return FoldResult([f.name for f in train], scores, seconds, result, predictions)
