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
from weldpool_core.student import predict as predict_module
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.predict import (
    FAMILIAR_DISTANCE,
    StudentPredictor,
    TrainingCodes,
    combine,
    frame_codes,
    frames_to_batch,
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


TINY_FAMILIAR = 1.5
"""The familiar distance for the tiny test student. ``FAMILIAR_DISTANCE`` is measured for the
default student on real frames (``bench/uncertainty.py``); the tiny student's 64² features are
weaker, and its frames lie closer: frames like its training ones at under 1, noise, blank,
inverted and low-contrast frames at 2 to 4 (over seeds and thread counts)."""


def _distances(predictor: StudentPredictor, images: list[NDArray[np.uint8]]) -> list[float]:
    batch, _ = frames_to_batch(images, predictor.config)
    with torch.inference_mode():
        codes = frame_codes(predictor.model.features(batch))
    assert predictor.training_codes is not None
    return predictor.training_codes.distance(codes)


def test_frames_unlike_the_training_ones_score_above_like_ones(
    sure_student: TrainResult, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Noise, a blank frame and an inverted one against held-out synthetic frames like the
    training ones: twice as far from the training frames as the farthest like one, and, with
    the familiar distance between the two, above every like frame in uncertainty. A constant
    score or a dropped novelty fails here."""
    assert (sure_student.model_dir / "frame_codes.safetensors").is_file()
    predictor = StudentPredictor.load(sure_student.model_dir, "cpu")
    like = [f.image for f in synthetic_frames(4, first_seed=20)]
    rng = np.random.default_rng(0)
    unlike = [
        rng.integers(0, 256, like[0].shape, dtype=np.uint8),
        np.zeros_like(like[0]),
        255 - like[0],
    ]
    near, far = _distances(predictor, like), _distances(predictor, unlike)
    assert max(near) < TINY_FAMILIAR < min(far) and min(far) > 2 * max(near), (near, far)
    monkeypatch.setattr(predict_module, "FAMILIAR_DISTANCE", TINY_FAMILIAR)
    found = predictor.predict(like + unlike, samples=4)
    scores = [p.uncertainty for p in found]
    assert all(s is not None and 0 <= s <= 1 for s in scores)
    assert min(scores[4:]) > max(scores[:4]), scores  # type: ignore[type-var]
    assert [p.uncertainty_parts["novelty"] for p in found[:4]] == [0.0] * 4  # type: ignore[index]


def _dim(frame: TrainingFrame, contrast: float = 0.1) -> NDArray[np.uint8]:
    """The frame with its contrast cut to ``contrast`` about its mean (a dim exposure, smoke
    over the pool): the pool's edge is hard to see."""
    image = frame.image.astype(np.float32)
    centre = image.mean()
    return np.clip(centre + contrast * (image - centre), 0, 255).astype(np.uint8)


def test_the_uncertainty_rises_on_frames_the_student_gets_wrong(
    sure_student: TrainResult, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A known hard region: the same held-out frames dimmed. The student really gets them wrong
    (lower IoU on average, checked), every dimmed frame scores above its clean self, and over
    both sets the score ranks the error. Constant, dropped or inverted, it fails."""
    monkeypatch.setattr(predict_module, "FAMILIAR_DISTANCE", TINY_FAMILIAR)
    predictor = StudentPredictor.load(sure_student.model_dir, "cpu")
    clean = synthetic_frames(6, first_seed=40)
    plain = predictor.predict([f.image for f in clean], samples=4)
    hard = predictor.predict([_dim(f) for f in clean], samples=4)
    clean_iou = [iou(p.mask, f.mask) for p, f in zip(plain, clean, strict=True)]
    hard_iou = [iou(p.mask, f.mask) for p, f in zip(hard, clean, strict=True)]
    assert np.mean(hard_iou) < np.mean(clean_iou) - 0.02 and min(clean_iou) > 0.8  # construction
    for easy, difficult in zip(plain, hard, strict=True):
        assert difficult.uncertainty > easy.uncertainty  # type: ignore[operator]
    scores = [p.uncertainty for p in plain + hard]
    errors = [1 - v for v in clean_iou + hard_iou]
    assert spearmanr(scores, errors)[0] >= 0.3
