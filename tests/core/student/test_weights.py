"""Per-frame loss weights (teacher pseudo-labels count less than reviewed labels)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest
import torch

from tests.core.student.common import TINY_STUDENT, synthetic_frames
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.student import train
from weldpool_core.student.data import (
    TrainingFrame,
    TrainingTargets,
    collate,
    make_targets,
    prepare_frame,
)
from weldpool_core.student.model import build_student
from weldpool_core.student.train import LossWeights, boundary_band, student_loss


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


def _batch(frames: list[TrainingFrame], weights: list[float]) -> TrainingTargets:
    params = HeatmapParams(k=4)
    size, aspect = TINY_STUDENT.input_size, TINY_STUDENT.aspect
    batch = collate([make_targets(prepare_frame(f, size, aspect, params), 2.0) for f in frames])
    return type(batch)(batch.image, batch.mask, batch.heatmap, torch.tensor(weights))


def test_each_head_learns_on_its_own_bootstrap_weights(monkeypatch: pytest.MonkeyPatch) -> None:
    """With several heads the loss is the heads' mean; each head's frames weigh by their own
    weight times a draw of mean 1, a new draw per head, and every head gets a gradient."""
    torch.manual_seed(0)
    model = build_student(replace(TINY_STUDENT, heads=3), load_pretrained=False).model
    batch = _batch(synthetic_frames(4), [1.0, 1.0, 0.5, 1.0])
    seen: list[torch.Tensor] = []
    real = train._head_losses

    def spy(*args: Any) -> tuple[torch.Tensor, torch.Tensor]:
        seen.append(args[-1])
        return real(*args)

    monkeypatch.setattr(train, "_head_losses", spy)
    losses = student_loss(model, batch, LossWeights(), 0.0, torch.Generator().manual_seed(0))
    assert len(seen) == 3 and not torch.allclose(seen[0], seen[1])
    for weight in seen:  # the frame's own weight times a positive draw
        assert (weight > 0).all() and not torch.allclose(weight, torch.tensor(1.0))
    losses.total.backward()
    for decoder in (model.decoder, *model.more_heads):
        assert decoder.head.weight.grad is not None and decoder.head.weight.grad.abs().sum() > 0


def test_identical_heads_on_one_frame_lose_what_one_head_does() -> None:
    """One frame: its weight cancels in every term, so three copies of one decoder lose exactly
    what that decoder alone does (a sum over heads instead of their mean fails here)."""
    torch.manual_seed(0)
    three = build_student(replace(TINY_STUDENT, heads=3), load_pretrained=False).model.eval()
    for decoder in three.more_heads:
        decoder.load_state_dict(three.decoder.state_dict())
    one = build_student(TINY_STUDENT, load_pretrained=False).model.eval()
    one.load_state_dict(three.state_dict(), strict=False)
    batch = _batch(synthetic_frames(1), [1.0])
    with torch.no_grad():
        found = [
            student_loss(m, batch, LossWeights(), 0.0, torch.Generator().manual_seed(0))
            for m in (three, one)
        ]
    assert float(found[0].mask) == pytest.approx(float(found[1].mask), rel=1e-5)
    assert float(found[0].heatmap) == pytest.approx(float(found[1].heatmap), rel=1e-5)
