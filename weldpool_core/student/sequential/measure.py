"""Measuring the cell against the per-frame student on the same frames."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from weldpool_core.device import resolve_device
from weldpool_core.metrics import iou
from weldpool_core.student.sequential.checkpoint import load_sequential
from weldpool_core.student.sequential.config import SequentialConfig
from weldpool_core.student.sequential.data import LabelledClip
from weldpool_core.student.sequential.model import SequentialStudent
from weldpool_core.student.sequential.training import (
    Window,
    WindowCodes,
    clip_windows,
    encode_windows,
    unroll,
    unsteadiness,
)


def _as_batch(window: Window, device: torch.device) -> torch.Tensor:
    """A window's frames as 1×T×3×S×S in [0, 1], unaugmented."""
    stacked = np.stack(window.inputs).transpose(0, 3, 1, 2).astype(np.float32) / np.float32(255)
    return torch.from_numpy(stacked)[None].to(device)


def _per_frame_masks(model: SequentialStudent, codes: WindowCodes, first: int = 0) -> torch.Tensor:
    """The per-frame student's mask probabilities (N×T′×S×S) of ``encode_windows`` codes from
    step ``first`` on: each frame decoded alone."""
    mask_logits, _ = model.student.decode(*codes.frames(first))
    steps = codes.latents.shape[1] - first
    return torch.sigmoid(mask_logits).reshape(len(codes.latents), steps, *mask_logits.shape[1:])


def measure_sequential(
    model_dir: str | Path,
    clips: Sequence[LabelledClip],
    config: SequentialConfig | None = None,
) -> dict[str, Any]:
    """The sequential student against its own per-frame student on the same frames.

    Accuracy: on each labelled frame of ``clips`` with ``window`` − 1 frames before it, the
    mask IoU (at model resolution, against the label brought there as for training) of the
    per-frame student on that frame alone and of the sequential student after the window's
    frames (stride 1, state fresh at the window's start). Steadiness: on the clips' unlabelled
    windows, ``unsteadiness`` (no drift: the share of the pool's mask that changes from one
    frame to the next) of each. Labelled frames should be ones the cell did not train on.

    Returns ``frames`` and ``windows`` counted, ``per_frame_iou`` / ``sequential_iou`` (None
    without a labelled window) and ``per_frame_change`` / ``sequential_change`` (None without
    an unlabelled window).
    """
    config = replace(config or SequentialConfig(), strides=(1,))
    root = Path(model_dir)
    device = resolve_device(config.device)
    model = load_sequential(root, device)
    windows = clip_windows(clips, config, model.config, require_labelled=False)
    ious: dict[str, list[float]] = {"per_frame": [], "sequential": []}
    changes: dict[str, list[float]] = {"per_frame": [], "sequential": []}
    still = torch.zeros(1, 2, device=device)
    with torch.no_grad():
        for window in windows:
            images = _as_batch(window, device)
            codes = encode_windows(model, images)  # once for both students
            last = images.shape[1] - 1 if window.labelled else 0  # a label: its frame only
            alone = _per_frame_masks(model, codes, last)
            steady = torch.sigmoid(unroll(model, images, first=last, codes=codes)[0])
            if window.labelled:
                truth = window.target.mask >= 128
                for name, probability in (("per_frame", alone), ("sequential", steady)):
                    predicted = (probability[0, -1] >= 0.5).cpu().numpy()
                    ious[name].append(iou(predicted, truth))
            else:
                changes["per_frame"].append(float(unsteadiness(alone, still)))
                changes["sequential"].append(float(unsteadiness(steady, still)))

    def mean(values: list[float]) -> float | None:
        return round(float(np.mean(values)), 4) if values else None

    return {
        "frames": len(ious["per_frame"]),
        "windows": len(changes["per_frame"]),
        "per_frame_iou": mean(ious["per_frame"]),
        "sequential_iou": mean(ious["sequential"]),
        "per_frame_change": mean(changes["per_frame"]),
        "sequential_change": mean(changes["sequential"]),
    }
