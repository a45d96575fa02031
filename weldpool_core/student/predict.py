"""Student inference: frames → mask, heatmap, keypoints and uncertainty, at full resolution.

``StudentPredictor.load(model_dir)`` reads a checkpoint once and prepares the network for
inference (BatchNorm folded into the convolutions, channels-last memory, inference mode; half
precision on CUDA via ``device.inference_dtype``). ``predict`` takes a batch of frames of any
size, fits each to the input (``FrameGeometry``), runs them together, and maps the outputs back.

Keypoints are read at model resolution and mapped to frame pixels (``frame_keypoints``), from
where the student's ``config.keypoints`` says. ``mask`` (the default): Algorithm 1 on the
predicted mask within the frame, the rule by which a label's keypoints are placed: on the real
labels it places them nearer than the heatmap's modes do, within a clip and across clips
(``bench/real_student.py``), and it costs ~0.5 ms a frame. ``heatmap`` (students saved
before the choice): the modes of the predicted heatmap (``keypoints_from_heatmap``), with the
sub-pixel refinement of the small map; of modes closer than half Algorithm 1's keypoint
separation, only the strongest counts: the others are lobes of the same keypoint
(``mode_distance``).

Uncertainty (``samples`` > 0): how likely the student's mask is wrong, in [0, 1], from three
signals (``uncertainty_parts`` holds them):

- ``spread``: how much of the answer the student's own posterior moves. The frame's
  predictive mask probability p̄ is the mean over ``samples`` seeded draws of the VAE's latent
  (its posterior mean plus noise of its predicted spread, decoded); the spread is 1 − the soft
  IoU (Σ min ÷ Σ max over the frame's pixels) of p̄ with the plain pass's mask probability
  (``mask_spread``): 0 where no draw changes the mask, higher where the draws move the
  pool's outline (the wire, the glare, a dark front edge: where a mask goes wrong), and like
  IoU it weighs that change against the pool's size.
- ``ambiguity``: the probability mass in doubt on p̄, Σ 2·min(p̄, 1 − p̄), over the predicted
  pool's area, capped at 1 (``mask_ambiguity``, which the live record also reports): how soft
  the outline is, against the pool's size.
- ``novelty``: how far the frame lies beyond the training frames, as the encoder sees them.
  Each frame's descriptor is the mean and standard deviation of every channel of the
  encoder's last feature map (``frame_codes``); training stores the training frames'
  descriptors (``frame_codes.safetensors``). Standardised per dimension by the training set's
  spread (``TrainingCodes``), r is the RMS distance to the nearest training frame; the novelty
  is e / (1 + e) with e = max(0, r − the student's familiar distance). Each student measures
  its own at the end of training (``familiar_distance``): ``FOREIGN_MARGIN`` of the way to the
  nearest of the frames it cannot read, made from its training frames (``foreign_versions``:
  blank, noise, inverted, contrast cut to a tenth), because how far frames lie depends on the
  student (a skip student puts a real clip it never saw at up to 6, the old default at 4.6).
  Frames of other runs of the same camera lie within it and score 0 (there novelty ranked the
  student's errors backwards, ``bench/uncertainty.py``); a blank, noise or inverted frame,
  another camera, lies beyond and scores high even where the student answers confidently.
  None for a model folder without codes.

The mask's part is √(spread × ambiguity) (``mask_doubt``): both must be high, and a change of
either by a factor counts the same whatever their scales. Each alone ranked the errors on one
test bed and not the other: on the 15 real labels (45 held-out predictions, leave-one-clip-out)
the spread ranks them at ρ +0.54 and the ambiguity at +0.34, on the varied synthetic pool of
``bench/active.py`` the ambiguity at +0.44 and the spread at +0.22; their geometric mean ranks
them at +0.58 and +0.38: above the spread on both, far above the ambiguity on the real frames
(``bench/uncertainty.py``, ``bench/uncertainty_synthetic.py``, docs/benchmarks).

``uncertainty`` = 1 − (1 − mask part)·(1 − novelty) (a noisy-or: either alone can raise
it). The draws are seeded, so the same frame gets the same score, and they never change
the answer itself (mask, heatmap, keypoints come from the latent mean). On the 15 real labels,
leave-one-clip-out, it ranks the default student's errors (Spearman ρ over 45 held-out
predictions, with its 95 % interval, in docs/benchmarks; ``bench/uncertainty.py``) where the score
of two releases ago, test-time-pass disagreement noisy-or'd with unshifted novelty, ranked them
backwards.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from weldpool_core.device import inference_dtype, resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, keypoints_from_mask
from weldpool_core.io import to_rgb8
from weldpool_core.keypoints import ModeParams, keypoints_from_heatmap
from weldpool_core.student.checkpoint import load_codes, load_student
from weldpool_core.student.classes import classes_to_frame
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.model import ResNetVAE, StudentConfig, channels_last, fuse_batchnorm

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

UNCERTAINTY_SEED = 0
MIN_MODE_DISTANCE = 5.0
FAMILIAR_DISTANCE = 4.0
"""The familiar distance of a model folder saved before each student measured its own
(``familiar_distance``): RMS standardised distance to the nearest training frame within which
a frame is familiar (novelty 0), measured for the default student of that time on real frames
(``bench/uncertainty.py``): real frames of clips it never saw at 0–4 from its training frames;
blank, white, noise, inverted, darkened frames and another camera's at 5–15."""
FOREIGN_MARGIN = 0.75
"""A student's familiar distance as a fraction of the distance of the nearest frame it could
not read (``foreign_versions`` of its training frames). Measured on the real folds
(``bench/uncertainty.py``, docs/benchmarks): the held-out clips reach 0.22–0.69 of it (up to 6.1 in
absolute units for a skip student whose foreign frames lie at 8.9 and beyond), so a fixed
distance either flags a real clip or lets a foreign frame through, depending on the student."""
FOREIGN_FRAMES = 8
"""Training frames whose foreign versions calibrate the familiar distance (evenly spaced)."""
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
        keypoints: m×2 ``(x, y)`` frame pixels (m ≤ k), in the order rule, read where
            ``StudentConfig.keypoints`` says (the mask's outline or the heatmap's modes).
        uncertainty: how likely the mask is wrong, in [0, 1] (see the module doc), or None
            when no samples were asked for.
        uncertainty_parts: its parts (``spread``, ``ambiguity``, ``novelty``), or None
            without samples.
        classes: the learned classes' answers (``classes.classes_to_frame``: a bool mask, or
            named points), empty for a pool-only student.
    """

    mask: NDArray[np.bool_]
    heatmap: NDArray[np.float32]
    keypoints: NDArray[np.float64]
    uncertainty: float | None = None
    uncertainty_parts: dict[str, float | None] | None = None
    classes: dict[str, Any] = field(default_factory=dict)


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
    config: StudentConfig,
) -> NDArray[np.float64]:
    """One frame's keypoints from its S×S outputs, in full-resolution frame pixels, read where
    ``config.keypoints`` says: Algorithm 1 on the mask (its outline within the frame; none for
    a mask too small to have one), or the heatmap's modes."""
    rows, columns = geometry.inner_rows, geometry.inner_columns
    if config.keypoints == "mask":
        try:
            points = keypoints_from_mask(
                mask_probability[rows, columns] >= 0.5, HeatmapParams(k=config.k)
            )
        except InvalidInputError:  # no pool, or one too small for an outline
            return np.zeros((0, 2))
    else:
        inner = np.stack([heatmap[rows, columns], mask_probability[rows, columns]], axis=2)
        params = ModeParams(min_distance=mode_distance(inner[:, :, 1], config.k))
        points = keypoints_from_heatmap(inner, k=config.k, params=params)
    offset = np.array([geometry.offset_x, geometry.offset_y], np.float64)
    return geometry.to_frame(points + offset) if len(points) else points


