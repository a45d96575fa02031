"""Validating the student during training, and moving a batch to the device it trains on.

``validate`` scores the mean-latent outputs at full resolution with
``metrics.proposal_quality`` (the pool) and, for a student with learned classes,
``classes.class_figures`` on the frames that have each class labelled (``metrics["classes"]``;
the round choice reads the pool's figures only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from weldpool_core.metrics import proposal_quality
from weldpool_core.student.classes import (
    ClassTruth,
    PreparedClasses,
    channel_slices,
    class_figures,
    classes_to_frame,
    unpack_truth,
)
from weldpool_core.student.data import PreparedFrame, TrainingTargets
from weldpool_core.student.model import ResNetVAE, StudentConfig
from weldpool_core.student.predict import to_frame


def class_truths(
    config: StudentConfig, prepared: PreparedClasses, height: int, width: int
) -> dict[str, ClassTruth]:
    """A prepared frame's full-resolution class labels, by class (those it has)."""
    truths: dict[str, ClassTruth] = {}
    for learned, where in zip(config.classes, channel_slices(config.classes).values(), strict=True):
        given = prepared.truths[where]
        if learned.segments:
            packed = given[0]
            if packed is not None and not isinstance(packed, tuple):
                truths[learned.name] = ClassTruth(mask=unpack_truth(packed, height, width))
            continue
        points = {
            n: xy for n, xy in zip(learned.points, given, strict=True) if isinstance(xy, tuple)
        }
        if points:
            truths[learned.name] = ClassTruth(points=points)
    return truths


def validate(
    model: ResNetVAE, frames: Sequence[PreparedFrame], device: torch.device, batch_size: int
) -> dict[str, Any]:
    """``metrics.proposal_quality`` of the model's mean-latent outputs on ``frames``, at full
    resolution (``per_image`` left out), and the learned classes' figures (``classes``)."""
    model.eval()
    scored: dict[str, tuple[NDArray[Any], Any, NDArray[Any], Any]] = {}
    outputs: list[dict[str, Any]] = []
    truths: list[dict[str, ClassTruth]] = []
    config = model.config
    with torch.inference_mode():
        for start in range(0, len(frames), batch_size):
            chunk = frames[start : start + batch_size]
            images = np.stack([f.image for f in chunk]).transpose(0, 3, 1, 2)
            batch = torch.from_numpy(images).to(device).float().div_(255.0)
            batch = batch.contiguous(memory_format=torch.channels_last)
            output = model(batch, sample=False)
            masks = torch.sigmoid(output.mask_logits).cpu().numpy()
            heatmaps = torch.sigmoid(output.heatmap_logits).cpu().numpy()
            extra = None
            if output.class_logits is not None:
                extra = torch.sigmoid(output.class_logits).cpu().numpy()
            for offset, frame in enumerate(chunk):
                found = to_frame(masks[offset], heatmaps[offset], frame.geometry, config)
                scored[f"{start + offset}:{frame.name}"] = (
                    found.mask,
                    found.keypoints,
                    frame.truth_mask(),
                    frame.frame_keypoints,
                )
                if extra is not None and frame.classes is not None:
                    geometry = frame.geometry
                    outputs.append(classes_to_frame(extra[offset], config.classes, geometry))
                    truths.append(
                        class_truths(config, frame.classes, geometry.height, geometry.width)
                    )
    metrics = proposal_quality(scored)
    metrics.pop("per_image")
    if config.classes:
        sizes = [(f.geometry.height, f.geometry.width) for f in frames if f.classes is not None]
        metrics["classes"] = class_figures(config.classes, outputs, truths, sizes)
    return metrics


def to_device(batch: TrainingTargets, device: torch.device) -> TrainingTargets:
    """A collated batch on ``device``, channels-last; per-pixel weights only where they vary."""
    weighted = batch.weight is not None and bool((batch.weight != 1).any())
    return replace(
        batch,
        image=batch.image.to(device).contiguous(memory_format=torch.channels_last),
        mask=batch.mask.to(device),
        heatmap=batch.heatmap.to(device),
        weight=batch.weight.to(device) if weighted and batch.weight is not None else None,
        classes=None if batch.classes is None else batch.classes.to(device),
        present=None if batch.present is None else batch.present.to(device),
    )
