"""Student inference: frames → mask, heatmap, keypoints and uncertainty, at full resolution.

``StudentPredictor.load(model_dir)`` reads a checkpoint once and prepares the network for
inference (BatchNorm folded into the convolutions, channels-last memory, inference mode; half
precision on CUDA via ``device.inference_dtype``). ``predict`` takes a batch of frames of any
size, fits each to the input (``FrameGeometry``), runs them together, and maps the outputs back.

Keypoints are the modes of the predicted heatmap (``keypoints_from_heatmap``) found at model
resolution and mapped to frame pixels, so they keep the sub-pixel refinement of the small map;
of modes closer than half Algorithm 1's keypoint separation, only the strongest counts: the
others are lobes of the same keypoint (``mode_distance``).

Uncertainty (``samples`` > 0): how likely the student's mask is wrong, in [0, 1], from two
epistemic signals (``uncertainty_parts`` holds both):

- ``disagreement``: test-time augmentation. The frame is run ``samples`` more times, each time
  changed the way a weld camera changes (a small shift, scale and rotation, exposure gamma and
  gain; ``TTA_RANGES``), and each output is mapped back onto the plain one. The score is
  1 − the mean soft IoU between the plain mask probability and the mapped-back ones over the
  frame's pixels: 0 when every pass agrees, higher where the student's mask depends on details
  it should not depend on (the frames it gets wrong).
- ``novelty``: how unlike the training frames the frame looks to the encoder. Each frame's
  descriptor is the mean and standard deviation of every channel of the encoder's last feature
  map (``frame_codes``); training stores the training frames' descriptors
  (``frame_codes.safetensors``). Standardised per dimension by the training set's spread
  (``TrainingCodes``), r is the RMS distance to the nearest training frame and the novelty is
  r / (1 + r). Frames unlike anything trained on (another camera, a blank or noise frame) score
  high even where the student answers confidently. None for a model folder without codes.

``uncertainty`` = 1 − (1 − disagreement)·(1 − novelty) (a noisy-or: either signal alone can
raise it). The passes and draws are seeded, so the same frame gets the same score, and they
never change the answer itself (mask, heatmap, keypoints come from the plain pass).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from weldpool_core.device import inference_dtype, resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.io import to_rgb8
from weldpool_core.keypoints import ModeParams, keypoints_from_heatmap
from weldpool_core.student.checkpoint import load_codes, load_student
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.model import ResNetVAE, StudentConfig, channels_last, fuse_batchnorm

UNCERTAINTY_SEED = 0
MIN_MODE_DISTANCE = 5.0
TTA_RANGES = {"shift": 0.04, "scale": 0.06, "rotation_deg": 4.0, "gamma": 0.35, "gain": 0.2}
"""Largest changes of the test-time passes (± fractions of the input, degrees, log-gamma
spread, gain)."""
MAX_SAMPLES = 64
"""Most test-time passes an uncertainty may take: each is one more forward pass of the batch,
and the score has long settled by then (the app takes 8)."""


@dataclass(frozen=True)
class StudentPrediction:
    """The student's answer for one frame, in full-resolution pixels.

    Attributes:
        mask: H×W bool, mask probability ≥ 0.5.
        heatmap: H×W×2 float32: channel 0 the keypoint heatmap in [0, 1], channel 1 the mask
            probability (the layout of Algorithm 1's output).
        keypoints: m×2 ``(x, y)`` heatmap modes in the order rule (m ≤ k).
        uncertainty: how likely the mask is wrong, in [0, 1] (see the module doc), or None
            when no samples were asked for.
        uncertainty_parts: its parts (``disagreement``, ``novelty``), or None without samples.
    """

    mask: NDArray[np.bool_]
    heatmap: NDArray[np.float32]
    keypoints: NDArray[np.float64]
    uncertainty: float | None = None
    uncertainty_parts: dict[str, float | None] | None = None


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


def frame_keypoints(
    mask_probability: NDArray[np.float32],
    heatmap: NDArray[np.float32],
    geometry: FrameGeometry,
    k: int,
) -> NDArray[np.float64]:
    """The heatmap's modes of one frame's S×S outputs, in full-resolution frame pixels."""
    rows, columns = geometry.inner_rows, geometry.inner_columns
    inner = np.stack([heatmap[rows, columns], mask_probability[rows, columns]], axis=2)
    params = ModeParams(min_distance=mode_distance(inner[:, :, 1], k))
    modes = keypoints_from_heatmap(inner, k=k, params=params)
    offset = np.array([geometry.offset_x, geometry.offset_y], np.float64)
    return geometry.to_frame(modes + offset) if len(modes) else modes


def to_frame(
    mask_probability: NDArray[np.float32],
    heatmap: NDArray[np.float32],
    geometry: FrameGeometry,
    k: int,
    uncertainty: float | None = None,
) -> StudentPrediction:
    """Map one frame's S×S outputs (mask probability, heatmap) back to its full resolution."""
    keypoints = frame_keypoints(mask_probability, heatmap, geometry, k)
    full = np.asarray(geometry.map_to_frame(np.stack([heatmap, mask_probability], axis=2)))
    full = np.clip(full, 0, 1).astype(np.float32)
    return StudentPrediction(full[:, :, 1] >= 0.5, full, keypoints, uncertainty)


def tta_thetas(count: int, seed: int = UNCERTAINTY_SEED) -> list[tuple[torch.Tensor, float, float]]:
    """``count`` test-time passes: a 2×3 affine in ``affine_grid``'s normalised coordinates
    (output → input), an exposure gamma and a gain, drawn within ``TTA_RANGES``."""
    rng = np.random.default_rng([seed, 11])
    passes = []
    for _ in range(count):
        angle = np.deg2rad(rng.uniform(-1, 1) * TTA_RANGES["rotation_deg"])
        scale = 1 + rng.uniform(-1, 1) * TTA_RANGES["scale"]
        shift = rng.uniform(-1, 1, 2) * 2 * TTA_RANGES["shift"]  # normalised span is 2
        cos, sin = np.cos(angle) * scale, np.sin(angle) * scale
        theta = torch.tensor([[cos, -sin, shift[0]], [sin, cos, shift[1]]], dtype=torch.float32)
        spread = np.log1p(TTA_RANGES["gamma"])
        gamma = float(np.exp(rng.uniform(-spread, spread)))
        gain = float(1 + rng.uniform(-1, 1) * TTA_RANGES["gain"])
        passes.append((theta, gamma, gain))
    return passes


def _check_samples(samples: int) -> None:
    if not 0 <= samples <= MAX_SAMPLES:
        raise InvalidInputError(f"samples must be between 0 and {MAX_SAMPLES}, not {samples}.")


def _warp(images: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    grid = F.affine_grid(
        theta.to(images.device, images.dtype).expand(len(images), 2, 3),
        list(images.shape),
        align_corners=False,
    )
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def _inverse(theta: torch.Tensor) -> torch.Tensor:
    full = torch.cat([theta, torch.tensor([[0.0, 0.0, 1.0]])])
    inverse: torch.Tensor = torch.linalg.inv(full)
    return inverse[:2]


def tta_disagreement(
    model: ResNetVAE,
    batch: torch.Tensor,
    plain: torch.Tensor,
    samples: int,
    geometries: Sequence[FrameGeometry],
) -> list[float]:
    """1 − the mean soft IoU between the plain mask probability (N×S×S) and ``samples``
    test-time passes mapped back onto it, per frame (see the module doc)."""
    inside = torch.zeros(plain.shape, dtype=torch.bool, device=plain.device)
    for index, geometry in enumerate(geometries):
        inside[index, geometry.inner_rows, geometry.inner_columns] = True
    overlaps = torch.zeros(len(plain), device=plain.device)
    for theta, gamma, gain in tta_thetas(samples):
        changed = (_warp(batch, theta).clamp(0, 1).pow(gamma) * gain).clamp(0, 1)
        changed = changed.contiguous(memory_format=torch.channels_last)
        mean, _ = model.encode(changed)
        mask_logits, _ = model.decode(mean)
        inverse = _inverse(theta)
        stacked = torch.stack([torch.sigmoid(mask_logits.float()), torch.ones_like(plain)], 1)
        back = _warp(stacked, inverse)
        valid = inside & (back[:, 1] > 0.99)
        found = back[:, 0] * valid
        reference = plain * valid
        union = torch.maximum(found, reference).flatten(1).sum(1)
        common = torch.minimum(found, reference).flatten(1).sum(1)
        overlaps += torch.where(union > 1e-6, common / union.clamp(min=1e-6), 1.0)
    return [float(1.0 - v / samples) for v in overlaps.cpu()]


def frame_codes(features: torch.Tensor) -> torch.Tensor:
    """One descriptor per frame from encoder features (N×F×h×w → N×2F, float32): each
    channel's mean and standard deviation over the map."""
    flat = features.float().flatten(2)
    return torch.cat([flat.mean(2), flat.std(2, unbiased=False)], dim=1)


@dataclass(frozen=True)
class TrainingCodes:
    """The training frames' descriptors, standardised: each dimension by its training mean and
    standard deviation (floored at half the mean standard deviation, so that a dimension that
    hardly varied over a few frames does not dominate)."""

    codes: torch.Tensor
    centre: torch.Tensor
    scale: torch.Tensor

    @classmethod
    def from_codes(cls, codes: torch.Tensor) -> TrainingCodes:
        """Standardise ``codes`` (M×D)."""
        codes = codes.float()
        centre = codes.mean(0)
        spread = codes.std(0, unbiased=False) if len(codes) > 1 else torch.zeros_like(centre)
        size = float(codes.pow(2).mean().sqrt())
        floor = max(0.5 * float(spread.mean()), 1e-3 * size, 1e-6)
        scale = spread.clamp(min=floor)
        return cls((codes - centre) / scale, centre, scale)

    def novelty(self, codes: torch.Tensor) -> list[float]:
        """r / (1 + r) per frame, r the RMS standardised distance to the nearest training
        frame (see the module doc)."""
        standard = (codes.float().cpu() - self.centre) / self.scale
        distance = torch.cdist(standard, self.codes).min(1).values
        ratio = distance / math.sqrt(self.codes.shape[1])
        return [float(r / (1 + r)) for r in ratio]


def combine(disagreement: float, novel: float | None) -> float:
    """The uncertainty of a frame from its parts (a noisy-or; see the module doc)."""
    return float(1.0 - (1.0 - disagreement) * (1.0 - (novel or 0.0)))


class StudentPredictor:
    """A trained student loaded once; ``predict`` maps batches of frames to predictions.

    Args:
        model: the network; the predictor owns it from then on (its BatchNorm is folded).
        device: where it runs.
        batch_size: frames per forward pass.
    """

    def __init__(
        self,
        model: ResNetVAE,
        device: torch.device,
        batch_size: int = 16,
        codes: torch.Tensor | None = None,
    ) -> None:
        self.config = model.config
        self.device = device
        self.dtype = inference_dtype(device)
        self.batch_size = batch_size
        self.model = channels_last(fuse_batchnorm(model.eval().to(device)))
        self.training_codes = None if codes is None else TrainingCodes.from_codes(codes)

    @classmethod
    def load(
        cls, model_dir: str | Path, device: str | torch.device = "auto", batch_size: int = 16
    ) -> StudentPredictor:
        """Read MODEL_DIR's best weights (and training codes) onto ``device``."""
        resolved = device if isinstance(device, torch.device) else resolve_device(device)
        codes = load_codes(model_dir)
        return cls(load_student(model_dir, resolved), resolved, batch_size, codes)

    def predict(self, images: Sequence[NDArray[Any]], samples: int = 0) -> list[StudentPrediction]:
        """Predictions for frames (any size; gray, RGB or 16-bit), in the same order.

        ``samples`` > 0 also scores each frame's uncertainty, with that many test-time passes.
        """
        _check_samples(samples)
        results: list[StudentPrediction] = []
        for start in range(0, len(images), self.batch_size):
            chunk = images[start : start + self.batch_size]
            results.extend(self._predict_batch(chunk, samples))
        return results

    def outputs(
        self, batch: torch.Tensor, samples: int = 0, geometries: Sequence[FrameGeometry] = ()
    ) -> tuple[NDArray[np.float32], NDArray[np.float32], list[dict[str, float | None] | None]]:
        """Model-resolution outputs of an N×3×S×S batch in [0, 1]: mask probability and heatmap
        (N×S×S each), and with ``samples`` > 0 each frame's uncertainty parts (else None)."""
        _check_samples(samples)
        batch = batch.to(self.device).contiguous(memory_format=torch.channels_last)
        autocast = torch.autocast(self.device.type, self.dtype, enabled=self.dtype != torch.float32)
        with torch.inference_mode(), autocast:
            features = self.model.features(batch)
            mean, _ = self.model.posterior(features)
            mask_logits, heatmap_logits = self.model.decode(mean)
            masks_t = torch.sigmoid(mask_logits.float())
            parts: list[dict[str, float | None] | None] = [None] * len(batch)
            if samples:
                spread = tta_disagreement(self.model, batch, masks_t, samples, geometries)
                novel: list[float | None] = [None] * len(batch)
                known = self.training_codes
                codes = frame_codes(features)
                if known is not None and codes.shape[1] == known.codes.shape[1]:
                    novel = list(known.novelty(codes))
                parts = [
                    {"disagreement": d, "novelty": n} for d, n in zip(spread, novel, strict=True)
                ]
        masks = masks_t.cpu().numpy()
        heatmaps = torch.sigmoid(heatmap_logits.float()).cpu().numpy()
        return masks, heatmaps, parts

    def _predict_batch(
        self, images: Sequence[NDArray[Any]], samples: int
    ) -> list[StudentPrediction]:
        batch, geometries = frames_to_batch(images, self.config)
        masks, heatmaps, parts = self.outputs(batch, samples, geometries)
        results = []
        for i, geometry in enumerate(geometries):
            found = to_frame(masks[i], heatmaps[i], geometry, self.config.k)
            part = parts[i]
            if part is not None:
                score = combine(float(part["disagreement"] or 0.0), part["novelty"])
                found = replace(found, uncertainty=score, uncertainty_parts=part)
            results.append(found)
        return results
