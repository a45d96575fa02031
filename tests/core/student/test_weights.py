"""Per-frame loss weights (teacher pseudo-labels count less than reviewed labels)."""

from __future__ import annotations

import pytest
import torch

from tests.core.student.common import TINY_STUDENT, synthetic_frames
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.student.data import TrainingFrame, collate, make_targets, prepare_frame
from weldpool_core.student.losses import LossWeights, boundary_band, student_loss
from weldpool_core.student.model import build_student


def _loss(frames: list[TrainingFrame], weights: list[float] | None) -> float:
    torch.manual_seed(0)
    model = build_student(TINY_STUDENT, load_pretrained=False).model.eval()
    prepared = [
        prepare_frame(f, TINY_STUDENT.input_size, TINY_STUDENT.aspect, HeatmapParams(k=4))
        for f in frames
    ]
    batch = collate([make_targets(p, 2.0) for p in prepared])
    if weights is None:
        batch = type(batch)(batch.image, batch.mask, batch.heatmap, None)
    else:
        batch = type(batch)(batch.image, batch.mask, batch.heatmap, torch.tensor(weights))
    with torch.no_grad():
        # a seeded draw: the first frame's latent noise is the same in a batch of one or two
        losses = student_loss(model, batch, LossWeights(), 0.0, torch.Generator().manual_seed(0))
    return float(losses.mask + losses.heatmap)


def test_a_frame_weighs_in_the_loss_by_its_weight() -> None:
    first, second = synthetic_frames(2)
    second = TrainingFrame(second.image, ~second.mask, None, "inverted")  # a very wrong target
    alone = _loss([first], None)
    both = _loss([first, second], None)
    assert _loss([first, second], [1.0, 1.0]) == pytest.approx(both, rel=1e-6)
    assert both != pytest.approx(alone, rel=1e-3)
    assert _loss([first, second], [1.0, 1e-9]) == pytest.approx(alone, rel=1e-6)
    half = _loss([first, second], [1.0, 0.5])
    assert min(alone, both) < half < max(alone, both)
    swapped = _loss([first, second], [1e-9, 1.0])  # the weight follows its frame
    assert swapped != pytest.approx(alone, rel=1e-3) and swapped > both


def test_a_frame_weight_must_lie_in_0_1() -> None:
    frame = synthetic_frames(1)[0]
    for bad in (0.0, -1.0, 1.5):
        with pytest.raises(InvalidInputError, match="weight"):
            TrainingFrame(frame.image, frame.mask, None, "w", bad)
    prepared = prepare_frame(
        TrainingFrame(frame.image, frame.mask, None, "w", 0.25), 64, "letterbox", HeatmapParams()
    )
    assert prepared.weight == 0.25 and float(make_targets(prepared, 2.0).weight) == 0.25


def test_the_boundary_band_is_the_outline_and_its_loss_weighs_only_there() -> None:
    mask = torch.zeros(1, 40, 40)
    mask[:, 10:30, 10:30] = 1
    band = boundary_band(mask, band=3)
    assert band[0, 20, 20] == 0 and band[0, 2, 2] == 0  # deep inside, far outside
    assert band[0, 10, 20] == 1 and band[0, 7, 20] == 1 and band[0, 12, 20] == 1
    assert band[0, 6, 20] == 0 and band[0, 13, 20] == 0  # beyond 3 px either side
    assert float(band.sum()) == 26 * 26 - 14 * 14  # the ring between dilation and erosion
    frames = synthetic_frames(1)
    plain = _loss(frames, None)
    torch.manual_seed(0)
    model = build_student(TINY_STUDENT, load_pretrained=False).model.eval()
    prepared = prepare_frame(
        frames[0], TINY_STUDENT.input_size, TINY_STUDENT.aspect, HeatmapParams(k=4)
    )
    batch = collate([make_targets(prepared, 2.0)])
    with torch.no_grad():
        off = student_loss(model, batch, LossWeights(), 0.0, torch.Generator().manual_seed(0))
        on = student_loss(
            model, batch, LossWeights(mask_boundary=1.0), 0.0, torch.Generator().manual_seed(0)
        )
    assert float(off.mask + off.heatmap) == pytest.approx(plain)
    assert float(on.mask) > float(off.mask)  # the band's BCE is added on top
