"""Held-out scores: the heatmap's keypoints and Algorithm 1's on the predicted mask, apart."""

from __future__ import annotations

import numpy as np
import pytest

from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.io import to_rgb8
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.evaluate import score_predictions
from weldpool_core.student.predict import StudentPrediction
from weldpool_core.synth import SynthParams, synth_frame


def test_the_mask_and_the_heatmap_keypoints_are_scored_each_on_its_own() -> None:
    """A prediction whose mask is the truth but whose heatmap keypoints sit 10 px to the right:
    mED 10 from the heatmap, 0 from Algorithm 1 on the mask. An empty mask has no corners."""
    truth = synth_frame(3, SynthParams(width=320, height=200))
    frame = TrainingFrame(to_rgb8(truth.image), truth.mask, None, "f")
    corners = heatmap_from_mask(truth.mask, HeatmapParams(k=4)).keypoints
    heatmap = np.zeros((*truth.mask.shape, 2), np.float32)
    right = StudentPrediction(truth.mask.astype(bool), heatmap, corners + np.array([10.0, 0.0]))
    empty = StudentPrediction(np.zeros_like(truth.mask, bool), heatmap, corners)
    scores = score_predictions([right, empty], [frame, frame], k=4)
    assert scores.ious == [1.0, 0.0]
    assert scores.distances[0] == pytest.approx([10.0] * len(corners))
    assert scores.distances[1] == pytest.approx([0.0] * len(corners))
    assert scores.mask_distances[0] == pytest.approx([0.0] * len(corners))
    assert np.isnan(scores.mask_distances[1]).all()
    assert scores.med == pytest.approx(5.0) and scores.mask_med == pytest.approx(0.0)
