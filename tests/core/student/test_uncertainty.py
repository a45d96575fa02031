"""The student's uncertainty: how far its posterior moves the mask and the mask's doubtful mass
over its area (their geometric mean), novelty beyond the student's own familiar distance from
its training frames, and what they add up to on frames the student gets wrong or never saw."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from numpy.typing import NDArray
from scipy.stats import spearmanr

from tests.core.student.common import synthetic_frames
from weldpool_core.metrics import iou
from weldpool_core.student.checkpoint import load_codes, save_codes
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.predict import (
    FAMILIAR_DISTANCE,
    FOREIGN_MARGIN,
    StudentPredictor,
    TrainingCodes,
    combine,
    familiar_distance,
    foreign_versions,
    frame_codes,
    frames_to_batch,
    mask_ambiguity,
    mask_doubt,
    mask_spread,
    uncertainty_of,
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


def test_spread_is_one_minus_the_soft_iou_of_the_draws_with_the_plain_mask() -> None:
    """0 when the draws leave the mask as it is, growing as they move its outline, the same
    either way round, weighed against the pool's size, and 0 for two empty frames."""
    plain = _disc(20, 2)
    moved = [mask_spread(np.roll(plain, shift, axis=1), plain) for shift in (0, 2, 6)]
    assert moved[0] == 0.0 and 0 < moved[1] < moved[2] < 1
    assert mask_spread(plain, np.roll(plain, 6, axis=1)) == pytest.approx(moved[2])
    small = _disc(10, 2)
    assert mask_spread(np.roll(small, 2, axis=1), small) > 1.5 * moved[1]
    half = 0.5 * plain  # every pixel's probability halved: the soft IoU is one half
    assert mask_spread(half, plain) == pytest.approx(0.5)
    assert mask_spread(np.zeros((64, 64)), np.zeros((64, 64))) == 0.0


def test_novelty_grows_with_the_distance_beyond_the_students_familiar_distance() -> None:
    rng = np.random.default_rng(0)
    codes = torch.from_numpy(rng.normal(size=(6, 32))).float()
    direction = torch.from_numpy(rng.normal(size=32)).float()
    steps = [0.0, 0.1, 0.5, 2.0, 10.0, 40.0, 100.0]
    moved = torch.stack([codes[2] + step * direction for step in steps])
    for familiar in (1.0, 6.0):
        known = TrainingCodes.from_codes(codes, familiar)
        distances = known.distance(moved)
        assert distances[0] == pytest.approx(0.0, abs=1e-6)
        assert all(a < b for a, b in itertools.pairwise(distances))
        scores = known.novelty(moved)
        inside = [s for s, r in zip(scores, distances, strict=True) if r <= familiar]
        beyond = [s for s, r in zip(scores, distances, strict=True) if r > familiar]
        assert inside == [0.0] * len(inside) and len(inside) >= 3 and len(beyond) >= 2
        assert all(a < b for a, b in itertools.pairwise(beyond)) and beyond[-1] > 0.8
        assert all(0 <= s < 1 for s in scores)
        for score, r in zip(beyond, distances[-len(beyond) :], strict=True):
            assert score == pytest.approx((r - familiar) / (1 + r - familiar))
    assert TrainingCodes.from_codes(codes).familiar == FAMILIAR_DISTANCE  # an older folder
    single = TrainingCodes.from_codes(codes[:1])  # one training frame still has a scale
    near, far = single.distance(torch.stack([codes[0] * 1.01, codes[0] * 3]))
    assert near < far


def test_the_familiar_distance_is_a_margin_short_of_the_nearest_foreign_frame(
    tmp_path,  # type: ignore[no-untyped-def]
) -> None:
    """Measured per student: ``FOREIGN_MARGIN`` of the distance of the nearest foreign frame
    (not the farthest, not the mean), so it scales with how far that student puts them; and
    it is saved with the codes, an older file reading as None."""
    rng = np.random.default_rng(1)
    codes = torch.from_numpy(rng.normal(size=(8, 16))).float()
    known = TrainingCodes.from_codes(codes)
    direction = torch.from_numpy(rng.normal(size=16)).float()
    for spread in (1.0, 3.0):
        foreign = torch.stack([codes[0] + spread * k * direction for k in (5.0, 2.0, 9.0)])
        nearest = min(known.distance(foreign))
        assert familiar_distance(known, foreign) == pytest.approx(FOREIGN_MARGIN * nearest)
    save_codes(tmp_path, codes, 2.5)
    found = load_codes(tmp_path)
    assert found is not None and torch.equal(found[0], codes) and found[1] == 2.5
    save_codes(tmp_path, codes)
    assert load_codes(tmp_path)[1] is None  # type: ignore[index]


