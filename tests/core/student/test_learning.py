"""The student learns: synthetic weld pools in, held-out mIoU and mED out (issue 6's bar).

150 256×160 synthetic frames (75 weld runs at 2 times each), the light student at 256²
(letterboxed, so model pixels are frame pixels), 12 epochs on the CPU: about 40 s on two
uncontended cores. Held out: 40 frames of 40 other weld runs, scored at full resolution
through ``StudentPredictor`` against the synthetic ground truth (Algorithm 1's keypoints).

Issue 6 asks for mIoU ≥ 0.85 and mED ≤ 8 px; the test asks for more (0.88 and 6 px), since a
student trained as long on masks shuffled between the frames reaches mIoU 0.83 and mED 6.8 px
(it learns where pools usually are) and would pass 8 px. This one reaches 0.93 and 4.2 px
(on half the frames the test first trained on, 300); an untrained one 0.21 and 85 px.
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
TIMES = (0.0, 1.4)


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
    assert result.train_frames + result.validation_frames == 150
    assert miou >= 0.88  # issue 6: 0.85; shuffled masks: 0.83
    assert scores.med is not None and scores.med <= 6.0 and scores.missed == 0  # 8; 6.8
    assert all(p.uncertainty is not None and 0 <= p.uncertainty <= 1 for p in found)
