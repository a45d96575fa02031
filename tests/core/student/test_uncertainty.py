"""The student's uncertainty: the mask's doubtful mass over its area, novelty beyond the
training frames, and what they add up to on frames the student gets wrong or never saw."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from numpy.typing import NDArray
from scipy.stats import spearmanr

from tests.core.student.common import synthetic_frames
from weldpool_core.metrics import iou
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.predict import (
    FAMILIAR_DISTANCE,
    StudentPredictor,
    TrainingCodes,
    combine,
    mask_ambiguity,
)
from weldpool_core.student.train import TrainResult


def _disc(radius: float, edge: float, size: int = 64) -> NDArray[np.float32]:
    """An S×S disc's mask probability whose edge ramps from 1 to 0 over ``edge`` pixels."""
    axis = np.arange(size, dtype=np.float32) - size / 2
    r = np.hypot(axis[None, :], axis[:, None])
    if edge == 0:
        return (r <= radius).astype(np.float32)
    return np.clip(0.5 - (r - radius) / edge, 0, 1).astype(np.float32)


def test_ambiguity_is_the_doubtful_mass_over_the_pool_area() -> None:
    """0 for a sure mask, growing with the width of its doubtful edge, higher for the same
    edge on a smaller pool, every doubtful pixel weighed by its doubt, and 0 for a confident
    empty frame."""
    sharp, soft, softer = (mask_ambiguity(_disc(20, e)) for e in (0, 4, 10))
    assert sharp == 0.0 and 0 < soft < softer < 1
    assert mask_ambiguity(_disc(10, 4)) > 1.5 * soft  # the same band, half the radius
    # every pixel weighed by its doubt (a count of pixels within 0.25–0.75 would see none here)
    nearly = np.where(_disc(20, 0) > 0, 0.9, 0.1).astype(np.float32)
    assert mask_ambiguity(nearly) == pytest.approx(0.2 * 4096 / float((nearly >= 0.5).sum()))
    assert mask_ambiguity(np.zeros((64, 64), np.float32)) == 0.0
    assert mask_ambiguity(np.full((64, 64), 0.45, np.float32)) == 1.0  # capped


def test_novelty_grows_with_the_distance_to_the_nearest_training_frame() -> None:
    rng = np.random.default_rng(0)
    codes = torch.from_numpy(rng.normal(size=(6, 32))).float()
    known = TrainingCodes.from_codes(codes)
    direction = torch.from_numpy(rng.normal(size=32)).float()
    steps = [0.0, 0.1, 0.5, 2.0, 10.0, 40.0, 100.0]
    moved = torch.stack([codes[2] + step * direction for step in steps])
    distances = known.distance(moved)
    assert distances[0] == pytest.approx(0.0, abs=1e-6)
    assert all(a < b for a, b in itertools.pairwise(distances))
    scores = known.novelty(moved)
    familiar = [s for s, r in zip(scores, distances, strict=True) if r <= FAMILIAR_DISTANCE]
    beyond = [s for s, r in zip(scores, distances, strict=True) if r > FAMILIAR_DISTANCE]
    assert familiar == [0.0] * len(familiar) and len(familiar) >= 3 and len(beyond) >= 2
    assert all(a < b for a, b in itertools.pairwise(beyond)) and beyond[-1] > 0.8
    assert all(0 <= s < 1 for s in scores)
    for score, r in zip(beyond, distances[-len(beyond) :], strict=True):
        excess = r - FAMILIAR_DISTANCE
        assert score == pytest.approx(excess / (1 + excess))
    single = TrainingCodes.from_codes(codes[:1])  # one training frame still has a scale
    near, far = single.distance(torch.stack([codes[0] * 1.01, codes[0] * 3]))
    assert near < far


def test_either_part_raises_the_uncertainty() -> None:
    assert combine(0.0, None) == 0.0 and combine(0.0, 0.0) == 0.0
    assert combine(0.2, 0.5) == pytest.approx(0.6)
    assert combine(0.3, 0.1) > combine(0.2, 0.1) and combine(0.2, 0.4) > combine(0.2, 0.1)
    assert combine(1.0, 0.0) == 1.0 and combine(0.0, 1.0) == 1.0


def test_frames_unlike_the_training_ones_score_above_like_ones(sure_student: TrainResult) -> None:
    """Noise, a blank frame and an inverted one against held-out synthetic frames like the
    training ones; a constant score fails here."""
    assert (sure_student.model_dir / "frame_codes.safetensors").is_file()
    predictor = StudentPredictor.load(sure_student.model_dir, "cpu")
    like = [f.image for f in synthetic_frames(4, first_seed=20)]
    rng = np.random.default_rng(0)
    unlike = [
        rng.integers(0, 256, like[0].shape, dtype=np.uint8),
        np.zeros_like(like[0]),
        255 - like[0],
    ]
    scores = [p.uncertainty for p in predictor.predict(like + unlike, samples=4)]
    assert all(s is not None and 0 <= s <= 1 for s in scores)
    assert min(scores[4:]) > max(scores[:4]), scores  # type: ignore[type-var]


def _hide_front(frame: TrainingFrame) -> NDArray[np.uint8]:
    """The frame with the front 60 % of its pool under a flat grey between the pool's and the
    plate's, so that the pool's front edge cannot be seen (as under glare or a dark front)."""
    image = frame.image.copy()
    rows, columns = np.nonzero(frame.mask)
    front = int(np.percentile(columns, 40))
    image[max(rows.min() - 4, 0) : rows.max() + 5, front:] = 45
    return image


def test_the_uncertainty_rises_on_frames_the_student_gets_wrong(sure_student: TrainResult) -> None:
    """A known hard region: the same held-out frames with the pool's front hidden. The student
    really gets them wrong (lower IoU, checked), and every hidden frame scores above its clean
    self; over both sets the score ranks the error. Constant, dropped or inverted, it fails."""
    predictor = StudentPredictor.load(sure_student.model_dir, "cpu")
    clean = synthetic_frames(6, first_seed=40)
    hidden = [_hide_front(f) for f in clean]
    plain = predictor.predict([f.image for f in clean], samples=4)
    hard = predictor.predict(hidden, samples=4)
    clean_iou = [iou(p.mask, f.mask) for p, f in zip(plain, clean, strict=True)]
    hard_iou = [iou(p.mask, f.mask) for p, f in zip(hard, clean, strict=True)]
    assert all(h < c - 0.02 for h, c in zip(hard_iou, clean_iou, strict=True))  # construction
    assert min(clean_iou) > 0.85
    for easy, difficult in zip(plain, hard, strict=True):
        assert difficult.uncertainty > easy.uncertainty  # type: ignore[operator]
        assert difficult.uncertainty_parts["novelty"] == 0.0  # type: ignore[index]
    scores = [p.uncertainty for p in plain + hard]
    errors = [1 - v for v in clean_iou + hard_iou]
    assert spearmanr(scores, errors)[0] >= 0.5
