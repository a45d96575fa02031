"""The student's uncertainty: test-time passes mapped back, novelty against the training
frames, and what they add up to on frames unlike the training ones."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from tests.core.student.common import synthetic_frames
from weldpool_core.student.predict import (
    StudentPredictor,
    TrainingCodes,
    _inverse,
    _warp,
    combine,
    tta_thetas,
)
from weldpool_core.student.train import TrainResult


def _blob(size: int = 64) -> torch.Tensor:
    axis = torch.arange(size, dtype=torch.float32)
    spot = torch.exp(-((axis[None, :] - 30) ** 2 + (axis[:, None] - 36) ** 2) / (2 * 8.0**2))
    return spot.expand(1, 3, size, size).clone()


def test_a_pass_mapped_back_lands_on_the_frame() -> None:
    image = _blob()
    inner = (slice(None), slice(None), slice(12, 52), slice(12, 52))
    for theta, gamma, gain in tta_thetas(4):
        assert not torch.allclose(theta, torch.tensor([[1.0, 0, 0], [0, 1.0, 0]]))
        assert gamma != 1.0 and gain != 1.0
        moved = _warp(image, theta)
        assert (moved - image)[inner].abs().max() > 0.02  # the pass really moves the frame
        back = _warp(moved, _inverse(theta))
        assert (back - image)[inner].abs().max() < 0.02
        twice = _warp(moved, theta)  # the forward map again is not the way back
        assert (twice - image)[inner].abs().max() > 0.02
    assert all(torch.equal(a[0], b[0]) for a, b in zip(tta_thetas(3), tta_thetas(3), strict=True))


def test_novelty_grows_with_the_distance_to_the_nearest_training_frame() -> None:
    rng = np.random.default_rng(0)
    codes = torch.from_numpy(rng.normal(size=(6, 32))).float()
    known = TrainingCodes.from_codes(codes)
    direction = torch.from_numpy(rng.normal(size=32)).float()
    steps = [0.0, 0.1, 0.5, 2.0, 10.0]
    scores = known.novelty(torch.stack([codes[2] + step * direction for step in steps]))
    assert scores[0] == pytest.approx(0.0, abs=1e-6)
    assert all(a < b for a, b in itertools.pairwise(scores))
    assert scores[-1] > 0.8 and all(0 <= s < 1 for s in scores)
    single = TrainingCodes.from_codes(codes[:1])  # one training frame still has a scale
    near, far = single.novelty(torch.stack([codes[0] * 1.01, codes[0] * 3]))
    assert near < far


def test_either_part_raises_the_uncertainty() -> None:
    assert combine(0.0, None) == 0.0 and combine(0.0, 0.0) == 0.0
    assert combine(0.2, 0.5) == pytest.approx(0.6)
    assert combine(0.3, 0.1) > combine(0.2, 0.1) and combine(0.2, 0.4) > combine(0.2, 0.1)
    assert combine(1.0, 0.0) == 1.0 and combine(0.0, 1.0) == 1.0


def test_frames_unlike_the_training_ones_score_above_like_ones(trained: TrainResult) -> None:
    """Noise, a blank frame and an inverted one against held-out synthetic frames like the
    training ones; a constant score fails here."""
    assert (trained.model_dir / "frame_codes.safetensors").is_file()
    predictor = StudentPredictor.load(trained.model_dir, "cpu")
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
