"""The student learns: synthetic weld pools in, held-out mIoU and mED out (issue 6's bar).

A few hundred 256×160 synthetic frames (75 weld runs at 4 times each), the light student at
256² (letterboxed, so model pixels are frame pixels), 12 epochs on the CPU: about a minute on
two uncontended cores. Held out: 40 frames of 40 other weld runs, scored at full resolution
through ``StudentPredictor`` against the synthetic ground truth (Algorithm 1's keypoints).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from tests.core.student.common import synthetic_frames
from weldpool_core.metrics import iou, keypoint_scores
from weldpool_core.student.model import student_config
from weldpool_core.student.predict import StudentPredictor
from weldpool_core.student.train import TrainConfig, train_student
from weldpool_core.synth import SynthParams, synth_frame

FRAME = SynthParams(width=256, height=160)
TIMES = (0.0, 0.7, 1.4, 2.1)


@pytest.mark.slow
def test_the_light_student_learns_synthetic_pools_at_256(tmp_path: Path) -> None:
    started = time.perf_counter()
    frames = [f for t in TIMES for f in synthetic_frames(75, FRAME, 0, t)]
    student = student_config("light")
    assert student.input_size == 256
    result = train_student(
        frames, tmp_path / "model", student, TrainConfig(epochs=12, device="cpu", seed=0)
    )
    seconds = time.perf_counter() - started
    predictor = StudentPredictor.load(tmp_path / "model", "cpu")
    held_out = [synth_frame(seed, FRAME, 0.3) for seed in range(1000, 1040)]
    found = predictor.predict([frame.image for frame in held_out], samples=4)
    pairs = list(zip(found, held_out, strict=True))
    miou = float(np.mean([iou(p.mask, f.mask) for p, f in pairs]))
    scores = keypoint_scores({str(i): (p.keypoints, f.keypoints) for i, (p, f) in enumerate(pairs)})
    print(
        f"trained {len(frames)} frames in {seconds:.0f} s; held-out mIoU {miou:.3f}, "
        f"mED {scores.med:.2f} px, best epoch {result.best_epoch}"
    )
    assert result.train_frames + result.validation_frames == 300
    assert miou >= 0.85
    assert scores.med is not None and scores.med <= 8.0 and scores.missed == 0
    assert all(p.uncertainty is not None and 0 <= p.uncertainty <= 1 for p in found)