def to_frame(
    mask_probability: NDArray[np.float32],
    heatmap: NDArray[np.float32],
    geometry: FrameGeometry,
    config: StudentConfig,
    uncertainty: float | None = None,
) -> StudentPrediction:
    """Map one frame's S×S outputs (mask probability, heatmap) back to its full resolution."""
    keypoints = frame_keypoints(mask_probability, heatmap, geometry, config)
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


def mask_spread(drawn: NDArray[np.floating[Any]], plain: NDArray[np.floating[Any]]) -> float:
    """1 − the soft IoU (Σ min ÷ Σ max) of the latent draws' mean mask probability with the
    plain pass's, over one frame's pixels: how much of the answer the student's own posterior
    moves (0 when both are empty; see the module doc)."""
    a, b = np.asarray(drawn, np.float64), np.asarray(plain, np.float64)
    union = float(np.maximum(a, b).sum())
    return 0.0 if union <= 1e-6 else 1.0 - float(np.minimum(a, b).sum()) / union


def frame_codes(features: torch.Tensor) -> torch.Tensor:
    """One descriptor per frame from encoder features (N×F×h×w → N×2F, float32): each
    channel's mean and standard deviation over the map."""
    flat = features.float().flatten(2)
    return torch.cat([flat.mean(2), flat.std(2, unbiased=False)], dim=1)


