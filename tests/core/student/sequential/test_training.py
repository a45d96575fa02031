"""The drift-aware steadiness loss, and what training teaches the cell."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from weldpool_core.heatmap import HeatmapParams
from weldpool_core.student import checkpoint
from weldpool_core.student.data import TrainingFrame, prepare_frame
from weldpool_core.student.sequential import (
    LabelledClip,
    SequentialConfig,
    load_sequential,
    shift,
    train_sequential,
    unsteadiness,
)


def test_shift_moves_a_map_by_the_drift_along_x_and_y() -> None:
    values = torch.zeros(1, 2, 16, 16)
    values[0, :, 5, 3] = 1.0  # row 5, column 3
    moved = shift(values, torch.tensor([[4.0, 2.0]]))  # 4 px right, 2 px down
    assert moved[0, 0, 7, 7] == pytest.approx(1.0) and moved[0, 1, 7, 7] == pytest.approx(1.0)
    assert moved.sum() == pytest.approx(2.0)
    half = shift(values, torch.tensor([[0.5, 0.0]]))[0, 0]
    assert half[5, 3] == pytest.approx(0.5) and half[5, 4] == pytest.approx(0.5)


def test_unsteadiness_counts_only_what_the_drift_does_not_explain() -> None:
    square = torch.zeros(32, 32)
    square[10:20, 10:20] = 1.0
    moved = torch.roll(square, shifts=(0, 2), dims=(0, 1))  # 2 px right
    grown = square.clone()
    grown[10:20, 20] = 1.0  # one column more: 10 of 110 pixels new
    pair = torch.stack([square, moved])[None]
    assert float(unsteadiness(pair, torch.tensor([[2.0, 0.0]]))) == pytest.approx(0.0, abs=1e-6)
    # the same move with no drift to explain it: 20 pixels lost, 20 gained, of 100
    assert float(unsteadiness(pair, torch.tensor([[0.0, 0.0]]))) == pytest.approx(0.4)
    # a drift along y does not explain a move along x: the squares overlap on 8×8 pixels
    assert float(unsteadiness(pair, torch.tensor([[0.0, 2.0]]))) == pytest.approx(0.72)
    growing = torch.stack([square, grown])[None]
    assert float(unsteadiness(growing, torch.zeros(1, 2))) == pytest.approx(10 / 110)


def _noisy_clip(frames: list[np.ndarray], label: TrainingFrame, index: int) -> LabelledClip:
    ends = tuple(range(5, len(frames)))  # unlabelled windows of 6 for the steadiness term
    return LabelledClip(frames.__getitem__, len(frames), {index: label}, "noisy", ends)


@pytest.mark.slow
def test_training_teaches_the_cell_to_steady_a_flickering_pool(tmp_path: Path) -> None:
    """A student trained on still frames, a clip whose frames flicker (independent noise and
    exposure per frame around one still pool): after training, the sequential answers move
    less from frame to frame than the per-frame ones, and fit the pool as well."""
    from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
    from weldpool_core.student.train import train_student

    frames = synthetic_frames(16)
    root = tmp_path / "model"
    latent_only = replace(TINY_STUDENT, skips=0)  # a skip student's finer maps are per frame
    train_student(frames, root, latent_only, tiny_config(epochs=None, steps=150, rounds=3))
    rng = np.random.default_rng(0)

    def flicker(image: np.ndarray) -> np.ndarray:
        noisy = image * rng.uniform(0.6, 1.4) + rng.normal(0, 25, image.shape)
        return np.clip(noisy, 0, 255).astype(np.uint8)

    clips = []
    for label in frames[:6]:
        video = [flicker(label.image) for _ in range(12)]
        clips.append(_noisy_clip(video, label, 11))
    config = SequentialConfig(steps=60, device="cpu", window=6, strides=(1, 2))
    result = train_sequential(root, clips, config)
    assert result.windows == 12 and np.isfinite(result.last_loss)
    model = load_sequential(root)
    per_frame = checkpoint.load_student(root)
    held = frames[12]
    video = torch.stack(
        [
            torch.from_numpy(
                prepare_frame(
                    TrainingFrame(flicker(held.image), held.mask), 64, "letterbox", HeatmapParams()
                ).image.transpose(2, 0, 1)
                / np.float32(255)
            )
            for _ in range(20)
        ]
    )
    with torch.inference_mode():
        alone = torch.sigmoid(per_frame(video, sample=False).mask_logits)
        state, steady = None, []
        for t in range(len(video)):
            mask, _, state = model.step(video[t : t + 1], state)
            steady.append(torch.sigmoid(mask)[0])
    together = torch.stack(steady)
    moves = (alone[6:] - alone[5:-1]).abs().mean()
    moves_seq = (together[6:] - together[5:-1]).abs().mean()
    truth = torch.from_numpy(
        prepare_frame(held, 64, "letterbox", HeatmapParams()).mask.astype(np.float32) / 255
    )

    def iou(probability: torch.Tensor) -> float:
        found, true = probability >= 0.5, truth >= 0.5
        return float((found & true).sum() / (found | true).sum().clamp(min=1))

    ious = [iou(p) for p in alone[5:]]
    ious_seq = [iou(p) for p in together[5:]]
    print(f"moves {moves:.4f} → {moves_seq:.4f}; IoU {np.mean(ious):.3f} → {np.mean(ious_seq):.3f}")
    assert moves_seq < 0.4 * moves  # without the steadiness term: 0.52
    assert np.mean(ious_seq) >= np.mean(ious) - 0.02
