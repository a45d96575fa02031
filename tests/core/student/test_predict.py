"""Inference: outputs mapped back to each frame's full resolution, batches, uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import keypoints_from_mask
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import StudentPredictor, to_frame
from weldpool_core.student.train import TrainResult
from weldpool_core.synth import SynthParams, synth_frame

HEATMAP_MODES = StudentConfig(keypoints="heatmap")


def _spot(size: int, x: float, y: float, sigma: float = 1.5) -> np.ndarray:
    axis = np.arange(size, dtype=np.float32)
    return np.exp(-((axis[None, :] - x) ** 2 + (axis[:, None] - y) ** 2) / (2 * sigma**2))


@pytest.mark.parametrize("aspect", ["letterbox", "resize"])
def test_keypoints_and_maps_come_back_in_frame_pixels(aspect: str) -> None:
    geometry = FrameGeometry.fit(200, 320, 64, aspect)  # type: ignore[arg-type]
    truth = np.array([[100.0, 50.0], [250.0, 150.0]])
    at_input = geometry.to_input(truth)
    heatmap = _spot(64, *at_input[0]) + _spot(64, *at_input[1])
    mask = np.zeros((64, 64), np.float32)
    mask[geometry.inner_rows, geometry.inner_columns] = 1.0
    found = to_frame(mask, heatmap.astype(np.float32), geometry, HEATMAP_MODES)
    assert found.mask.shape == (200, 320) and found.mask.all()
    assert found.heatmap.shape == (200, 320, 2) and found.heatmap.dtype == np.float32
    order = np.argsort(found.keypoints[:, 0])
    assert np.allclose(found.keypoints[order], truth, atol=0.6)


def test_keypoints_follow_the_source_the_config_names() -> None:
    """The predicted mask says a pool at one place, the heatmap has its peaks elsewhere: the
    default student reads Algorithm 1's keypoints of the mask (as a label's are placed; read at
    model size, within 5 model pixels of Algorithm 1 on the full-resolution mask, whose
    smoothing is finer), a heatmap student the peaks, 40 model pixels to the side; and a mask
    with no pool gives no keypoints, not the heatmap's."""
    frame = synth_frame(3)
    geometry = FrameGeometry.fit(*frame.mask.shape, 256)
    mask = geometry.image_to_input(frame.mask.astype(np.float32))
    elsewhere = np.roll(geometry.image_to_input(frame.heatmap[:, :, 0]), 40, axis=1)
    truth = keypoints_from_mask(frame.mask)
    from_mask = to_frame(mask, elsewhere, geometry, StudentConfig()).keypoints
    from_peaks = to_frame(mask, elsewhere, geometry, HEATMAP_MODES).keypoints
    pixel = 1 / geometry.scale_x
    assert len(from_mask) == 4 and np.abs(from_mask - truth).max() < 5 * pixel
    assert len(from_peaks) == 4 and np.abs(from_peaks - truth)[:, 0].min() > 30 * pixel
    nothing = to_frame(np.zeros_like(mask), elsewhere, geometry, StudentConfig())
    assert nothing.keypoints.shape == (0, 2) and not nothing.mask.any()


def test_a_notch_split_in_two_lobes_is_one_keypoint() -> None:
    """Algorithm 1's heatmap is Gaussians × mask, so the wire's notch shows as two lobes.

    Read at model size, each synthetic frame's true maps give back all of its keypoints: the
    second lobe does not take the place of another keypoint (it did with a fixed 8 px radius in
    9 of these 24 runs).
    """
    for seed in range(24):
        frame = synth_frame(seed)
        geometry = FrameGeometry.fit(*frame.mask.shape, 256)
        maps = geometry.image_to_input(frame.heatmap)
        found = to_frame(maps[:, :, 1], maps[:, :, 0], geometry, HEATMAP_MODES)
        cost = np.linalg.norm(found.keypoints[:, None] - frame.keypoints[None], axis=2)
        rows, columns = linear_sum_assignment(cost)
        assert len(found.keypoints) == 4, seed
        assert cost[rows, columns].max() < 3.0 / geometry.scale_x, seed  # 3 model pixels


def test_frames_of_any_size_and_kind_predict_in_one_batch(trained: TrainResult) -> None:
    predictor = StudentPredictor.load(trained.model_dir, "cpu", batch_size=2)
    wide = synth_frame(0, SynthParams(width=160, height=100)).image  # gray uint8
    tall = np.zeros((90, 70, 3), np.uint8)
    deep = synth_frame(1, SynthParams(width=96, height=64, bit_depth=16)).image
    found = predictor.predict([wide, tall, deep])
    assert [p.mask.shape for p in found] == [(100, 160), (90, 70), (64, 96)]
    assert [p.heatmap.shape[:2] for p in found] == [(100, 160), (90, 70), (64, 96)]
    for prediction in found:
        assert prediction.uncertainty is None and len(prediction.keypoints) <= 4
        assert np.array_equal(prediction.mask, prediction.heatmap[:, :, 1] >= 0.5)
        assert prediction.heatmap.min() >= 0 and prediction.heatmap.max() <= 1


def test_uncertainty_is_a_reproducible_spread_in_zero_one(trained: TrainResult) -> None:
    predictor = StudentPredictor.load(trained.model_dir, "cpu")
    frames = [synth_frame(seed, SynthParams(width=96, height=64)).image for seed in (3, 4)]
    first = predictor.predict(frames, samples=6)
    again = predictor.predict(frames, samples=6)
    scores = [p.uncertainty for p in first]
    assert scores == [p.uncertainty for p in again]
    assert all(s is not None and 0 < s <= 1 for s in scores)
    plain = predictor.predict(frames)
    assert np.array_equal(plain[0].mask, first[0].mask)  # sampling never changes the answer
    with pytest.raises(InvalidInputError, match="samples"):
        predictor.predict(frames, samples=-1)


def test_samples_are_at_most_64(trained: TrainResult) -> None:
    """Each sample is one more forward pass: a count past the documented cap
    (``predict.MAX_SAMPLES``) is one sentence, either way in (``predict`` of frames, and
    ``outputs`` of a prepared batch, as ``weldpool stream --samples`` calls it)."""
    import torch

    predictor = StudentPredictor.load(trained.model_dir, "cpu")
    frames = [synth_frame(3, SynthParams(width=96, height=64)).image]
    sentence = "samples must be between 0 and 64, not 65."
    with pytest.raises(InvalidInputError, match=sentence):
        predictor.predict(frames, samples=65)
    with pytest.raises(InvalidInputError, match=sentence):
        predictor.outputs(torch.zeros(1, 3, 64, 64), samples=65)


def test_a_folder_without_a_model_is_one_sentence(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InvalidInputError, match="not a student model folder"):
        StudentPredictor.load(tmp_path, "cpu")