def foreign_versions(batch: torch.Tensor, seed: int = UNCERTAINTY_SEED) -> torch.Tensor:
    """Frames no student of this camera can read, made from an N×3×S×S batch in [0, 1]: black,
    mid-grey and white frames, uniform noise, each frame inverted, and each with its contrast
    cut to a tenth (6N frames). A darkened or mirrored frame is left out: a real camera gives
    those (another exposure, another mounting)."""
    generator = torch.Generator(device="cpu").manual_seed(seed)
    noise = torch.rand(batch.shape, generator=generator).to(batch.device, batch.dtype)
    centre = batch.mean(dim=(1, 2, 3), keepdim=True)
    return torch.cat(
        [
            torch.zeros_like(batch),
            torch.full_like(batch, 0.5),
            torch.ones_like(batch),
            noise,
            1 - batch,
            centre + 0.1 * (batch - centre),
        ]
    )


@dataclass(frozen=True)
class TrainingCodes:
    """The training frames' descriptors, standardised: each dimension by its training mean and
    standard deviation (floored at half the mean standard deviation, so that a dimension that
    hardly varied over a few frames does not dominate), and the distance within which a frame
    is familiar (``familiar_distance``)."""

    codes: torch.Tensor
    centre: torch.Tensor
    scale: torch.Tensor
    familiar: float = FAMILIAR_DISTANCE

    @classmethod
    def from_codes(cls, codes: torch.Tensor, familiar: float | None = None) -> TrainingCodes:
        """Standardise ``codes`` (M×D); ``familiar`` None: ``FAMILIAR_DISTANCE``."""
        codes = codes.float()
        centre = codes.mean(0)
        spread = codes.std(0, unbiased=False) if len(codes) > 1 else torch.zeros_like(centre)
        size = float(codes.pow(2).mean().sqrt())
        floor = max(0.5 * float(spread.mean()), 1e-3 * size, 1e-6)
        scale = spread.clamp(min=floor)
        return cls((codes - centre) / scale, centre, scale, familiar or FAMILIAR_DISTANCE)

    def distance(self, codes: torch.Tensor) -> list[float]:
        """r per frame: the RMS standardised distance to the nearest training frame."""
        standard = (codes.float().cpu() - self.centre) / self.scale
        nearest = torch.cdist(standard, self.codes).min(1).values
        return [float(r) for r in nearest / math.sqrt(self.codes.shape[1])]

    def novelty(self, codes: torch.Tensor) -> list[float]:
        """e / (1 + e) per frame, e = max(0, r − ``familiar``) (see the module doc)."""
        beyond = [max(0.0, r - self.familiar) for r in self.distance(codes)]
        return [e / (1 + e) for e in beyond]


def familiar_distance(known: TrainingCodes, foreign_codes: torch.Tensor) -> float:
    """A student's own familiar distance: ``FOREIGN_MARGIN`` × the distance of the nearest of
    its training frames' ``foreign_versions`` (their descriptors, ``foreign_codes``)."""
    return FOREIGN_MARGIN * min(known.distance(foreign_codes))


def mask_doubt(spread: float, ambiguity: float) -> float:
    """The uncertainty's mask part: the geometric mean of the latent draws' spread and the
    outline's ambiguity (see the module doc)."""
    return math.sqrt(max(spread, 0.0) * max(ambiguity, 0.0))


def combine(mask: float, novel: float | None) -> float:
    """The uncertainty of a frame from its mask part and its novelty (a noisy-or; see the
    module doc)."""
    return float(1.0 - (1.0 - mask) * (1.0 - (novel or 0.0)))


