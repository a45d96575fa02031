"""The student's training loss: ``mask_bce``·BCE + ``mask_dice``·Dice on the mask logits (+ an
optional BCE on the band around the true outline) + ``heatmap``·a quality focal loss on the
heatmap logits + β·KL (``weldpool_core.student.train`` explains each term and β's ramp), +
``classes``·the learned classes' terms (``class_loss``) for a student with classes."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from weldpool_core.student.classes import channel_kinds
from weldpool_core.student.data import TrainingTargets
from weldpool_core.student.model import ResNetVAE, kl_divergence


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms (β, the KL weight, is in ``TrainConfig``)."""

    mask_bce: float = 1.0
    mask_dice: float = 1.0
    heatmap: float = 1.0
    mask_boundary: float = 0.0
    """BCE on a band of ``BOUNDARY_BAND`` input pixels either side of the true outline,
    averaged over the band (0: off): where the mask's errors are, e.g. at the wire."""
    classes: float = 1.0
    """Weight of the learned classes' terms (``class_loss``); the pool's terms keep theirs."""


BOUNDARY_BAND = 5
"""Half-width of the boundary loss's band, in model input pixels."""


def boundary_band(mask: torch.Tensor, band: int = BOUNDARY_BAND) -> torch.Tensor:
    """N×H×W 0/1: the pixels within ``band`` pixels of the edge of the N×H×W mask in [0, 1]
    (its dilation minus its erosion by a (2·band + 1)² square)."""
    size = 2 * band + 1
    grown = F.max_pool2d(mask[:, None], size, stride=1, padding=band)
    shrunk = -F.max_pool2d(-mask[:, None], size, stride=1, padding=band)
    return (grown - shrunk)[:, 0].clamp(0, 1)


def _weighted_mean(values: torch.Tensor, weight: torch.Tensor | None) -> torch.Tensor:
    """Σ wᵢ·vᵢ / Σ wᵢ over the batch (the plain mean without weights)."""
    if weight is None:
        return values.mean()
    return (values * weight).sum() / weight.sum().clamp(min=1e-12)


def dice_loss(
    logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """1 − soft Dice per frame, averaged over the batch (N×H×W logits and targets in [0, 1]),
    each frame by its weight when given."""
    probability = torch.sigmoid(logits).flatten(1)
    truth = target.flatten(1)
    overlap = (probability * truth).sum(1)
    return _weighted_mean(1 - (2 * overlap + 1) / (probability.sum(1) + truth.sum(1) + 1), weight)


def heatmap_loss(
    logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """Quality focal loss |y − p|²·BCE(p, y), summed and divided by the target's mass (each
    frame's sum and mass by its weight when given)."""
    probability = torch.sigmoid(logits)
    bce = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    per_frame = (bce * (probability - target).abs().pow(2)).flatten(1).sum(1)
    mass = target.flatten(1).sum(1)
    if weight is not None:
        per_frame, mass = per_frame * weight, mass * weight
    return per_frame.sum() / mass.sum().clamp(min=1.0)


def class_loss(
    logits: torch.Tensor, target: torch.Tensor, present: torch.Tensor, segments: list[bool]
) -> torch.Tensor:
    """The learned classes' loss (N×E×S×S logits and targets, N×E presence flags): per
    segmentation channel BCE + Dice, per point channel the heatmap's quality focal loss, each
    over the frames that have the channel labelled only; summed over the channels."""
    total = logits.new_zeros(())
    for channel, segment in enumerate(segments):
        weight = present[:, channel]
        if not bool(weight.any()):
            continue
        own, truth = logits[:, channel], target[:, channel]
        if segment:
            bce = F.binary_cross_entropy_with_logits(own, truth, reduction="none")
            total = total + _weighted_mean(bce.flatten(1).mean(1), weight)
            total = total + dice_loss(own, truth, weight)
        else:
            total = total + heatmap_loss(own, truth, weight)
    return total


@dataclass
class _Losses:
    total: torch.Tensor
    mask: torch.Tensor
    heatmap: torch.Tensor
    kl: torch.Tensor


def student_loss(
    model: ResNetVAE,
    batch: TrainingTargets,
    weights: LossWeights,
    beta: float,
    generator: torch.Generator | None,
) -> _Losses:
    """The training loss of one batch (see the module doc), with its parts."""
    output = model(batch.image, sample=True, generator=generator)
    bce = F.binary_cross_entropy_with_logits(output.mask_logits, batch.mask, reduction="none")
    mask = weights.mask_bce * _weighted_mean(
        bce.flatten(1).mean(1), batch.weight
    ) + weights.mask_dice * dice_loss(output.mask_logits, batch.mask, batch.weight)
    if weights.mask_boundary:
        band = boundary_band(batch.mask)
        per_frame = (bce * band).flatten(1).sum(1) / band.flatten(1).sum(1).clamp(min=1.0)
        mask = mask + weights.mask_boundary * _weighted_mean(per_frame, batch.weight)
    heat = weights.heatmap * heatmap_loss(output.heatmap_logits, batch.heatmap, batch.weight)
    kl = kl_divergence(output.mean, output.logvar)
    total = mask + heat + beta * kl
    if output.class_logits is not None and batch.classes is not None and batch.present is not None:
        segments = channel_kinds(model.config.classes)
        extra = class_loss(output.class_logits, batch.classes, batch.present, segments)
        total = total + weights.classes * extra
    return _Losses(total, mask, heat, kl)