def test_foreign_versions_are_blank_noise_inverted_and_washed_out() -> None:
    batch = torch.rand(2, 3, 8, 8, generator=torch.Generator().manual_seed(0))
    made = foreign_versions(batch)
    assert made.shape == (12, 3, 8, 8) and float(made.min()) >= 0 and float(made.max()) <= 1
    assert [float(made[i].mean()) for i in (0, 2, 4)] == [0.0, 0.5, 1.0]
    assert torch.equal(made[8:10], 1 - batch)
    washed = made[10:]
    assert torch.allclose(washed.std(dim=(1, 2, 3)), 0.1 * batch.std(dim=(1, 2, 3)), rtol=1e-4)
    assert torch.equal(made, foreign_versions(batch))  # seeded noise


def test_either_part_raises_the_uncertainty() -> None:
    assert combine(0.0, None) == 0.0 and combine(0.0, 0.0) == 0.0
    assert combine(0.2, 0.5) == pytest.approx(0.6)
    assert combine(0.3, 0.1) > combine(0.2, 0.1) and combine(0.2, 0.4) > combine(0.2, 0.1)
    assert combine(1.0, 0.0) == 1.0 and combine(0.0, 1.0) == 1.0


def test_the_mask_part_is_the_geometric_mean_of_the_spread_and_the_ambiguity() -> None:
    """Both must be high: either at 0 gives 0; each raises it; a factor on either counts the
    same (their scales differ: the spread is often a tenth of the ambiguity); and the
    uncertainty of a frame's parts is this part ⊕ the novelty."""
    assert mask_doubt(0.04, 0.25) == pytest.approx(0.1)
    assert mask_doubt(0.0, 0.9) == 0.0 and mask_doubt(0.3, 0.0) == 0.0
    assert mask_doubt(0.08, 0.25) > mask_doubt(0.04, 0.25) < mask_doubt(0.04, 0.5)
    assert mask_doubt(0.08, 0.25) == pytest.approx(mask_doubt(0.04, 0.5))
    assert mask_doubt(0.16, 0.25) == pytest.approx(2 * mask_doubt(0.04, 0.25))
    parts: dict[str, float | None] = {"spread": 0.04, "ambiguity": 0.25, "novelty": 0.5}
    assert uncertainty_of(parts) == pytest.approx(0.55)
    assert uncertainty_of(parts | {"novelty": None}) == pytest.approx(0.1)


def _distances(predictor: StudentPredictor, images: list[NDArray[np.uint8]]) -> list[float]:
    batch, _ = frames_to_batch(images, predictor.config)
    with torch.inference_mode():
        codes = frame_codes(predictor.model.features(batch))
    assert predictor.training_codes is not None
    return predictor.training_codes.distance(codes)


def test_frames_unlike_the_training_ones_score_above_like_ones(sure_student: TrainResult) -> None:
    """Noise, a blank frame and an inverted one against held-out synthetic frames like the
    training ones: twice as far from the training frames as the farthest like one, the
    student's own familiar distance between the two, and above every like frame in
    uncertainty. A constant score or a dropped novelty fails here."""
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
    assert predictor.training_codes is not None
    familiar = predictor.training_codes.familiar
    saved = load_codes(sure_student.model_dir)
    assert saved is not None and saved[1] == familiar  # measured by its training, not the fallback
    assert max(near) < familiar < min(far) and min(far) > 2 * max(near), (near, far, familiar)
    found = predictor.predict(like + unlike, samples=4)
    scores = [p.uncertainty for p in found]
    assert all(s is not None and 0 <= s <= 1 for s in scores)
    assert min(scores[4:]) > max(scores[:4]), scores  # type: ignore[type-var]
    assert [p.uncertainty_parts["novelty"] for p in found[:4]] == [0.0] * 4  # type: ignore[index]
    # The score is √(spread × ambiguity) ⊕ the novelty, from the parts it reports.
    parts = [p.uncertainty_parts or {} for p in found]
    made = [combine(mask_doubt(q["spread"] or 0, q["ambiguity"] or 0), q["novelty"]) for q in parts]
    assert scores == pytest.approx(made)
    assert any(q["spread"] != q["ambiguity"] for q in parts)  # type: ignore[index]


def _dim(frame: TrainingFrame, contrast: float = 0.1) -> NDArray[np.uint8]:
    """The frame with its contrast cut to ``contrast`` about its mean (a dim exposure, smoke
    over the pool): the pool's edge is hard to see."""
    image = frame.image.astype(np.float32)
    centre = image.mean()
    return np.clip(centre + contrast * (image - centre), 0, 255).astype(np.uint8)


def test_the_uncertainty_rises_on_frames_the_student_gets_wrong(sure_student: TrainResult) -> None:
    """A known hard region: the same held-out frames dimmed. The student really gets them wrong
    (lower IoU on average, checked), every dimmed frame scores above its clean self, and over
    both sets the score ranks the error. Constant, dropped or inverted, it fails."""
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
