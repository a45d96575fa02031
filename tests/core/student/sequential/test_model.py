"""The cell's arithmetic, and the first frame of a sequence."""

from __future__ import annotations

import torch

from tests.core.student.sequential.common import gated_cell
from weldpool_core.student import checkpoint
from weldpool_core.student.sequential import (
    LatentCell,
    SequentialStudent,
)
from weldpool_core.student.train import TrainResult


def test_the_cell_keeps_the_share_of_the_past_its_update_gate_leaves() -> None:
    x1, x2, x3 = (
        torch.randn(1, 2, 3, 3, generator=torch.Generator().manual_seed(s)) for s in (1, 2, 3)
    )
    cell = gated_cell(2, update=0.25)
    s1 = cell(x1, None)
    assert torch.equal(s1, x1)  # the first frame is the frame's own latent
    s2 = cell(x2, s1)
    torch.testing.assert_close(s2, x1 + 0.25 * (x2 - x1))
    s3 = cell(x3, s2)
    torch.testing.assert_close(s3, s2 + 0.25 * (x3 - s2))
    # the correction moves the candidate along the innovation: c = x + 0.5 (x − s)
    corrected = gated_cell(2, update=0.25, correction=0.5)(x2, x1)
    torch.testing.assert_close(corrected, x1 + 0.25 * 1.5 * (x2 - x1))
    # a state equal to the frame's latent is a fixed point, whatever the weights
    trained_like = LatentCell(2)
    with torch.no_grad():
        for parameter in trained_like.parameters():
            parameter.normal_()
    torch.testing.assert_close(trained_like(x2, x2), x2)


def test_the_first_frame_is_the_per_frame_students_answer(trained: TrainResult) -> None:
    student = checkpoint.load_student(trained.model_dir)
    model = SequentialStudent(student, LatentCell(student.config.latent_channels)).eval()
    images = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        alone = student(images, sample=False)
        mask, heat, state = model.step(images, None)
        torch.testing.assert_close(mask, alone.mask_logits)
        torch.testing.assert_close(heat, alone.heatmap_logits)
        torch.testing.assert_close(state, alone.mean)
