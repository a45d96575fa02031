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
signals (``uncertainty_parts`` holds both):

- ``ambiguity``: how much of the predicted pool the student is unsure of. The frame's
  predictive mask probability p̄ is the mean over ``samples`` seeded draws of the VAE's latent
  (its posterior mean plus noise of its predicted spread, decoded); the score is the
  probability mass in doubt, Σ 2·min(p̄, 1 − p̄) over the frame's pixels, divided by the
  predicted pool's area (pixels with p̄ ≥ 0.5), capped at 1: 0 for a mask whose every pixel
  is sure, higher where the edge is smeared over a wide band relative to the pool (the wire,
  the glare, a dark front edge: where a mask goes wrong). A mask error is mostly at its edge
  and IoU divides it by the pool's size, and the score does both.
- ``novelty``: how far the frame lies beyond the training frames, as the encoder sees them.
  Each frame's descriptor is the mean and standard deviation of every channel of the
  encoder's last feature map (``frame_codes``); training stores the training frames'
  descriptors (``frame_codes.safetensors``). Standardised per dimension by the training set's
  spread (``TrainingCodes``), r is the RMS distance to the nearest training frame; the novelty
  is e / (1 + e) with e = max(0, r − ``FAMILIAR_DISTANCE``). Frames of other runs of the same
  camera lie within that distance and score 0 (there novelty ranked the student's errors
  backwards, ``bench/uncertainty.py``); a blank, noise or inverted frame, another camera,
  lies beyond and scores high even where the student answers confidently. None for a model
  folder without codes.

``uncertainty`` = 1 − (1 − ambiguity)·(1 − novelty) (a noisy-or: either signal alone can raise
it). The draws are seeded, so the same frame gets the same score, and they never change the
answer itself (mask, heatmap, keypoints come from the latent mean). On the 15 real labels,
leave-one-clip-out, the ambiguity ranks the student's errors (Spearman ρ +0.49 over 45
held-out predictions, 95 % interval +0.22 to +0.68) where the earlier score, test-time-pass
disagreement noisy-or'd with unshifted novelty, ranked them backwards (−0.39).
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
FAMILIAR_DISTANCE = 4.0
"""RMS standardised distance to the nearest training frame within which a frame is familiar
(novelty 0). Measured (``bench/uncertainty.py`` and the module doc): real frames of clips a
student never saw lie at 0–4 from its training frames; blank, white, noise, inverted, darkened
frames and another camera's at 5–15, a flipped one at 4–6."""
MAX_SAMPLES = 64
"""Most latent draws an uncertainty may take: each is one more decoder pass of the batch, and
the score has long settled by then (the app takes 8)."""


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
        uncertainty_parts: its parts (``ambiguity``, ``novelty``), or None without samples.
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


def _check_samples(samples: int) -> None:
    if not 0 <= samples <= MAX_SAMPLES:
        raise InvalidInputError(f"samples must be between 0 and {MAX_SAMPLES}, not {samples}.")


def predictive_mask(
    model: ResNetVAE,
    mean: torch.Tensor,
    logvar: torch.Tensor,
    samples: int,
    seed: int = UNCERTAINTY_SEED,
    skips: tuple[torch.Tensor, ...] = (),
) -> torch.Tensor:
    """The mean mask probability (N×S×S, float32) over ``samples`` seeded latent draws (the
    same draws for every frame, so a frame's score does not depend on its batch)."""
    generator = torch.Generator(device="cpu").manual_seed(seed)
    total = torch.zeros((), device=mean.device)
    spread = torch.exp(0.5 * logvar.float())
    for _ in range(samples):
        noise = torch.randn((1, *mean.shape[1:]), generator=generator).to(mean.device)
        logits, _ = model.decode((mean.float() + noise * spread).to(mean.dtype), skips)
        total = total + torch.sigmoid(logits.float())
    return total / samples


def mask_ambiguity(probability: NDArray[np.floating[Any]]) -> float:
    """Σ 2·min(p, 1 − p) over a mask probability's pixels ÷ the pool's area (p ≥ 0.5), capped
    at 1 (see the module doc): the one rule for the uncertainty's part and the live record."""
    p = np.asarray(probability, np.float32)
    doubt = float(np.minimum(p, 1 - p).sum(dtype=np.float64)) * 2
    area = int(np.count_nonzero(p >= 0.5))
    return min(1.0, doubt / max(area, 1))


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

    def distance(self, codes: torch.Tensor) -> list[float]:
        """r per frame: the RMS standardised distance to the nearest training frame."""
        standard = (codes.float().cpu() - self.centre) / self.scale
        nearest = torch.cdist(standard, self.codes).min(1).values
        return [float(r) for r in nearest / math.sqrt(self.codes.shape[1])]

    def novelty(self, codes: torch.Tensor) -> list[float]:
        """e / (1 + e) per frame, e = max(0, r − ``FAMILIAR_DISTANCE``) (see the module doc)."""
        beyond = [max(0.0, r - FAMILIAR_DISTANCE) for r in self.distance(codes)]
        return [e / (1 + e) for e in beyond]


def combine(ambiguity: float, novel: float | None) -> float:
    """The uncertainty of a frame from its parts (a noisy-or; see the module doc)."""
    return float(1.0 - (1.0 - ambiguity) * (1.0 - (novel or 0.0)))


def uncertainty_of(parts: dict[str, float | None]) -> float:
    """The uncertainty of a frame from its ``uncertainty_parts``."""
    return combine(float(parts["ambiguity"] or 0.0), parts["novelty"])


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

        ``samples`` > 0 also scores each frame's uncertainty, with that many latent draws.
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
            features, skips = self.model.encoder_maps(batch)
            mean, logvar = self.model.posterior(features)
            mask_logits, heatmap_logits = self.model.decode(mean, skips)
            masks_t = torch.sigmoid(mask_logits.float())
            parts: list[dict[str, float | None] | None] = [None] * len(batch)
            if samples:
                predictive = predictive_mask(self.model, mean, logvar, samples, skips=skips)
                drawn = predictive.cpu().numpy()
                inner = list(drawn)
                for index, geometry in enumerate(geometries):
                    inner[index] = drawn[index, geometry.inner_rows, geometry.inner_columns]
                ambiguity = [mask_ambiguity(d) for d in inner]
                novel: list[float | None] = [None] * len(batch)
                known = self.training_codes
                codes = frame_codes(features)
                if known is not None and codes.shape[1] == known.codes.shape[1]:
                    novel = list(known.novelty(codes))
                parts = [
                    {"ambiguity": a, "novelty": n} for a, n in zip(ambiguity, novel, strict=True)
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
                found = replace(found, uncertainty=uncertainty_of(part), uncertainty_parts=part)
            results.append(found)
        return results