def uncertainty_of(parts: dict[str, float | None]) -> float:
    """The uncertainty of a frame from its ``uncertainty_parts``: the one rule for it."""
    mask = mask_doubt(float(parts["spread"] or 0.0), float(parts["ambiguity"] or 0.0))
    return combine(mask, parts["novelty"])


class StudentPredictor:
    """A trained student loaded once; ``predict`` maps batches of frames to predictions.

    Args:
        model: the network; the predictor owns it from then on (its BatchNorm is folded).
        device: where it runs.
        batch_size: frames per forward pass.
        codes: the training frames' descriptors and the student's familiar distance
            (``checkpoint.load_codes``), for the novelty part of the uncertainty.
    """

    def __init__(
        self,
        model: ResNetVAE,
        device: torch.device,
        batch_size: int = 16,
        codes: tuple[torch.Tensor, float | None] | None = None,
    ) -> None:
        self.config = model.config
        self.device = device
        self.dtype = inference_dtype(device)
        self.batch_size = batch_size
        self.model = channels_last(fuse_batchnorm(model.eval().to(device)))
        self.training_codes = None if codes is None else TrainingCodes.from_codes(*codes)

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
        masks, heatmaps, parts, _ = self.outputs_all(batch, samples, geometries)
        return masks, heatmaps, parts

    def outputs_all(
        self, batch: torch.Tensor, samples: int = 0, geometries: Sequence[FrameGeometry] = ()
    ) -> tuple[
        NDArray[np.float32],
        NDArray[np.float32],
        list[dict[str, float | None] | None],
        NDArray[np.float32] | None,
    ]:
        """``outputs`` and the learned classes' probabilities (N×E×S×S; None without)."""
        _check_samples(samples)
        batch = batch.to(self.device).contiguous(memory_format=torch.channels_last)
        autocast = torch.autocast(self.device.type, self.dtype, enabled=self.dtype != torch.float32)
        with torch.inference_mode(), autocast:
            features, skips = self.model.encoder_maps(batch)
            mean, logvar = self.model.posterior(features)
            mask_logits, heatmap_logits, class_logits = self.model.decode_all(mean, skips)
            masks = torch.sigmoid(mask_logits.float()).cpu().numpy()
            parts: list[dict[str, float | None] | None] = [None] * len(batch)
            if samples:
                predictive = predictive_mask(self.model, mean, logvar, samples, skips=skips)
                drawn = predictive.cpu().numpy()
                inner, inner_plain = list(drawn), list(masks)
                for index, geometry in enumerate(geometries):
                    rows, columns = geometry.inner_rows, geometry.inner_columns
                    inner[index] = drawn[index, rows, columns]
                    inner_plain[index] = masks[index, rows, columns]
                novel: list[float | None] = [None] * len(batch)
                known = self.training_codes
                codes = frame_codes(features)
                if known is not None and codes.shape[1] == known.codes.shape[1]:
                    novel = list(known.novelty(codes))
                parts = [
                    {
                        "spread": mask_spread(d, p),
                        "ambiguity": mask_ambiguity(d),
                        "novelty": n,
                    }
                    for d, p, n in zip(inner, inner_plain, novel, strict=True)
                ]
        heatmaps = torch.sigmoid(heatmap_logits.float()).cpu().numpy()
        extra = None
        if class_logits is not None:
            extra = torch.sigmoid(class_logits.float()).cpu().numpy()
        return masks, heatmaps, parts, extra

    def _predict_batch(
        self, images: Sequence[NDArray[Any]], samples: int
    ) -> list[StudentPrediction]:
        batch, geometries = frames_to_batch(images, self.config)
        masks, heatmaps, parts, extra = self.outputs_all(batch, samples, geometries)
        results = []
        for i, geometry in enumerate(geometries):
            found = to_frame(masks[i], heatmaps[i], geometry, self.config)
            if extra is not None:
                answers = classes_to_frame(extra[i], self.config.classes, geometry)
                found = replace(found, classes=answers)
            part = parts[i]
            if part is not None:
                found = replace(found, uncertainty=uncertainty_of(part), uncertainty_parts=part)
            results.append(found)
        return results
