"""Student inference: frames → mask, heatmap, keypoints and uncertainty, at full resolution.

``StudentPredictor.load(model_dir)`` reads a checkpoint once and prepares the network for
inference (BatchNorm folded into the convolutions, channels-last memory, inference mode; half
precision on CUDA via ``device.inference_dtype``). ``predict`` takes a batch of frames of any
size, fits each to the input (``FrameGeometry``), runs them together, and maps the outputs back.

Keypoints are the modes of the predicted heatmap (``keypoints_from_heatmap``) found at model
resolution and mapped to frame pixels, so they keep the sub-pixel refinement of the small map;
of modes closer than half Algorithm 1's keypoint separation, only the strongest counts: the
others are lobes of the same keypoint (``mode_distance``).

Uncertainty (``samples`` > 0): the frame is encoded once, the decoder runs on ``samples`` latent
draws z = μ + σ·ε, and the score is twice the mean, over the frame's pixels, of the per-pixel
standard deviation of the mask probability across the draws. A probability's standard
deviation is at most 0.5, so the score lies in [0, 1]: 0 when every draw agrees, higher where
the encoder is unsure of the pool (the active-learning queue sorts by it). The draws are seeded,
so the same frame gets the same score.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from numpy.typing import NDArray

from weldpool_core.device import inference_dtype, resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.io import to_rgb8
from weldpool_core.keypoints import ModeParams, keypoints_from_heatmap
from weldpool_core.student.checkpoint import load_student
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.model import ResNetVAE, StudentConfig, channels_last, fuse_batchnorm

UNCERTAINTY_SEED = 0
MIN_MODE_DISTANCE = 5.0


@dataclass(frozen=True)
class StudentPrediction:
    """The student's answer for one frame, in full-resolution pixels.

    Attributes:
        mask: H×W bool, mask probability ≥ 0.5.
        heatmap: H×W×2 float32: channel 0 the keypoint heatmap in [0, 1], channel 1 the mask
            probability (the layout of Algorithm 1's output).
        keypoints: m×2 ``(x, y)`` heatmap modes in the order rule (m ≤ k).
        uncertainty: the latent-sample spread in [0, 1] (see the module doc), or None when no
            samples were asked for.
    """

    mask: NDArray[np.bool_]
    heatmap: NDArray[np.float32]
    keypoints: NDArray[np.float64]
    uncertainty: float | None = None


def frames_to_batch(
    images: Sequence[NDArray[Any]], config: StudentConfig
) -> tuple[torch.Tensor, list[FrameGeometry]]:
    """RGB frames → an N×3×S×S input batch in [0, 1], and each frame's geometry."""
    inputs, geometries = [], []
    for image in images:
        rgb = to_rgb8(image)
        geometry = FrameGeometry.fit(rgb.shape[0], rgb.shape[1], config.input_size, config.aspect)
        inputs.append(geometry.image_to_input(rgb))
        geometries.append(geometry)
    batch = torch.from_numpy(np.stack(inputs)).permute(0, 3, 1, 2).float().div_(255.0)
    return batch, geometries


def mode_distance(mask_probability: NDArray[np.float32], k: int) -> float:
    """Radius within which two heatmap modes are lobes of one keypoint, in model pixels.

    Algorithm 1 keeps keypoints at least ``HeatmapParams(k).separation`` of the outline apart,
    and its heatmap is the Gaussians times the smoothed mask, so a keypoint at a concave notch
    (the wire's) shows as two lobes on either side of it. Modes closer than half that separation
    (as a straight distance along the predicted outline) are one keypoint, and the strongest
    lobe is the nearer to it (the keypoint lies on the outline); 5 px at least.
    """
    mask = (mask_probability >= 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return MIN_MODE_DISTANCE
    perimeter = cv2.arcLength(max(contours, key=cv2.contourArea), closed=True)
    return max(MIN_MODE_DISTANCE, 0.5 * HeatmapParams(k=k).separation * perimeter)


def to_frame(
    mask_probability: NDArray[np.float32],
    heatmap: NDArray[np.float32],
    geometry: FrameGeometry,
    k: int,
    uncertainty: float | None = None,
) -> StudentPrediction:
    """Map one frame's S×S outputs (mask probability, heatmap) back to its full resolution."""
    rows, columns = geometry.inner_rows, geometry.inner_columns
    inner = np.stack([heatmap[rows, columns], mask_probability[rows, columns]], axis=2)
    params = ModeParams(min_distance=mode_distance(inner[:, :, 1], k))
    modes = keypoints_from_heatmap(inner, k=k, params=params)
    offset = np.array([geometry.offset_x, geometry.offset_y], np.float64)
    keypoints = geometry.to_frame(modes + offset) if len(modes) else modes
    full = np.asarray(geometry.map_to_frame(np.stack([heatmap, mask_probability], axis=2)))
    full = np.clip(full, 0, 1).astype(np.float32)
    return StudentPrediction(full[:, :, 1] >= 0.5, full, keypoints, uncertainty)


def sample_spread(
    model: ResNetVAE,
    mean: torch.Tensor,
    logvar: torch.Tensor,
    samples: int,
    geometries: Sequence[FrameGeometry],
) -> list[float]:
    """The uncertainty score of each frame from ``samples`` latent draws (see the module doc)."""
    generator = torch.Generator(device=mean.device).manual_seed(UNCERTAINTY_SEED)
    sigma = torch.exp(0.5 * logvar)
    draws = []
    for _ in range(samples):
        noise = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        mask_logits, _ = model.decode(mean + noise * sigma)
        draws.append(torch.sigmoid(mask_logits.float()))
    spread = torch.stack(draws).std(dim=0, unbiased=False).cpu().numpy()
    return [
        float(2.0 * spread[i, g.inner_rows, g.inner_columns].mean())
        for i, g in enumerate(geometries)
    ]


class StudentPredictor:
    """A trained student loaded once; ``predict`` maps batches of frames to predictions.

    Args:
        model: the network; the predictor owns it from then on (its BatchNorm is folded).
        device: where it runs.
        batch_size: frames per forward pass.
    """

    def __init__(self, model: ResNetVAE, device: torch.device, batch_size: int = 16) -> None:
        self.config = model.config
        self.device = device
        self.dtype = inference_dtype(device)
        self.batch_size = batch_size
        self.model = channels_last(fuse_batchnorm(model.eval().to(device)))

    @classmethod
    def load(
        cls, model_dir: str | Path, device: str | torch.device = "auto", batch_size: int = 16
    ) -> StudentPredictor:
        """Read MODEL_DIR's best weights onto ``device`` (a spec for ``resolve_device``)."""
        resolved = device if isinstance(device, torch.device) else resolve_device(device)
        return cls(load_student(model_dir, resolved), resolved, batch_size)

    def predict(self, images: Sequence[NDArray[Any]], samples: int = 0) -> list[StudentPrediction]:
        """Predictions for frames (any size; gray, RGB or 16-bit), in the same order.

        ``samples`` > 0 also scores each frame's uncertainty from that many latent draws.
        """
        if samples < 0:
            raise InvalidInputError(f"samples must be 0 or more, not {samples}.")
        results: list[StudentPrediction] = []
        for start in range(0, len(images), self.batch_size):
            chunk = images[start : start + self.batch_size]
            results.extend(self._predict_batch(chunk, samples))
        return results

    def _predict_batch(
        self, images: Sequence[NDArray[Any]], samples: int
    ) -> list[StudentPrediction]:
        batch, geometries = frames_to_batch(images, self.config)
        batch = batch.to(self.device).contiguous(memory_format=torch.channels_last)
        autocast = torch.autocast(self.device.type, self.dtype, enabled=self.dtype != torch.float32)
        with torch.inference_mode(), autocast:
            mean, logvar = self.model.encode(batch)
            mask_logits, heatmap_logits = self.model.decode(mean)
            spread = (
                sample_spread(self.model, mean, logvar, samples, geometries)
                if samples
                else [None] * len(geometries)
            )
        masks = torch.sigmoid(mask_logits.float()).cpu().numpy()
        heatmaps = torch.sigmoid(heatmap_logits.float()).cpu().numpy()
        return [
            to_frame(masks[i], heatmaps[i], geometry, self.config.k, spread[i])
            for i, geometry in enumerate(geometries)
        ]
