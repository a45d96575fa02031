"""Training windows: frames and targets move together; what labels can make a window."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import write_video
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.student.data import Augmentation, TrainingFrame, prepare_frame
from weldpool_core.student.sequential import (
    SequentialConfig,
    Window,
    train_sequential,
)
from weldpool_core.student.sequential.training import _example
from weldpool_core.student.train import TrainResult


def test_a_window_moves_its_frames_and_their_targets_together() -> None:
    """With a drift, step t of a window is the labelled frame shifted by v·(t − T + 1) — its
    input and its targets by the same amount (a target left behind, or moved the other way,
    would teach the cell to lag)."""
    image = np.zeros((64, 64, 3), np.uint8)
    mask = np.zeros((64, 64), bool)
    image[24:40, 20:36] = 200
    mask[24:40, 20:36] = True
    prepared = prepare_frame(TrainingFrame(image, mask), 64, "letterbox", HeatmapParams())
    window = Window([prepared.image] * 6, prepared)
    config = SequentialConfig(drift=0.05, augmentation=Augmentation(enabled=False))
    images, masks, heats, drift = _example(window, config, np.random.default_rng(4))

    def centre(values: np.ndarray) -> np.ndarray:
        rows, columns = np.indices(values.shape)
        return np.array([(columns * values).sum(), (rows * values).sum()]) / values.sum()

    inputs = np.array([centre(images[t, 0].numpy()) for t in range(6)])
    targets = np.array([centre(masks[t].numpy()) for t in range(6)])
    np.testing.assert_allclose(inputs, targets, atol=0.05)
    steps = np.diff(targets, axis=0)
    assert np.abs(steps).max() > 0.5  # it drifts …
    np.testing.assert_allclose(steps, np.repeat(steps[:1], 5, 0), atol=0.05)  # … steadily
    np.testing.assert_allclose(targets[-1], centre(mask.astype(np.float64)), atol=0.05)
    np.testing.assert_allclose(steps[0], drift.numpy(), atol=0.05)  # the drift it reports
    assert all(heats[t].sum() > 0 for t in range(6))


def _dataset(root: Path, stem: str) -> Path:
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    cv2.imwrite(str(root / "images" / f"{stem}.png"), np.zeros((64, 96, 3), np.uint8))
    cv2.imwrite(str(root / "masks" / f"{stem}.png"), np.zeros((64, 96), np.uint8))
    return root


def test_labels_that_cannot_make_a_window_are_one_sentence(
    trained: TrainResult, tmp_path: Path
) -> None:
    from weldpool_core.student.sequential import dataset_clips

    videos = tmp_path / "videos"
    videos.mkdir()
    write_video(videos / "weld3.avi", 16)
    config = SequentialConfig()
    early = _dataset(tmp_path / "early", "weld3_f0002")  # 7 frames before it are needed
    with pytest.raises(InvalidInputError, match="frames before it"):
        train_sequential(trained.model_dir, dataset_clips(early, videos, config), config)
    unnamed = _dataset(tmp_path / "unnamed", "weld3")
    with pytest.raises(InvalidInputError, match="does not name its video frame"):
        dataset_clips(unnamed, videos, config)
    beyond = _dataset(tmp_path / "beyond", "weld3_f0040")
    with pytest.raises(InvalidInputError, match="has 16 frames; labelled frame 40"):
        dataset_clips(beyond, videos, config)
    absent = _dataset(tmp_path / "absent", "run7_f0020")
    with pytest.raises(InvalidInputError, match=r"No video run7\.mp4"):
        dataset_clips(absent, videos, config)


def test_a_clip_kept_at_model_resolution_gives_the_same_windows(tmp_path: Path) -> None:
    """Frames placed on the student's input as they are decoded (what keeps a long video's
    windows small) make exactly the windows the full-resolution frames make."""
    from tests.core.student.common import TINY_STUDENT
    from weldpool_core.student.sequential import clip_windows, video_clip

    video = write_video(tmp_path / "run.avi", 24)
    capture = cv2.VideoCapture(str(video))
    for _ in range(16):
        ok, bgr = capture.read()
    capture.release()
    assert ok
    mask = np.zeros(bgr.shape[:2], np.bool_)
    mask[20:44, 30:70] = True
    labels = {15: TrainingFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), mask, name="f15")}
    config = SequentialConfig()
    full = video_clip(video, labels, config, unlabelled=[9, 23])
    small = video_clip(video, labels, config, unlabelled=[9, 23], student=TINY_STUDENT)
    assert full.placed is None and small.frames(15).shape == (64, 64, 3)
    assert full.frames(15).shape == (64, 96, 3)
    ours, theirs = (
        clip_windows([small], config, TINY_STUDENT),
        clip_windows([full], config, TINY_STUDENT),
    )
    assert [w.labelled for w in ours] == [True, True, False, False]
    assert len(ours) == len(theirs)
    for mine, reference in zip(ours, theirs, strict=True):
        assert all(np.array_equal(a, b) for a, b in zip(mine.inputs, reference.inputs, strict=True))
        assert np.array_equal(mine.target.mask, reference.target.mask)
        assert np.array_equal(mine.target.keypoints, reference.target.keypoints)
    other = replace(TINY_STUDENT, input_size=96)
    with pytest.raises(InvalidInputError, match="were kept for a 64² input"):
        clip_windows([small], config, other)
    halved = {15: TrainingFrame(np.zeros((32, 48, 3), np.uint8), mask[:32, :48], name="f15")}
    assert video_clip(video, halved, config, student=TINY_STUDENT).placed == small.placed
    wrong = {15: TrainingFrame(np.zeros((64, 64, 3), np.uint8), mask[:, :64], name="f15")}
    with pytest.raises(InvalidInputError, match="is 64×64, another shape than the video's 96×64"):
        video_clip(video, wrong, config, student=TINY_STUDENT)
